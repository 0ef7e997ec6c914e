"""Power cut at every storage write of a table update (C firmware, posix port): after every
restart the old or the new table is active with a valid CRC, never a mix, and the update can
be pushed again."""

from __future__ import annotations

import numpy as np
import pytest
from firmware_tiers import missing_reason

from grassd.rigs.power_cut import power_cut_sweep

pytestmark = pytest.mark.skipif(missing_reason("posix") is not None,
                                reason=str(missing_reason("posix")))

N_PIXELS = 4


def tables():
    rng = np.random.default_rng(3)
    old = rng.integers(0, 20001, 256).astype(np.uint16)  # a global table
    new = rng.integers(0, 20001, (N_PIXELS, 256)).astype(np.uint16)  # per-pixel tables
    return old, new


@pytest.mark.parametrize(("has_old", "keeps"), [
    (True, ("none", "half", "all-but-one")), (False, ("half",))],
    ids=["over-old-table", "first-table"])
def test_every_cut_leaves_old_or_new_table(tmp_path, has_old, keeps):
    old, new = tables()
    old = old if has_old else None
    out = power_cut_sweep(tmp_path, old, new, n_pixels=N_PIXELS, max_chunk=128, keeps=keeps)
    writes = len(out) // len(keeps) - 1
    # BEGIN's invalidation + 2048 bytes in 128-byte chunks + the header switch
    assert writes == 1 + 16 + 1
    cuts = sum(o.cut for o in out)
    print(f"power cut tested at {cuts} points ({writes} storage writes x {len(keeps)} ways to "
          f"tear the cut write: {', '.join(keeps)}) + {len(keeps)} uncut runs, "
          f"{'over an old table' if has_old else 'first table'}")
    assert [o.cut for o in out] == ([True] * writes + [False]) * len(keeps)
    before_switch = "old" if has_old else "none"
    assert [o.active for o in out] == ([before_switch] * writes + ["new"]) * len(keeps)
    assert all(o.status_crc_ok and o.recovered for o in out)
