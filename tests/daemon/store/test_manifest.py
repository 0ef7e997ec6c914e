"""A bundle manifest is validated key by key; each bad value is named with its fix."""

from __future__ import annotations

from pathlib import Path
from zoneinfo import ZoneInfo

import pytest

from grassd.daemon.core.errors import ManifestError
from grassd.daemon.core.store.manifest import parse_manifest


def test_a_manifest_is_validated_and_every_bad_key_named():
    base = Path("/b")
    m = parse_manifest({"timestamp": "2026-01-01T10:00:00", "hdri": "a.hdr",
                        "ambient_lux": 500}, base, tz=ZoneInfo("UTC"))
    assert m.light.hdri == base / "a.hdr" and m.light.ambient_lux == 500.0 and m.timestamp.tzinfo
    bad = [
        ({"hdri": "a.exr"}, "timestamp: required key is missing"),
        ({"timestamp": "x", "hdri": "a.exr"}, "ISO 8601"),
        ({"timestamp": "2026-01-01T00:00:00Z", "hdri": "a.png"}, ".exr"),
        ({"timestamp": "2026-01-01T00:00:00Z", "hdri": "../a.exr"}, "plain file name"),
        ({"timestamp": "2026-01-01T00:00:00Z", "hdri": "a.exr", "ambient_lux": -5},
         "ambient_lux: -5 lux is impossible"),
        ({"timestamp": "2026-01-01T00:00:00Z", "hdri": "a.exr", "sun_azimuth_deg": 3},
         "both"),
        ({"timestamp": "2026-01-01T00:00:00Z", "hdri": "a.exr", "lux": 3}, "unknown"),
        ({"timestamp": "2026-01-01T00:00:00Z", "hdri": "a.exr", "ambient_lux": True}, "finite"),
    ]
    for data, words in bad:
        with pytest.raises(ManifestError, match=words.replace(".", r"\.")):
            parse_manifest(data, base)


@pytest.mark.parametrize("chart", ["/etc/passwd", "chart.csv", "../charts/mine.csv", "macbeth"])
def test_a_bundle_names_only_a_built_in_chart(chart):
    """A bundle's ``checker_chart`` never makes the daemon read a file: a path or an unknown
    name is refused by the parser, naming the built-in charts."""
    raw = {"timestamp": "2026-01-01T00:00:00Z", "hdri": "a.exr", "checker_raw": "c.dng",
           "checker_corners": [[0, 0], [10, 0], [10, 10], [0, 10]]}
    with pytest.raises(ManifestError, match="must be a built-in chart.*spydercheckr-24"):
        parse_manifest({**raw, "checker_chart": chart}, Path("/b"))
    m = parse_manifest({**raw, "checker_chart": "SpyderCheckr 24"}, Path("/b"))
    assert m.checker is not None and m.checker.chart == "SpyderCheckr 24"
