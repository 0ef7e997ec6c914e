"""The status page (reports/index.html) written by the daemon after its runs (real renderer,
SQLite, simulated controllers on ptys), opened from file:// in headless Chromium at a desktop
and a phone width: no console errors, embedded plots decode, nothing wider than a phone,
screenshots written."""

from __future__ import annotations

import re

import pytest
from daemon_harness import drop, service, write_config
from headless_chromium import CHROMIUM, MISSING, Browser

from grassd.daemon.core.store.layout import PAGE_NAME


@pytest.fixture
def page_after_runs(tmp_path, hw):
    """A daemon after three applied bundles under different light, a rejected and a quarantined
    bundle, with one controller unplugged at the end: returns (its status page, service)."""
    sim, cfg = hw
    svc = service(write_config(tmp_path / "g.toml", tmp_path / "state", cfg))
    for i, lux in enumerate((800.0, 3000.0, 12000.0)):
        drop(svc.cfg.light.inbox, f"b{i}", lux=lux, timestamp=f"2026-03-0{i + 1}T12:00:00Z")
        svc.tick()
    bad = svc.cfg.light.inbox / ".bad"
    bad.mkdir()
    (bad / "sky.exr").write_bytes(b"not an EXR <script>alert(1)</script>")
    (bad / "manifest.toml").write_text('timestamp = 2026-03-05T12:00:00Z\nhdri = "sky.exr"\n')
    bad.rename(svc.cfg.light.inbox / "bad")
    drop(svc.cfg.light.inbox, "poison", lux=500.0, timestamp="2026-03-06T12:00:00Z")
    [poison] = svc.inbox.poll()
    for _ in range(svc.inbox.max_attempts):
        svc.inbox.begin(poison)
    svc.inbox.recover()
    svc.tick()
    sim.buses[1].unplug(down_s=30.0)
    svc.reconcile()  # the controller's state changed: the page is written again
    page = svc.reports_dir / PAGE_NAME
    assert page.is_file()
    yield page, svc
    svc.shutdown()


def test_page_holds_every_section(page_after_runs):
    page, svc = page_after_runs
    text = page.read_text()
    assert '<meta name="viewport" content="width=device-width, initial-scale=1">' in text
    headings = ("Active table", "Display measurement", "Controllers", "Serial lines",
                "Last runs", "Trends", "Rejected and quarantined bundles")
    at = [text.index(f"<h2>{heading}</h2>") for heading in headings]
    assert at == sorted(at), at  # the measure feature's card after the active table
    for port in svc.status().daemon.lines:  # each bus the daemon used, with its verdict
        assert re.search(rf'<td data-label="port">{re.escape(port)}</td>'
                         r'<td data-label="line"[^>]*>(good|noisy|failing)</td>', text), port
    assert "grassd: degraded" in text and "unreachable" in text
    assert text.count("data:image/png;base64,") == 1 and text.count("<svg") == 3
    assert "abandoned after 3 attempts" in text and ">quarantined<" in text
    assert "<script" not in text  # a reason is text, never markup
    assert not re.search(r'(src|href)="(?!data:)', text)  # self-contained
    assert not list(page.parent.glob(".index.html*"))  # written atomically, no leftovers


@pytest.mark.skipif(CHROMIUM is None, reason=MISSING)
@pytest.mark.parametrize("width,mobile", [(1280, False), (390, True)], ids=["desktop", "phone"])
def test_page_in_headless_chromium(page_after_runs, tmp_path, width, mobile):
    page, _ = page_after_runs
    with Browser() as browser:
        tab = browser.open(page.as_uri(), width=width, mobile=mobile)
        assert tab.problems() == []
        assert tab.evaluate("document.title") == "grassd: degraded"
        assert tab.evaluate("Array.from(document.images).length") == 1
        assert tab.evaluate("Array.from(document.images).every("
                            "i => i.complete && i.naturalWidth > 100)")
        assert tab.evaluate("document.querySelectorAll('svg polyline').length") == 3
        # nothing sticks out sideways: wide tables scroll inside their own box
        assert tab.evaluate("document.documentElement.scrollWidth") <= width
        shot = tab.screenshot(tmp_path / f"status-{width}.png")
    data = shot.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    assert int.from_bytes(data[16:20], "big") == width
    assert int.from_bytes(data[20:24], "big") > 600  # the whole page, not one screen


@pytest.mark.skipif(CHROMIUM is None, reason=MISSING)
def test_the_browser_check_sees_console_errors(tmp_path):
    """The check above can fail: a page with a console error, an uncaught exception and a
    missing image is reported as such."""
    bad = tmp_path / "bad.html"
    bad.write_text('<!DOCTYPE html><html><head><meta charset="utf-8"></head><body>'
                   '<img src="missing.png"><script>console.error("boom"); nosuchfunction();'
                   "</script></body></html>")
    with Browser() as browser:
        problems = browser.open(bad.as_uri(), width=800).problems()
    text = "\n".join(problems)
    assert "boom" in text and "nosuchfunction" in text and "missing.png" in text, text
