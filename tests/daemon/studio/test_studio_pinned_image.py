"""The condition pinned as B gets its views after A's: its characteristic run to its target (B
may have been pinned before it converged) and its image refined; refined images are kept, so a
condition seen again goes on from the passes it had instead of starting over. A B that cannot be
lit is said as B's, and A goes on."""

from __future__ import annotations

import pytest
from conftest import studio_and_condition

from grassd.daemon.studio import pace
from grassd.daemon.studio.worker import Superseded

LENGTHS = [0, 10, 20]


def _refined(sent: list[dict]) -> list[dict]:
    """A's refined images (192 px) sent after its views (the audience map)."""
    kinds = [m["type"] for m in sent]
    after = sent[kinds.index("audience") + 1:] if "audience" in kinds else []
    return [m for m in after if m["type"] == "pixel" and m["width"] == pace.REFINE_IMAGE[0]]


def _run_until_a_refines(st, cond, pinned) -> list[dict]:
    """Messages of ``st.run(cond, pinned=pinned)`` up to A's first refined image after its
    views."""
    sent: list[dict] = []

    def check() -> None:
        if _refined(sent):
            raise Superseded("a newer input")

    with pytest.raises(Superseded):
        st.run(cond, sent.append, check, pinned=pinned)
    return sent


def test_the_pinned_image_refines_after_the_views_and_is_kept(renderer, shared_hdri):
    st, a = studio_and_condition(shared_hdri("courtyard"), {
        "ambient_lux": 5000, "viewpoint": [170, 2, 0], "lengths_mm": LENGTHS})
    b = st.parse({"ambient_lux": 5000, "viewpoint": [120, 3, 12], "lengths_mm": LENGTHS})
    sent = _run_until_a_refines(st, a, b)
    kinds = [m["type"] for m in sent]
    # B's views come once A's are all out (its audience map last), before A's image refines
    assert kinds.index("pinned") == kinds.index("audience") + 1
    curve = sent[kinds.index("pinned")]
    assert curve["curve"]["converged"] and curve["curve"]["max_stderr"] <= 0.1
    assert curve["curve"]["lengths_mm"] == LENGTHS and curve["ogcd_range"] > 1.0
    pinned = [m for m in sent if m["type"] == "pinned" and "image" in m]
    assert [m["spp"] for m in pinned] == list(range(1, pace.PINNED_PASSES + 1))
    assert [m["final"] for m in pinned] == [False] * (pace.PINNED_PASSES - 1) + [True]
    assert all(m["width"] == pace.REFINE_IMAGE[0] for m in pinned)
    assert kinds.index("pinned") < sent.index(_refined(sent)[0])
    assert [m["spp"] for m in _refined(sent)] == [1]

    # the same two conditions again: nothing is simulated anew but A's image, which goes on (its
    # curve, audience map and refined image are kept, B's curve and image too)
    runs = []
    characteristic = st.characteristic
    st.characteristic = lambda *args, **kw: runs.append(args) or characteristic(*args, **kw)
    again = _run_until_a_refines(st, a, b)
    assert runs == []
    assert [{**m, "ms": 0} for m in again if m["type"] == "audience"] == [
        {**m, "ms": 0} for m in sent if m["type"] == "audience"]
    first = next(m for m in again if m["type"] == "pixel")
    assert first["width"] == pace.REFINE_IMAGE[0] and first["spp"] >= 2
    curves_again = [m["curve"] for m in again if m["type"] == "pinned" and "curve" in m]
    assert not curve["curve"]["kept"]
    assert curves_again == [{**curve["curve"], "kept": True}]  # kept: sent as it was
    pinned_again = [m for m in again if m["type"] == "pinned" and "image" in m]
    assert len(pinned_again) == 1 and pinned_again[0]["final"]
    assert pinned_again[0]["spp"] == pace.PINNED_PASSES
    assert pinned_again[0]["image"] == pinned[-1]["image"]
    assert _refined(again)[0]["spp"] >= 2  # the passes of the first run kept


def test_a_pinned_condition_that_cannot_be_lit_is_said_and_a_goes_on(renderer, shared_hdri):
    st, a = studio_and_condition(shared_hdri("courtyard"), {
        "ambient_lux": 5000, "viewpoint": [170, 2, 0], "lengths_mm": LENGTHS})
    night = st.parse({"ambient_lux": 5000, "viewpoint": [170, 2, 0], "lengths_mm": LENGTHS,
                      "sun": {"mode": "site", "lux": 30000, "when": "2026-11-27T23:00"}})
    sent = _run_until_a_refines(st, a, night)
    pinned = [m for m in sent if m["type"] == "pinned"]
    assert len(pinned) == 1 and pinned[0]["final"]
    assert "below the horizon" in pinned[0]["error"]
    assert _refined(sent)  # A's image went on after B's error
