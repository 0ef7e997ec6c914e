"""A measurement's report (grassd.daemon.measure.report): JSON and HTML written
into the state directory for a successful and a failed measurement, hostile text escaped,
reports read back past a corrupt file, and the trend that shows the display fading."""

from __future__ import annotations

import json
import logging
import math
import re

import pytest
from headless_chromium import CHROMIUM, MISSING, Browser
from measurement_samples import failed_report, ok_report

from grassd.daemon.core.store.layout import StateLayout
from grassd.daemon.measure.report import load_reports, trend, write_report
from grassd.daemon.measure.report_page import grid_shape

EVIL = "camera <script>alert(1)</script>\n\x1b[2J"


def test_a_successful_report_round_trips_and_shows_its_verdict(tmp_path):
    layout = StateLayout(tmp_path / "state")
    rep = ok_report(shape=[2, 3])
    path = write_report(layout, rep)
    assert path == layout.measure / "20261127T235000Z.json"
    assert json.loads(path.read_text()) == rep
    assert layout.measurement_reports() == [path]
    page = path.with_suffix(".html").read_text()
    assert "<title>grassd measurement 20261127T235000Z: within tolerance</title>" in page
    assert "worst pixel pair 0.80 dE00 after correction" in page
    assert "3.88\u00d7" in page  # improvement factor
    for heading in ("Uniformity", "Camera, light and tables", "Pixels on the display",
                    "Pixels", "Characteristic: measured vs predicted",
                    "Trend over the measurements"):
        assert f"<h2>{heading}</h2>" in page
    # heat maps: three grids of 2 x 3 cells, one per quantity
    assert page.count('<svg class="heat"') == 3 and "2 \u00d7 3" in page
    assert page.count("<title>pixel 5:") == 3
    assert "pixel 5: +0.200" not in page and "pixel 5: 0.20" in page  # offset map
    assert "points: measured; dashed: model predicted" in page  # the characteristic plot
    assert "<script" not in page
    assert not re.search(r'(src|href)="', page)  # self-contained
    assert not list(layout.measure.glob(".*"))  # written atomically, no leftovers


def test_a_failed_report_escapes_its_error(tmp_path):
    layout = StateLayout(tmp_path / "state")
    path = write_report(layout, failed_report(error=EVIL))
    assert json.loads(path.read_text())["error"] == EVIL
    page = path.with_suffix(".html").read_text()
    assert "measurement 20261128T010000Z: failed" in page
    assert "<script" not in page and "\x1b" not in page
    assert "camera &lt;script&gt;alert(1)&lt;/script&gt;\n\\x1b[2J" in page
    assert "No successful measurement yet." in page
    rep = failed_report(mid="20261128T020000Z") | {"status": "interrupted",
                                                   "error": "measurement stopped"}
    page = write_report(layout, rep).with_suffix(".html").read_text()
    assert "measurement 20261128T020000Z: interrupted" in page


def test_nan_is_written_as_null_and_a_bad_id_refused(tmp_path, caplog):
    layout = StateLayout(tmp_path / "state")
    rep = ok_report()
    rep["pixels"][2]["rms_lab"] = math.nan
    rep["uniformity"]["improvement"] = math.inf
    with caplog.at_level(logging.WARNING):
        path = write_report(layout, rep)
    back = json.loads(path.read_text())
    assert back["pixels"][2]["rms_lab"] is None and back["uniformity"]["improvement"] is None
    assert "2 non-finite number(s)" in caplog.text
    with pytest.raises(ValueError):
        write_report(layout, failed_report(mid="../escape"))


def test_trend_shows_the_gains_drifting_over_months(tmp_path):
    layout = StateLayout(tmp_path / "state")
    months = [("20260115T120000Z", 1.00, 1.00, 0.1, 0.6),
              ("20260415T120000Z", 0.97, 1.02, 0.3, 0.8),
              ("20260715T120000Z", 0.93, 1.05, 0.6, 1.4)]
    for mid, g, y, off, after in months:
        write_report(layout, ok_report(mid, green=g, yellow=y, offset=off, after=after))
    write_report(layout, failed_report())  # not a trend point
    reports = load_reports(layout)
    assert [r["measurement"] for r in reports] == [m[0] for m in months] + ["20261128T010000Z"]
    pts = trend(reports)
    assert [p["measurement"] for p in pts] == [m[0] for m in months]
    greens = [p["green_gain"] for p in pts]
    yellows = [p["yellow_gain"] for p in pts]
    offsets = [p["abs_offset_mm"] for p in pts]
    assert greens == sorted(greens, reverse=True) and greens[-1] == pytest.approx(0.93)
    assert yellows == sorted(yellows) and yellows[-1] == pytest.approx(1.05 - 0.005)
    assert offsets == sorted(offsets)
    assert [p["after_de00"] for p in pts] == [0.6, 0.8, 1.4]
    assert [p["verdict"] for p in pts] == ["within tolerance"] * 2 + ["recalibrate"]
    assert pts[0]["started_at"] == "2026-01-15T12:00:00+00:00"
    # the latest successful report's page shows the trend (plots and table)
    page = (layout.measure / "20260715T120000Z.html").read_text()
    assert "recalibrate" in page and page.count("<polyline") >= 5
    assert "\u25b6 20260715T120000Z" in page  # this measurement marked in the trend table
    assert load_reports(layout, limit=2)[0]["measurement"] == "20260715T120000Z"


def test_load_reports_skips_a_corrupt_file(tmp_path, caplog):
    layout = StateLayout(tmp_path / "state")
    write_report(layout, ok_report("20260101T000000Z"))
    (layout.measure / "20260201T000000Z.json").write_text('{"measurement": "2026')
    (layout.measure / "20260301T000000Z.json").write_text("[1, 2]")
    write_report(layout, ok_report("20260401T000000Z"))
    with caplog.at_level(logging.WARNING):
        reports = load_reports(layout)
    assert [r["measurement"] for r in reports] == ["20260101T000000Z", "20260401T000000Z"]
    assert reports[0]["report"] == str(layout.measure / "20260101T000000Z.json")
    assert "20260201T000000Z.json skipped" in caplog.text
    assert "20260301T000000Z.json skipped" in caplog.text
    assert load_reports(StateLayout(tmp_path / "nothing")) == []


def test_grid_shape_and_a_report_missing_most_keys(tmp_path):
    assert grid_shape(6, [2, 3]) == (2, 3) and grid_shape(6, [4, 4]) == (1, 6)
    assert grid_shape(6, None) == (1, 6) and grid_shape(0) == (1, 1)
    layout = StateLayout(tmp_path / "state")
    rep = {"measurement": "20260101T000000Z", "status": "ok",
           "pixels": [{"index": 0, "green_gain": "x"}], "uniformity": {"before": None},
           "characteristic": {"lengths_mm": [1.0], "measured_ogcd": [[None]]}}
    page = write_report(layout, rep).with_suffix(".html").read_text()
    assert "measurement 20260101T000000Z: no verdict" in page


def test_a_report_the_page_cannot_render_still_gets_a_page_saying_so(tmp_path, monkeypatch,
                                                                     caplog):
    from grassd.daemon.measure import report_page

    def broken(report, past):
        raise KeyError("camera")

    monkeypatch.setattr(report_page, "render_report", broken)
    path = write_report(StateLayout(tmp_path / "state"), ok_report("20260101T000000Z"))
    page = path.with_suffix(".html").read_text()
    assert "could not be rendered: &#x27;camera&#x27;" in page and path.name in page
    assert json.loads(path.read_text())["measurement"] == "20260101T000000Z"
    assert "HTML report not rendered" in caplog.text


@pytest.mark.skipif(CHROMIUM is None, reason=MISSING)
def test_report_renders_in_headless_chromium(tmp_path):
    layout = StateLayout(tmp_path / "state")
    write_report(layout, ok_report("20260101T000000Z", green=0.99, after=0.7))
    path = write_report(layout, ok_report(shape=[2, 3], after=1.3))
    with Browser() as browser:
        tab = browser.open(path.with_suffix(".html").as_uri(), width=390, mobile=True)
        assert tab.problems() == []
        assert tab.evaluate("document.title") == \
            "grassd measurement 20261127T235000Z: recalibrate"
        assert tab.evaluate("document.querySelectorAll('svg.heat rect').length") == 18
        assert tab.evaluate("document.documentElement.scrollWidth") <= 390
