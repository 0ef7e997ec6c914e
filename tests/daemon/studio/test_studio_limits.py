"""The studio's caps in process: their bounds, the cost of a characteristic and the refusal
of one beyond the cap, and the light sources kept within their caps (uploads dropped oldest
first with their files, panoramas unloaded least recently used first)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from grassd.daemon.studio.cost import JobTooCostly, check_cost, job_cost
from grassd.daemon.studio.inputs import StudioInputError, parse_condition
from grassd.daemon.studio.lights import Lights, LightSource
from grassd.daemon.studio.limits import BOUNDS, DEFAULT_LIMITS, StudioLimitError, StudioLimits


def test_every_cap_has_bounds_and_one_outside_them_is_refused_naming_it():
    assert set(BOUNDS) == {f.name for f in dataclasses.fields(StudioLimits)}
    for name, (lo, hi) in BOUNDS.items():
        assert lo <= getattr(DEFAULT_LIMITS, name) <= hi, name
        with pytest.raises(StudioLimitError, match=f"studio's {name} is .*from {lo} to {hi}"):
            StudioLimits(**{name: hi * 2 + 1})
    with pytest.raises(StudioLimitError, match="connections is True"):
        StudioLimits(connections=True)


def _cond(**kw):
    data = {"ambient_lux": 5000.0, "viewpoint": [170, 2, 0], **kw}
    return parse_condition(data, green_max_mm=20.0, timezone="UTC", lights={"f"},
                           default_light="f")


def test_a_characteristic_costs_its_lengths_by_its_precision_by_sun_and_splay():
    lengths = [round(20 * i / 63, 3) for i in range(64)]
    assert job_cost(_cond(lengths_mm=[0, 5, 10]), 0.0) == pytest.approx(3)
    assert job_cost(_cond(lengths_mm=[0, 5, 10], target_stderr=0.05), 0.0) == pytest.approx(12)
    low_sun = dict(sun_lux=30000, sun_azimuth_deg=180, sun_elevation_deg=15)
    costly = _cond(lengths_mm=lengths, target_stderr=0.02, **low_sun)
    assert job_cost(costly, 45.0) == pytest.approx(64 * 25 * 2.3 * 2.5)
    assert job_cost(_cond(lengths_mm=lengths, sun_lux=0), 0.0) == pytest.approx(64)
    check_cost(_cond(lengths_mm=lengths, target_stderr=0.05, **low_sun), 45.0, 2000)
    with pytest.raises(JobTooCostly) as exc:
        check_cost(costly, 45.0, 2000, "this input")
    msg = str(exc.value)
    assert msg.startswith("this input would cost about 9200 units (64 lengths x (0.1 / 0.02 "
                          "dE00)^2 x 2.3 for the splay x 2.5 for the sun)")
    assert "runs at most 2000: ask for a target_stderr of at least 0.043 dE00 or at most 13 " \
           "lengths" in msg
    check_cost(_cond(lengths_mm=lengths, target_stderr=0.043, **low_sun), 45.0, 2000)


def _sky(path: Path, level: float) -> Path:
    from grassd.sim.hdri import write_hdr

    write_hdr(path, np.full((64, 128, 3), level, np.float32))
    return path


def test_uploads_beyond_the_cap_are_dropped_oldest_first_with_their_files(tmp_path):
    lights = Lights([LightSource("file", "f", _sky(tmp_path / "base.hdr", 1.0))],
                    limits=StudioLimits(kept_uploads=2))
    try:
        names, paths = [], []
        for i in range(4):
            path = lights.upload_path(f"sky{i}.hdr")
            _sky(path, 0.5 + i / 10)
            src, dropped = lights.add_upload(f"sky{i}.hdr", path)
            names.append(src.name)
            paths.append(path)
            assert dropped == ([] if i < 2 else [names[i - 2]])
        assert [s["name"] for s in lights.describe()] == ["file", *names[2:]]
        assert [p.exists() for p in paths] == [False, False, True, True]
        assert lights.holds(paths[3]) and not lights.holds(paths[0])
        bad = lights.upload_path("broken.exr")
        bad.write_bytes(b"not a panorama")
        with pytest.raises(StudioInputError, match="cannot use broken.exr as the light"):
            lights.add_upload("broken.exr", bad)
        assert not bad.exists() and len(lights.describe()) == 3
    finally:
        lights.cleanup()


def test_panoramas_beyond_the_cap_are_unloaded_least_recently_used_first(tmp_path):
    sources = [LightSource(f"s{i}", f"s{i}", _sky(tmp_path / f"s{i}.hdr", 1.0 + i))
               for i in range(3)]
    lights = Lights(sources, limits=StudioLimits(kept_maps=2))
    for name in ("s0", "s1", "s0", "s2"):
        assert lights.source(name).image is not None
    assert lights.loaded() == ["s0", "s2"]
    assert sources[1].image is None  # the least recently used, read again when chosen
    assert lights.source("s1").image is not None and lights.loaded() == ["s2", "s1"]
    lights.forget("s2")  # not an upload of this object's folder: its file stays
    assert lights.loaded() == ["s1"] and (tmp_path / "s2.hdr").exists()
    assert "s2" not in lights.names
