"""The declared form of a worker's answer (daemon/compute/wire.py) and the checks on its
arrival (``remote.check_arrival``): a real local run's result crosses it unchanged; an answer
tampered with on the way (dtype, size, non-finite entries, extra fields, infinities, text for
numbers, an error type nobody declared, tables the run would have rejected) is refused as
:class:`ComputeResultRefused`, and a declared error comes back as its own type."""

from __future__ import annotations

import enum
import json
from dataclasses import dataclass, replace
from typing import Literal, NotRequired, Required, TypedDict

import msgpack
import numpy as np
import pytest
from dask_cluster import tampered
from test_remote_calibration import LIGHT, SMALL, _without_timings

from grassd.daemon.compute.remote import check_arrival
from grassd.daemon.compute.wire import answer_of, error_answer, read_answer
from grassd.daemon.core.calibration.calibrate import Calibrator, init_backend
from grassd.daemon.core.calibration.result import CalibrationResult
from grassd.daemon.core.config.settings import parse_config
from grassd.daemon.core.errors import ComputeResultRefused
from grassd.sim.errors import LightingError, SimError

WHERE = "Dask worker tls://192.0.2.7:40000"


@pytest.fixture(scope="module")
def cfg(tmp_path_factory):
    c = parse_config(SMALL, base_dir=tmp_path_factory.mktemp("wire"))
    init_backend(c)
    return c


@pytest.fixture(scope="module")
def run(cfg):
    """A real run's result and its answer as msgpack carries it (lists come back as tuples)."""
    result = Calibrator(cfg).run(LIGHT)
    wire = msgpack.unpackb(msgpack.packb(answer_of(result)), use_list=False)
    return result, wire




def test_a_result_crosses_unchanged(cfg, run):
    result, wire = run
    back = read_answer(wire, CalibrationResult, WHERE)
    assert np.array_equal(back.table_um, result.table_um) and back.table_um.dtype == np.uint16
    assert (json.dumps(_without_timings(back.report()), sort_keys=True)
            == json.dumps(_without_timings(result.report()), sort_keys=True))
    check_arrival(cfg, back, WHERE, previous_um=result.table_um)


def _set_array(name, dtype=None, data=None, shape=None):
    def change(r):
        d, s, b = r[name]
        r[name] = [dtype or d, shape if shape is not None else s,
                   data if data is not None else b]
    return change


def _nan_in_characteristic(r):
    d, s, b = r["units"][0]["characteristic"]["ogcd"]
    a = np.frombuffer(b, d).copy()
    a[1] = np.nan
    r["units"][0]["characteristic"]["ogcd"] = [d, s, a.tobytes()]


@pytest.mark.parametrize(("change", "reason"), [
    (_set_array("table_um", dtype="<f8"), "table_um has dtype '<f8', not '<u2'"),
    (_set_array("table_um", data=b"\0" * 10), "table_um has 10 bytes for the shape (256,)"),
    (_set_array("table_um", shape=[16, 16, 1, 1]), "table_um has the shape"),
    (_nan_in_characteristic, "units[0].characteristic.ogcd holds entries that are not finite"),
    (lambda r: r["units"][0].update(evil=1), "units[0] is not a UnitTable"),
    (lambda r: r.update(table_um=[b"\x80\x04K\x01."]), "table_um is list, not an array"),
    (lambda r: r["units"][0].update(max_error=float("inf")), "units[0].max_error is infinite"),
    (lambda r: r["units"][0].update(r2_after="0.99"), "units[0].r2_after is a str, not a num"),
    (lambda r: r.update(grouping={"groups_checked": b"\x80\x04"}),
     "grouping['groups_checked'] is a bytes, not an integer"),
    (lambda r: r.update(grouping={"groups_checked": 1, "x": 1.0}),
     "grouping is not a GroupingSummary"),
    (lambda r: r.update(shape=[2]), "shape has 1 entries, not 2"),
])
def test_a_tampered_result_is_refused(run, change, reason):
    with pytest.raises(ComputeResultRefused) as exc:
        read_answer(tampered(run[1], change), CalibrationResult, WHERE)
    assert str(exc.value).startswith(f"{WHERE} answered a result whose ")
    assert reason in str(exc.value)


@pytest.mark.parametrize("answer", [b"\x80\x04K\x01.", [1, 2], {"result": 1, "error": 2},
                                    {"results": {}}, {"error": {"kinds": []}}])
def test_what_is_no_answer_is_refused(answer):
    with pytest.raises(ComputeResultRefused, match=WHERE):
        read_answer(answer, CalibrationResult, WHERE)


def test_a_declared_error_comes_back_as_its_type_and_others_do_not():
    err = error_answer(LightingError("the sun is below the horizon"))
    assert err["error"]["kinds"][:2] == ["grassd.sim.errors.LightingError",
                                         "grassd.sim.errors.SimError"]
    with pytest.raises(LightingError, match="^the sun is below the horizon$"):
        read_answer(err, CalibrationResult, WHERE)
    # a class named by the worker but never declared (here: os.system) is not looked up
    forged = {"error": {"kinds": ["os.system", "builtins.eval"], "type": "system",
                        "message": "id"}}
    with pytest.raises(ComputeResultRefused, match="the run failed on .*: system: id"):
        read_answer(forged, CalibrationResult, WHERE)
    other = error_answer(MemoryError("no room"))
    assert other["error"]["kinds"] == []
    with pytest.raises(ComputeResultRefused, match="MemoryError: no room"):
        read_answer(other, CalibrationResult, WHERE)
    assert not issubclass(ComputeResultRefused, SimError)


def test_tables_the_run_would_reject_are_refused_on_arrival(cfg, run):
    result = read_answer(run[1], CalibrationResult, WHERE)

    def with_table(t):
        return read_answer(tampered(run[1], lambda r: r.update(
            table_um=["<u2", [256], np.asarray(t, np.uint16).tobytes()])),
            CalibrationResult, WHERE)

    falling = with_table(np.linspace(20000, 0, 256))
    with pytest.raises(ComputeResultRefused, match="its display table is not monotone"):
        check_arrival(cfg, falling, WHERE)
    too_long = with_table(np.full(256, 60000))
    with pytest.raises(ComputeResultRefused, match="its display table leaves the range 0.."):
        check_arrival(cfg, too_long, WHERE)
    strict = cfg.replace(calibration=replace(cfg.calibration, max_jump_mm=1.0))
    far = with_table(np.linspace(0, 1000 * cfg.display.green_max_mm, 256))
    with pytest.raises(ComputeResultRefused, match="differs from the active one by up to"):
        check_arrival(strict, far, WHERE, previous_um=np.zeros(256, np.uint16))
    check_arrival(strict, far, WHERE, previous_um=np.zeros(256, np.uint16), force=True)
    stranger = read_answer(tampered(run[1], lambda r: r["controller_tables"].update(
        {"/dev/ttyEVIL": ["<u2", [256], result.table_um.tobytes()]})), CalibrationResult, WHERE)
    with pytest.raises(ComputeResultRefused, match="controllers that are not configured"):
        check_arrival(cfg, stranger, WHERE)
    other = read_answer(tampered(run[1], lambda r: r.update(granularity="pixel")),
                        CalibrationResult, WHERE)
    with pytest.raises(ComputeResultRefused, match="has granularity 'pixel'"):
        check_arrival(cfg, other, WHERE)


#: an audience region in front of the 2 x 2 display (m, cm)
AUDIENCE = ('[audience]\npolygon = [[-1.0, 1.5], [1.0, 1.5], [1.0, 3.0], [-1.0, 3.0]]\n'
            'h_cm = [150, 180]\nground_samples = 3\nheight_samples = 2\n')


@pytest.mark.parametrize("extra", ['[tables]\ngranularity = "controller"\n',
                                   '[tables]\ngranularity = "pixel"\neye = "pixel"\n', AUDIENCE],
                         ids=["controller", "pixel", "audience"])
def test_every_kind_of_run_crosses_unchanged(extra, tmp_path):
    """Runs with tables per controller, per pixel and from a region (their grouping and region
    summaries are plain data) cross the declared form and pass the arrival checks."""
    c = parse_config(SMALL + extra, base_dir=tmp_path)
    init_backend(c)
    result = Calibrator(c).run(LIGHT, force=True)
    wire = msgpack.unpackb(msgpack.packb(answer_of(result)), use_list=False)
    back = read_answer(wire, CalibrationResult, WHERE)
    check_arrival(c, back, WHERE)
    assert back.controller_tables.keys() == result.controller_tables.keys()
    assert all(np.array_equal(back.controller_tables[k], t)
               for k, t in result.controller_tables.items())
    assert (json.dumps(_without_timings(back.report()), sort_keys=True)
            == json.dumps(_without_timings(result.report()), sort_keys=True))


class _Verdict(enum.Enum):
    KEPT = "kept"
    REFUSED = "refused"


class _Summary(TypedDict):
    mean_de00: float
    worst: NotRequired[int]


@dataclass(frozen=True)
class _Typed:
    summary: _Summary
    verdict: _Verdict
    side: Literal["left", "right"]


def _crossed(value):
    return msgpack.unpackb(msgpack.packb(answer_of(value)), use_list=False)


def test_typed_dicts_enums_and_literals_cross_as_declared():
    value = _Typed({"mean_de00": 0.4}, _Verdict.REFUSED, "left")
    assert read_answer(_crossed(value), _Typed, WHERE) == value
    full = _Typed({"mean_de00": 0.4, "worst": 3}, _Verdict.KEPT, "right")
    assert read_answer(_crossed(full), _Typed, WHERE) == full


@pytest.mark.parametrize("field, bad, reason", [
    ("summary", {"mean_de00": 0.4, "extra": 1}, "keys"),
    ("summary", {"worst": 3}, "required"),
    ("summary", {"mean_de00": "0.4"}, "not a number"),
    ("verdict", "lost", "not a _Verdict"),
    ("side", "up", "not one of"),
    ("side", 1, "not one of"),
])
def test_a_tampered_typed_field_is_refused(field, bad, reason):
    wire = {"result": {**_crossed(_Typed({"mean_de00": 0.4}, _Verdict.KEPT, "left"))["result"],
                       field: bad}}
    with pytest.raises(ComputeResultRefused, match=reason):
        read_answer(wire, _Typed, WHERE)


class _Partial(TypedDict, total=False):
    note: str
    count: Required[int]


def test_a_partial_typed_dict_needs_only_its_required_keys():
    assert read_answer(_crossed({"count": 2}), _Partial, WHERE) == {"count": 2}
    with pytest.raises(ComputeResultRefused, match="required"):
        read_answer(_crossed({"note": "x"}), _Partial, WHERE)
