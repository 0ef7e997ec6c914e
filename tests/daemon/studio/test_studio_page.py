"""The studio's page in headless Chromium over the DevTools protocol, against a real
``grassd studio`` process: it loads and converges, dragging the eye on the top view changes the
curve, an uploaded picture appears on the display view, a bad value shows a message in the page
and the next good one clears it, a pinned condition shows beside the current one; no
console errors; screenshots at 1280 and 390 px wide (kept
under pytest's tmp directory, and in $GRASSD_SCREENSHOTS when set)."""

from __future__ import annotations

import io
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from headless_chromium import CHROMIUM, MISSING, Browser

pytestmark = pytest.mark.skipif(CHROMIUM is None, reason=MISSING)

CONVERGED = "window.studio.curve && window.studio.curve.converged"


def _keep(path: Path) -> None:
    if os.environ.get("GRASSD_SCREENSHOTS"):
        out = Path(os.environ["GRASSD_SCREENSHOTS"])
        out.mkdir(parents=True, exist_ok=True)
        shutil.copy(path, out / path.name)


def _picture(path: Path) -> Path:
    """A 64 x 32 picture: dark on the left, bright on the right."""
    from PIL import Image

    ramp = np.tile(np.linspace(0, 255, 64), (32, 1)).astype(np.uint8)
    buf = io.BytesIO()
    Image.fromarray(ramp, "L").save(buf, "PNG")
    path.write_bytes(buf.getvalue())
    return path


def _display_halves(page) -> tuple[float, float]:
    """Mean brightness of the left and right halves of the display view's image."""
    return tuple(page.evaluate("""(() => {
        const img = document.getElementById('display-img');
        const c = document.createElement('canvas');
        c.width = img.naturalWidth; c.height = img.naturalHeight;
        const g = c.getContext('2d'); g.drawImage(img, 0, 0);
        const d = g.getImageData(0, 0, c.width, c.height).data;
        let l = 0, r = 0, nl = 0, nr = 0;
        for (let i = 0; i < d.length; i += 4) {
          const x = (i / 4) % c.width, v = d[i] + d[i + 1] + d[i + 2];
          if (v <= 72) continue;  // the background
          if (x < c.width / 2) { l += v; nl++; } else { r += v; nr++; }
        }
        return [l / nl, r / nr];
    })()"""))


def test_the_page_follows_the_eye_shows_a_picture_and_reports_bad_input(studio, tmp_path):
    with Browser(timeout_s=60) as browser:
        page = browser.open(studio.url, 1280, 900)
        page.wait_for(CONVERGED)
        assert page.evaluate("document.getElementById('pixel-choice-row').hidden")  # one pixel
        first = page.evaluate("window.studio.curve.ogcd")
        assert page.evaluate("window.studio.condition.viewpoint") == [170, 2, 0]
        assert page.wait_for("window.studio.pixels") >= 1
        page.wait_for("window.studio.audience")
        page.screenshot(tmp_path / "studio-1280.png")
        _keep(tmp_path / "studio-1280.png")

        # drag the eye from the reference viewpoint to the right on the top view
        box = page.evaluate("(() => { const r = document.getElementById('topview')"
                            ".getBoundingClientRect(); return [r.left, r.top, r.width,"
                            " r.height]; })()")
        eye = page.evaluate("(() => { const c = document.getElementById('topview'),"
                            " r = c.getBoundingClientRect(), f = topFrame(),"
                            " p = f.toPx(studio.eye.x, studio.eye.y);"
                            " return [r.left + p[0] * r.width / c.width,"
                            " r.top + p[1] * r.height / c.height]; })()")
        assert box[0] <= eye[0] <= box[0] + box[2]
        page.drag(tuple(eye), (eye[0] + 0.3 * box[2], eye[1] + 0.1 * box[3]))
        page.wait_for("window.studio.condition.viewpoint[2] > 20")
        page.wait_for(CONVERGED + " && window.studio.curve.id === window.studio.id")
        moved = page.evaluate("window.studio.curve.ogcd")
        assert moved != first
        assert max(abs(a - b) for a, b in zip(moved, first, strict=True)) > 0.3

        # a picture, dark left and bright right, on the display view
        page.set_files("#picture", [_picture(tmp_path / "ramp.png")])
        page.wait_for("window.studio.displays > 0 && "
                      "!document.getElementById('display-img').hidden")
        page.wait_for("document.getElementById('display-img').complete")
        left, right = _display_halves(page)
        # each colour shows as the nearest colour the grass can make (the daemon's [content]
        # map): the dark half as the deep green of long grass, the bright half as the lightest
        # (the yellow tufts of the shortest)
        assert right > left + 40, (left, right)

        # a bad value shows its message in the page; the next good one clears it
        page.evaluate("document.getElementById('lux').value = 5e9;"
                      "document.getElementById('lux').dispatchEvent(new Event('change'))")
        message = page.wait_for("!document.getElementById('error').hidden && "
                                "document.getElementById('error').textContent")
        assert "ambient_lux = 5e+09 is out of range" in message
        page.evaluate("document.getElementById('pin').click()")  # nothing sound to pin
        assert page.evaluate("window.studio.pinned") is None
        page.evaluate("document.getElementById('lux').value = 8000;"
                      "document.getElementById('lux').dispatchEvent(new Event('change'))")
        page.wait_for("document.getElementById('error').hidden")
        page.wait_for(CONVERGED + " && window.studio.curve.id === window.studio.id")

        # pin this condition as B, lower the eye: A and B side by side
        page.evaluate("document.getElementById('pin').click()")
        page.evaluate("document.getElementById('eye-h').value = 60;"
                      "document.getElementById('eye-h').dispatchEvent(new Event('input'))")
        page.wait_for("window.studio.condition.viewpoint[0] === 60")
        page.wait_for(CONVERGED + " && window.studio.curve.id === window.studio.id")
        page.wait_for("window.studio.audience && window.studio.audience.id === window.studio.id")
        assert not page.evaluate("document.getElementById('compare').hidden")
        assert page.evaluate("curvePlot.series.length") == 5  # A, its band, B
        # B was pinned with its first image (96 px); it refines after A's views
        page.wait_for("window.studio.pinned.final && "
                      "document.getElementById('b-img').naturalWidth === 192")
        page.screenshot(tmp_path / "studio-1280-compare.png")
        _keep(tmp_path / "studio-1280-compare.png")
        assert page.problems() == []

        # a B that cannot be computed (here its sun set) is said under B, and A goes on
        page.evaluate("const p = window.studio.pinned; p.final = false;"
                      "p.condition = {...p.condition, sun: {mode: 'site', lux: 30000,"
                      " when: '2026-11-27T23:00'}}; send()")
        page.wait_for("window.studio.pinned.error")
        assert "below the horizon" in page.evaluate("document.getElementById('b-cap')"
                                                    ".textContent")
        assert page.evaluate("document.getElementById('error').hidden")
        page.wait_for(CONVERGED + " && window.studio.curve.id === window.studio.id")

        narrow = browser.open(studio.url, 390, 844, mobile=True)
        narrow.wait_for(CONVERGED + " && window.studio.pixels > 0 && window.studio.table"
                        " && window.studio.audience")
        width = narrow.evaluate("document.documentElement.scrollWidth")
        assert width <= 390, f"the page scrolls sideways at 390 px ({width} px wide)"
        narrow.screenshot(tmp_path / "studio-390.png")
        _keep(tmp_path / "studio-390.png")
        assert narrow.problems() == []
