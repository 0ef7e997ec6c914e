"""The declared form of a sweep worker's answer (``ConditionResult`` through
daemon/compute/wire.py) and the checks on its arrival (``sweep.check_arrival``): a real
condition's result crosses msgpack unchanged; one tampered with on the way (another
condition, a length missing, other lengths, a NaN or an infinity, an extra field, bytes for an
array, a float32 array) is refused as :class:`ComputeResultRefused`; a declared error comes
back as its own type."""

from __future__ import annotations

import msgpack
import numpy as np
import pytest
from dask_cluster import tampered

from grassd.daemon.compute.wire import answer_of, error_answer, read_answer
from grassd.daemon.core.errors import ComputeResultRefused
from grassd.daemon.offline.sweep import (
    ConditionResult,
    SweepJob,
    SweepSpec,
    check_arrival,
    conditions,
    run_task,
    sweep_on_worker,
)
from grassd.sim.errors import LightingError

WHERE = "Dask worker tls://192.0.2.7:40000"
SPEC = SweepSpec(lengths_mm=(0.0, 10.0, 20.0), samples=128, replicates=2, latitude=48.1,
                 longitude=11.6, date="2026-03-20", timezone="Europe/Berlin")


@pytest.fixture(scope="module")
def conds(tmp_path_factory):
    from grassd.sim.hdri import write_exr

    env = np.ones((16, 32, 3), np.float32)
    env[:8] *= 2.5
    path = tmp_path_factory.mktemp("hdri") / "sky.exr"
    write_exr(path, env)
    return conditions([str(path)], ["13:00"], [(170, 2, 0), (150, 3, 45)])


@pytest.fixture(scope="module")
def run(conds):
    """A real condition's result and its answer as msgpack carries it."""
    result = run_task(SPEC, conds[0])
    wire = msgpack.unpackb(msgpack.packb(answer_of(result)), use_list=False)
    return result, wire




def test_a_result_crosses_unchanged(conds, run):
    result, wire = run
    back = read_answer(wire, ConditionResult, WHERE)
    check_arrival(SPEC, conds[0], back, WHERE)
    assert back.row() == result.row()
    assert back.ogcd.dtype == np.float64 and back.ogcd.shape == (3,)


def _array(a):
    a = np.asarray(a)
    return [a.dtype.str, list(a.shape), a.tobytes()]


@pytest.mark.parametrize(("change", "needle"), [
    (lambda r: r.update(ogcd=_array([0.0, np.nan, 2.0])), "ogcd holds entries that are not fin"),
    (lambda r: r.update(ogcd=_array(np.zeros(3, np.float32))), "ogcd has dtype '<f4'"),
    (lambda r: r.update(ogcd=b"\x80\x04K\x01."), "ogcd is bytes, not an array"),
    (lambda r: r.update(ogcd_range=float("inf")), "ogcd_range is infinite"),
    (lambda r: r.update(seed="1"), "seed is a str, not an integer"),
    (lambda r: r.update(extra=1), "is not a ConditionResult"),
])
def test_an_answer_out_of_the_declared_form_is_refused(run, change, needle):
    _, wire = run
    with pytest.raises(ComputeResultRefused, match=needle):
        read_answer(tampered(wire, change), ConditionResult, WHERE)


def test_an_answer_for_another_condition_is_refused(conds, run):
    """A worker answering the first condition's result when asked for the second."""
    _, wire = run
    back = read_answer(wire, ConditionResult, WHERE)
    with pytest.raises(ComputeResultRefused, match="is for another condition"):
        check_arrival(SPEC, conds[1], back, WHERE)


@pytest.mark.parametrize(("change", "needle"), [
    (lambda r: r.update(L=_array(np.zeros(2))), r"has L of shape \(2,\), not \(3,\)"),
    (lambda r: r.update(length_mm=_array([0.0, 10.0, 30.0])), "other lengths than the sweep's"),
    (lambda r: r.update(ogcd_range=float("nan")), "figures that are not finite"),
    (lambda r: r.update(linearity_r2=float("nan")), "figures that are not finite"),
])
def test_arrival_checks_refuse_what_the_form_lets_through(conds, run, change, needle):
    _, wire = run
    back = read_answer(tampered(wire, change), ConditionResult, WHERE)
    with pytest.raises(ComputeResultRefused, match=needle):
        check_arrival(SPEC, conds[0], back, WHERE)


def test_a_declared_error_comes_back_as_its_own_type():
    wire = msgpack.unpackb(msgpack.packb(error_answer(LightingError("no sky"))),
                           use_list=False)
    with pytest.raises(LightingError, match="no sky"):
        read_answer(wire, ConditionResult, WHERE)


def test_the_worker_answers_its_job_in_the_declared_form(conds, run):
    """The task a Dask worker runs answers msgpack's own types only."""
    result, _ = run
    answer = sweep_on_worker(SweepJob(SPEC, conds[0]))
    back = read_answer(msgpack.unpackb(msgpack.packb(answer)), ConditionResult, WHERE)
    assert {k: v for k, v in back.row().items() if k not in ("seconds", "worker")} == {
        k: v for k, v in result.row().items() if k not in ("seconds", "worker")}
