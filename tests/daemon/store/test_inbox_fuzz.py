"""Random and mutated bundles (rigs/inbox_fuzz.py: file kinds, sizes, names, manifests) through
the inbox for a fixed budget with a fixed seed: no scan raises or blocks, every bundle ends
claimed or rejected with a readable reason, every valid one (odd names too) claimed, and a
restart recovers the state.
``python -m bench hostile`` runs the same fuzzing longer."""

from __future__ import annotations

from grassd.rigs.inbox_fuzz import fuzz_inbox

SEED = 20261127
BUNDLES = 120


def test_random_hostile_bundles_end_claimed_or_rejected(tmp_path):
    counts = fuzz_inbox(tmp_path, SEED, BUNDLES)
    print(f"\n  {BUNDLES} random bundles: {counts}")
    assert counts["rejected"] > BUNDLES // 3  # the generator is mostly hostile
    assert counts["valid"] > BUNDLES // 10  # ... but not only; each valid one was claimed
