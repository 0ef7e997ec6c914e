"""The image of the condition pinned as B refines after A's views, and refined images are kept:
a condition seen again goes on from the passes it had instead of starting over."""

from __future__ import annotations

import pytest
from conftest import parse_studio_condition, studio_and_condition

from grassd.daemon.studio import session
from grassd.daemon.studio.worker import Superseded


def _run_until_a_refines(st, cond, pinned) -> list[dict]:
    """Messages of ``st.run(cond, pinned=pinned)`` up to A's first refined image (192 px)."""
    sent: list[dict] = []

    def check() -> None:
        if any(m["type"] == "pixel" and not m.get("pinned")
               and m["width"] == session.REFINE_IMAGE[0] for m in sent):
            raise Superseded("a newer input")

    with pytest.raises(Superseded):
        st.run(cond, sent.append, check, pinned=pinned)
    return sent


def test_the_pinned_image_refines_after_the_views_and_is_kept(renderer, shared_hdri):
    st, a = studio_and_condition(shared_hdri("courtyard"), {
        "ambient_lux": 5000, "viewpoint": [170, 2, 0], "lengths_mm": [0, 10, 20]})
    b = parse_studio_condition(st, {"ambient_lux": 5000, "viewpoint": [120, 3, 12],
                                    "lengths_mm": [0, 10, 20]})
    sent = _run_until_a_refines(st, a, b)
    kinds = [m["type"] for m in sent]
    pinned = [m for m in sent if m.get("pinned")]
    # B refines once A's views are all out (its audience map last), before A's own refinement
    assert kinds.index("pixel", kinds.index("audience")) == sent.index(pinned[0])
    assert [m["spp"] for m in pinned] == list(range(1, session.PINNED_PASSES + 1))
    assert [m["final"] for m in pinned] == [False] * (session.PINNED_PASSES - 1) + [True]
    assert all(m["width"] == session.REFINE_IMAGE[0] for m in pinned)
    a_refined = [m for m in sent if m["type"] == "pixel" and not m.get("pinned")
                 and m["width"] == session.REFINE_IMAGE[0]]
    assert [m["spp"] for m in a_refined] == [1]

    # the same two conditions again: B's image is sent once as it was, A's goes on
    again = _run_until_a_refines(st, a, b)
    pinned_again = [m for m in again if m.get("pinned")]
    assert len(pinned_again) == 1 and pinned_again[0]["final"]
    assert pinned_again[0]["spp"] == session.PINNED_PASSES
    assert pinned_again[0]["image"] == pinned[-1]["image"]
    a_again = [m for m in again if m["type"] == "pixel" and not m.get("pinned")
               and m["width"] == session.REFINE_IMAGE[0]]
    assert a_again[0]["spp"] >= 2  # the pass of the first run (and any after it) kept
