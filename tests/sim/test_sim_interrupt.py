"""Stopping a launch in flight (``grassd.sim.interrupt``): a launch skips its remaining paths
once its word changes, and the renderer traces it anew or ends the run as the interrupt says."""

# (no "from __future__ import annotations": Taichi reads kernel annotations as objects)

import subprocess
import sys

import numpy as np
import pytest

from grassd.sim.errors import SimError
from grassd.sim.interrupt import Interrupt
from grassd.sim.lighting import build_lighting
from grassd.sim.scene import DisplaySpec, RenderSettings, Viewpoint

LENGTHS = np.linspace(0.0, 20.0, 11)


class Stopped(Exception):
    pass


class Scripted(Interrupt):
    """Arms each launch with the next of ``bases`` (then the word itself); raises Stopped at
    call number ``stop_at``."""

    def __init__(self, word, bases=(), stop_at=None):
        super().__init__(word)
        self.bases = list(bases)
        self.stop_at = stop_at
        self.calls = 0

    def arm(self):
        self.calls += 1
        if self.calls == self.stop_at:
            raise Stopped
        return self.bases.pop(0) if self.bases else int(self.word[0])


@pytest.fixture
def lighting(shared_hdri):
    return build_lighting(shared_hdri("courtyard"), ambient_lux=5000)


@pytest.fixture
def launches(renderer):
    """Sets the shared renderer's launch sizes (other tests change them too) and restores
    them, with no interrupt, afterwards: ``launches(fewest)`` (no most)."""
    kept = renderer.min_launch_paths, renderer.max_launch_paths

    def set_fewest(fewest: int) -> None:
        renderer.launch_paths(fewest)

    yield set_fewest
    renderer.launch_paths(*kept)
    renderer.interrupt = None


def test_a_launch_armed_with_a_stale_word_is_traced_anew_with_the_same_numbers(
        renderer, lighting, launches):
    launches(1 << 17)
    s = RenderSettings(samples=256, replicates=4, seed=5)
    vp = Viewpoint(170, 2, 5)
    plain = renderer.characteristic(DisplaySpec(), lighting, vp, LENGTHS, s)
    stale = Scripted(np.array([7], np.int32), bases=[6])  # the first launch skips every path
    renderer.interrupt = stale
    try:
        again = renderer.characteristic(DisplaySpec(), lighting, vp, LENGTHS, s)
    finally:
        renderer.interrupt = None
    assert stale.calls == 2  # one launch, armed again after it skipped its paths
    np.testing.assert_array_equal(again.rgb_replicates, plain.rgb_replicates)
    assert again.paths_traced == plain.paths_traced


def test_each_launch_is_armed_and_a_raising_interrupt_ends_the_run(renderer, lighting,
                                                                   launches):
    s = RenderSettings(samples=256, replicates=8, seed=5)
    launches(512)  # launches of 2 replicates: 4 launches
    word = np.array([0], np.int32)
    counted = Scripted(word)
    renderer.interrupt = counted
    try:
        renderer.characteristic(DisplaySpec(), lighting, Viewpoint(170, 2, 5), LENGTHS, s)
        assert counted.calls == 4
        renderer.interrupt = Scripted(word, stop_at=3)
        with pytest.raises(Stopped):
            renderer.characteristic(DisplaySpec(), lighting, Viewpoint(170, 2, 5), LENGTHS, s)
        renderer.interrupt = Scripted(word, bases=[1], stop_at=2)  # stale, then stopped
        with pytest.raises(Stopped):
            renderer.preview(DisplaySpec(), lighting, Viewpoint(170, 2, 5), 10.0, width=32,
                             spp=1)
        assert int(renderer.skipped[None]) == 32 * 32  # the stale launch drew no pixel
    finally:
        renderer.interrupt = None


def test_a_launch_another_process_stops_is_finished_with_the_uninterrupted_numbers(
        renderer, lighting, launches, tmp_path):
    """A second process writes the word (a shared file mapping) 0.05 s after the launch is
    armed, into a launch of 262144 paths (about 1.4 s on 2 cores): the launch skips the rest of
    its paths; its later tries skip or trace only those, and the launch gives the numbers, and
    the path count, of the launch uninterrupted."""
    launches(1 << 20)
    s = RenderSettings(samples=65536, replicates=4, seed=1)  # one launch of 262144 paths
    vp = Viewpoint(170, 2, 5)
    plain = renderer.characteristic(DisplaySpec(), lighting, vp, LENGTHS, s)
    path = tmp_path / "word"
    path.write_bytes(bytes(4))
    word = np.memmap(path, dtype=np.int32, mode="r+", shape=(1,))
    writer = subprocess.Popen(
        [sys.executable, "-c", (
            "import sys, time\n"
            "import numpy as np\n"
            f"w = np.memmap({str(path)!r}, dtype=np.int32, mode='r+', shape=(1,))\n"
            "print('ready', flush=True); sys.stdin.readline(); time.sleep(0.05)\n"
            "w[0] = 1\n"
            "w.flush()\n")],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    assert writer.stdout.readline().strip() == "ready"

    class Timed(Scripted):
        """Starts the writer's clock when the launch is armed; then arms it once more under the
        old word (every path not yet traced is skipped again), then under the new one; notes
        what each try skipped."""

        def __init__(self, word):
            super().__init__(word)
            self.skips = []

        def arm(self):
            if self.calls == 0:
                writer.stdin.write("go\n")
                writer.stdin.flush()
            else:
                self.skips.append(int(renderer.skipped[None]))
            self.calls += 1
            return 0 if self.calls <= 2 else int(self.word[0])

    timed = Timed(np.ndarray((1,), np.int32, buffer=word))
    renderer.interrupt = timed
    try:
        again = renderer.characteristic(DisplaySpec(), lighting, vp, LENGTHS, s)
    finally:
        renderer.interrupt = None
        writer.wait(timeout=30)
    assert int(word[0]) == 1 and timed.calls == 3
    assert 0 < timed.skips[0] < 4 * 65536  # stopped part-way through
    assert timed.skips[1] == timed.skips[0]  # a try skips only what no try has traced
    np.testing.assert_array_equal(again.rgb_replicates, plain.rgb_replicates)
    assert again.paths_traced == plain.paths_traced  # each path traced once


def test_an_interrupt_word_must_be_one_int32():
    with pytest.raises(SimError, match="int32"):
        Interrupt(np.zeros(1, np.int64))
    with pytest.raises(SimError, match="shape"):
        Interrupt(np.zeros(2, np.int32))


def test_a_renderer_whose_kernels_do_not_read_host_memory_ignores_its_interrupt(
        renderer, lighting, launches, monkeypatch):
    """On a GPU a kernel would read a copy of the word (and write it back after): there the
    interrupt is not armed and launches run to their end. The CPU backend reads it in place."""
    from grassd.sim import backend

    assert backend.runs_on_host() and renderer.interruptible
    launches(1 << 17)
    monkeypatch.setattr(type(renderer), "interruptible", property(lambda self: False))
    never = Scripted(np.array([7], np.int32), bases=[6], stop_at=1)  # would stop the run
    renderer.interrupt = never
    m = renderer.characteristic(DisplaySpec(), lighting, Viewpoint(170, 2, 5), LENGTHS,
                                RenderSettings(samples=256, replicates=2, seed=5))
    assert never.calls == 0 and m.paths_traced > 0


def test_a_launch_under_an_interrupt_compiles_no_kernel_anew():
    """Taichi compiles a kernel once per kind of array argument: the word a launch without an
    interrupt reads is of the interrupt word's kind (a NumPy array) on the CPU, so the
    studio's first launch under an interrupt, after its warm-up without one, compiles nothing
    (with a device array there it compiled the trace kernel again: 0.85 s more). In a process
    of its own: the session's renderer has compiled both kinds already."""
    script = (
        "import numpy as np\n"
        "from grassd.sim import backend\n"
        "backend.init('cpu')\n"
        "from grassd.sim.interrupt import Interrupt\n"
        "from grassd.sim.lighting import build_lighting\n"
        "from grassd.sim.renderer import Renderer\n"
        "from grassd.sim.scene import DisplaySpec, RenderSettings, Viewpoint\n"
        "env = np.random.default_rng(3).uniform(0.2, 2.0, (32, 64, 3)).astype(np.float32)\n"
        "light = build_lighting(env, 5000.0)\n"
        "r = Renderer.shared()\n"
        "s = RenderSettings(samples=256, replicates=2, seed=5)\n"
        "args = (DisplaySpec(), light, Viewpoint(170, 2, 5), np.linspace(0, 20, 3), s)\n"
        "compiled = Renderer._trace_kernel._primal.compiled_kernels\n"
        "r.characteristic(*args)\n"
        "before = len(compiled)\n"
        "r.interrupt = Interrupt(np.zeros(1, np.int32))\n"
        "r.characteristic(*args)\n"
        "print('kernels', before, len(compiled))\n")
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          timeout=600, check=True)
    counts = [line for line in done.stdout.splitlines() if line.startswith("kernels")]
    assert counts, done.stdout + done.stderr
    _, before, after = counts[-1].split()
    assert int(before) >= 1 and after == before
