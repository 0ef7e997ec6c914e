"""The TOML the daemon writes with tomli-w (a capture bundle's manifest.toml, a validation
capture.toml) reads back with :mod:`tomllib` to the same values, whatever text a camera reports
or a path holds: quotes, backslashes, control characters, characters beyond the Basic
Multilingual Plane."""

from __future__ import annotations

import math
import tomllib
from pathlib import Path

import tomli_w
from hypothesis import given
from hypothesis import strategies as st

from grassd.daemon.capture.station import manifest_toml
from grassd.daemon.offline.validate import (
    CaptureManifest,
    Photo,
    Series,
    load_manifest,
    manifest_to_toml,
)
from grassd.sim.light_input import LightInput

AWKWARD = ['THETA Z1 \U0001F600', 'a "quoted" \\ name', "line\nbreak\ttab\r\x07\x1f\x7f", "é"]
QUAD = ((10.0, 12.0), (54.0, 12.0), (56.0, 50.0), (8.0, 50.0))

# Subnormal floats are left out: once a Taichi kernel has run in a process (the daemon renders
# in its own), Taichi's CPU runtime has set denormals-are-zero for the thread, and float() --
# hence tomllib -- reads 1e-308 back as 0.0, whoever wrote the text.
_scalars = (st.text() | st.booleans() | st.integers(-2**63, 2**63 - 1)
            | st.floats(allow_nan=False, allow_subnormal=False))
_values = st.recursive(
    _scalars, lambda inner: st.lists(inner, max_size=4)
    | st.dictionaries(st.from_regex(r"[A-Za-z_][A-Za-z0-9_]{0,8}", fullmatch=True), inner,
                      max_size=4), max_leaves=12)


@given(_values)
def test_any_value_reads_back_the_same(value):
    assert tomllib.loads(tomli_w.dumps({"x": value}))["x"] == value


def test_non_finite_floats_read_back():
    back = tomllib.loads(tomli_w.dumps({"x": [math.inf, -math.inf, math.nan]}))["x"]
    assert back[:2] == [math.inf, -math.inf] and math.isnan(back[2])


def test_capture_manifest_keeps_the_cameras_strings():
    manifest = {"timestamp": "2026-06-21T12:00:00+00:00", "ambient_lux": 812.5,
                "capture": {"camera_model": AWKWARD[0], "camera_serial": AWKWARD[1],
                            "camera_firmware": AWKWARD[2], "camera_manufacturer": AWKWARD[3],
                            "exposures_s": [0.001, 0.004], "sun_clipped": True}}
    assert tomllib.loads(manifest_toml(manifest)) == manifest


def test_capture_toml_keeps_awkward_paths(tmp_path):
    root = tmp_path
    names = [f"p{i} {s}.dng" for i, s in enumerate(AWKWARD[:2] + ["new\nline", "é"])]
    photos = tuple(Photo(root / n, float(i), QUAD) for i, n in enumerate(names))
    m = CaptureManifest(root=root, light=LightInput(root / 'env "sky".exr', 500.0),
                        checker_photo=root / "checker\\1.dng", checker_corners=QUAD,
                        series=(Series((170.0, 2.0, 0.0), photos, True),))
    text = manifest_to_toml(m)
    (root / "capture.toml").write_text(text, encoding="utf-8")
    data = tomllib.loads(text)
    assert data["hdri"] == 'env "sky".exr'
    assert data["checker_raw"] == "checker\\1.dng"
    assert [p["file"] for p in data["series"][0]["photos"]] == names
    for n in names + ['env "sky".exr', "checker\\1.dng"]:
        (root / n).write_bytes(b"")
    assert [Path(p).name for p in load_manifest(root).photos()[1:]] == names
