"""The HTML report of ``grassd validate``: one self-contained file whose embedded PNG plots
decode at the sizes the page states, and which headless Chromium renders with the plots
visible (skipped with a reason where Chromium is not installed)."""

from __future__ import annotations

import base64
import io
import json
import os
import re
import shutil
import subprocess
from html.parser import HTMLParser

import numpy as np
import pytest

from grassd.daemon.offline.report import REAL_COLOUR, SIM_COLOUR, validation_html
from grassd.daemon.offline.validate import load_manifest, validate_capture
from grassd.daemon.offline.virtual_capture import capture_world
from grassd.sim.light_input import LightInput

CHROMIUM = next((p for p in ("/usr/bin/chromium", shutil.which("chromium"),
                             shutil.which("chromium-browser"))
                 if p and os.access(p, os.X_OK)), None)
VIEWS = [(170.0, 2.0, 0.0), (150.0, 2.0, 0.0), (170.0, 2.0, 90.0), (150.0, 2.0, 90.0)]


@pytest.fixture(scope="module")
def report(renderer, shared_hdri, tmp_path_factory):
    from grassd.sim.scene import PixelSpec, RenderSettings

    root = tmp_path_factory.mktemp("capture")
    light = LightInput(shared_hdri("courtyard"), 8000.0)
    lighting = light.lighting()
    capture_world(root, light, VIEWS, [0.0, 5.0, 10.0, 15.0, 20.0],
                  real_pixel=PixelSpec(splay_deg=15.0), renderer=renderer, lighting=lighting,
                  width=64, spp=4)
    res = validate_capture(load_manifest(root), renderer=renderer, lighting=lighting,
                           settings=RenderSettings(samples=1024, replicates=4))
    path = root / "report.html"
    path.write_text(validation_html(res))
    return res, path


class _Page(HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.imgs: list[dict] = []
        self.text: list[str] = []
        self.tags: list[str] = []

    def handle_starttag(self, tag, attrs):
        self.tags.append(tag)
        if tag == "img":
            self.imgs.append(dict(attrs))

    def handle_data(self, data):
        self.text.append(data)


def _decode(src: str) -> np.ndarray:
    import matplotlib.image as mpimg

    prefix = "data:image/png;base64,"
    assert src.startswith(prefix)
    return mpimg.imread(io.BytesIO(base64.b64decode(src[len(prefix):])), format="png")


def _has_colour(img: np.ndarray, hex_colour: str, min_pixels: int = 50) -> bool:
    rgb = np.array([int(hex_colour[i: i + 2], 16) for i in (1, 3, 5)]) / 255.0
    close = np.abs(img[..., :3] - rgb).max(axis=-1) < 0.06
    return int(close.sum()) >= min_pixels


def test_html_is_self_contained_and_pngs_decode_at_stated_sizes(report):
    res, path = report
    text = path.read_text()
    page = _Page()
    page.feed(text)
    assert not re.search(r'(src|href)="(?!data:)', text)  # nothing loaded from elsewhere
    assert len(page.imgs) == 4  # curves, viewpoint grid, appearance swatches, calibration
    for img in page.imgs:
        pixels = _decode(img["src"])
        assert pixels.shape[:2] == (int(img["height"]), int(img["width"]))
        assert pixels.shape[0] >= 200 and pixels.shape[1] >= 400
    curves, grid, swatches, cal = (_decode(i["src"]) for i in page.imgs)
    for plot in (curves, grid, cal):
        assert _has_colour(plot, REAL_COLOUR)  # real curve / scatter drawn
    assert _has_colour(curves, SIM_COLOUR) and _has_colour(grid, SIM_COLOUR)
    # the swatches show the measured grass colours: yellow-green at 0 mm, green at 20 mm
    ref = res.reference
    from grassd.daemon.offline.report import lab_to_srgb

    for lab in (ref.real_lab[0], ref.real_lab[-1], ref.sim_lab[-1]):
        assert _has_colour(swatches, "#" + "".join(f"{round(255 * c):02x}"
                                                    for c in lab_to_srgb(lab)), 200)
    words = " ".join(page.text)
    for v in res.viewpoints:
        assert v.label in words
        assert f"{v.frechet:.2f}" in words
    assert "paper Figure 8" in words and "paper Figure 11" in words
    assert page.tags.count("table") == 2


@pytest.mark.skipif(CHROMIUM is None, reason="headless Chromium is not installed (Debian "
                    "package 'chromium'); the HTML structure test above still runs")
def test_report_renders_in_headless_chromium(report, tmp_path):
    res, path = report
    # the page itself, plus a script that records what the browser decoded for each image
    probe = tmp_path / "probe.html"
    probe.write_text(path.read_text().replace("</body>", """<script>
window.addEventListener('load', () => { document.body.setAttribute('data-imgs', JSON.stringify(
  [...document.images].map(i => [i.naturalWidth, i.naturalHeight, i.width, i.complete]))); });
</script></body>"""))
    base = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
            "--virtual-time-budget=5000"]
    dom = subprocess.run(base + ["--dump-dom", probe.as_uri()], capture_output=True,
                         text=True, timeout=120, check=True).stdout
    m = re.search(r'data-imgs="([^"]*)"', dom)
    assert m, dom[:500]
    imgs = json.loads(m.group(1).replace("&quot;", '"'))
    page = _Page()
    page.feed(path.read_text())
    assert [(w, h) for w, h, _, _ in imgs] == [(int(i["width"]), int(i["height"]))
                                                for i in page.imgs]
    assert all(done for *_, done in imgs)
    assert "grassd validate" in dom and res.viewpoints[0].label in dom
    shot = tmp_path / "shot.png"
    subprocess.run(base + ["--window-size=1200,2600", f"--screenshot={shot}", path.as_uri()],
                   capture_output=True, timeout=120, check=True)
    import matplotlib.image as mpimg

    pixels = mpimg.imread(shot)
    assert pixels.shape[:2] == (2600, 1200)
    # the plots are on screen: many pixels of the real (green) and simulated (orange) curves
    assert _has_colour(pixels, REAL_COLOUR, 500) and _has_colour(pixels, SIM_COLOUR, 300)
