"""freed_when_done: the cycles a block makes and drops are freed at its end, not at the next
full collection (a run's report figure, saved through commit_run)."""

from __future__ import annotations

import gc
import io
import weakref

import numpy as np
import pytest

from grassd.daemon.core.runtime.young_garbage import freed_when_done


class Node:
    """A link of a reference cycle."""

    next: Node


def _ring(n: int) -> weakref.ref:
    """A ring of ``n`` nodes, dropped at return; a weak reference to one of them. ``n`` is
    large enough that the collector's young collections run (and promote) while it is built."""
    nodes = [Node() for _ in range(n)]
    for a, b in zip(nodes, nodes[1:] + nodes[:1], strict=True):
        a.next = b
    return weakref.ref(nodes[0])


def _full_collections() -> int:
    return gc.get_stats()[2]["collections"]


@pytest.fixture
def collector_on():
    """The collector enabled for the test, as it was afterwards."""
    was = gc.isenabled()
    gc.enable()
    gc.collect()
    yield
    if not was:
        gc.disable()


def test_a_dropped_ring_waits_for_a_full_collection_without_the_block(collector_on):
    full = _full_collections()
    ring = _ring(50_000)
    if _full_collections() != full:
        pytest.skip("a full collection ran meanwhile: nothing to compare against")
    assert ring() is not None  # promoted while built: only a full collection frees it
    gc.collect()
    assert ring() is None


def test_the_block_frees_a_dropped_ring_at_its_end(collector_on):
    with freed_when_done():
        ring = _ring(50_000)
        assert ring() is not None  # nothing collected inside the block
    assert ring() is None
    assert gc.isenabled()


def test_a_saved_figure_is_freed_at_the_end_of_the_block(collector_on):
    from matplotlib.figure import Figure

    def saved() -> weakref.ref:
        fig = Figure(figsize=(12, 4), dpi=100)
        axes = fig.subplots(1, 3)
        for ax in axes:
            ax.plot(np.arange(256), np.linspace(0.0, 8.0, 256), label="unit")
            ax.legend(fontsize=6)
        fig.tight_layout()
        fig.savefig(io.BytesIO(), format="png")
        return weakref.ref(fig)

    with freed_when_done():
        fig = saved()
    assert fig() is None


def test_an_object_still_referenced_survives(collector_on):
    with freed_when_done():
        kept = Node()
        kept.next = kept
    assert kept.next is kept


def test_a_disabled_collector_stays_disabled():
    was = gc.isenabled()
    gc.disable()
    try:
        with freed_when_done():
            ring = _ring(1000)
        assert not gc.isenabled()
        assert ring() is not None  # the caller turned collection off: nothing collected
    finally:
        gc.collect()
        if was:
            gc.enable()


def test_nested_blocks_enable_the_collector_only_at_the_outermost_end(collector_on):
    with freed_when_done():
        with freed_when_done():
            ring = _ring(1000)
        assert not gc.isenabled()
    assert gc.isenabled()
    assert ring() is None


def _live_figures() -> int:
    """Matplotlib figures the collector tracks now, unreachable or not (nothing collected)."""
    from matplotlib.figure import Figure

    return sum(isinstance(o, Figure) for o in gc.get_objects())


def test_a_committed_runs_report_figure_is_gone_when_the_tick_ends(tmp_path, hw, collector_on):
    """Through the daemon's own commit: a run's report plot is written and, as the tick that
    made it ends, no figure is left waiting for a full collection."""
    from daemon_harness import after_first_bundle, drop

    sim, cfg = hw
    svc, _ = after_first_bundle(tmp_path, cfg)
    gc.collect()
    drop(svc.cfg.light.inbox, "b2", lux=1500.0)
    svc.tick()
    run = svc.history.runs(1)[0]
    assert run.status == "ok" and run.plot_path and run.plot_path.endswith(".png")
    assert _live_figures() == 0
