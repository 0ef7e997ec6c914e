"""The status page's picture of what the display shows, as the controllers report it: a frame
offered through the service to simulated controllers on real ptys, read back with
GET_POSITIONS once the motors arrived (every pixel's target is ``table[level]``, its length
that within the simulated encoder's resolution), drawn as a
PNG whose blocks lie where the display's pixels do (a bright corner pixel in its corner), in the
status page; a controller unplugged shows grey and is named."""

from __future__ import annotations

import base64
import io
import re
import time

import numpy as np
from daemon_harness import POLICY
from PIL import Image
from test_content_in_service import _config

from grassd.calib.colour_spaces import lab_to_srgb
from grassd.daemon.cli.features import daemon_features
from grassd.daemon.content.display_picture import (
    MISSING_RGB8,
    picture_scale,
    shown_png,
    shown_rgb8,
)
from grassd.daemon.content.shown import LengthColours, ShownDisplay
from grassd.daemon.core.config.settings import load_config, load_default_config
from grassd.daemon.core.runtime.service import Service
from grassd.rigs.simulated_site import SimulatedHardware

_PNG = re.compile(r'<figure class="shown"><img src="data:image/png;base64,([A-Za-z0-9+/=]+)"'
                  r'.*?<figcaption>(.*?)</figcaption>', re.S)


#: the simulated controllers' encoder resolution (um per count)
ENCODER_UM = 12.5


def _shown(svc):
    """The display as the content feature reads it for the status page (None: nothing)."""
    return svc.features.get("content").shown(svc)


def _arrived(svc: Service, want: np.ndarray, timeout_s: float = 10.0) -> ShownDisplay:
    """Read the display until every pixel's target is ``want`` (rows, cols) [um] and its
    length within an encoder count of it."""
    deadline = time.monotonic() + timeout_s
    while True:
        shown = _shown(svc)  # None until the player shows the frame
        there = shown is not None and np.array_equal(shown.targets_um, want) and bool(
            (np.abs(shown.lengths_um - want) <= ENCODER_UM).all())
        if there or time.monotonic() > deadline:
            assert shown is not None, "the frame never showed"
            return shown
        time.sleep(0.1)


def _blocks(png: bytes, rows: int, cols: int) -> np.ndarray:
    """The PNG as (rows, cols, 3): one colour per display pixel (each block uniform)."""
    img = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))
    s = img.shape[1] // cols
    assert img.shape == (rows * s, cols * s, 3)
    blocks = img.reshape(rows, s, cols, s, 3)
    assert (blocks == blocks[:, :1, :, :1]).all()  # every block one colour
    return blocks[:, 0, :, 0]


def test_the_page_shows_the_frame_as_the_controllers_report_it(tmp_path, ports):
    sim = SimulatedHardware(load_default_config(), tmp_path / "hw")
    hw_cfg = sim.start()
    conf = tmp_path / "grassd.toml"
    conf.write_text(_config(tmp_path, hw_cfg, ports, True))
    svc = Service(load_config(conf), features=daemon_features(), config_path=conf,
                  policy=POLICY)
    try:
        rows, cols = svc.cfg.display.rows, svc.cfg.display.cols
        assert _shown(svc) is None  # no content configured to play yet: nothing read
        table = np.rint(np.linspace(0, 20000, 256)).astype(np.uint16)
        assert all(r.ok for r in svc.fleet.push(table, 1))
        svc.features.restart(svc, None)
        levels = np.array([(i * 7) % 100 for i in range(rows * cols)])
        levels[cols - 1] = 255  # row 0, last column: the top right corner, the longest grass
        assert svc.handle_request({"cmd": "content_frame", "levels": levels.tolist(),
                                   "hold_s": 60})["ok"]
        want = table[levels].reshape(rows, cols).astype(float)
        shown = _arrived(svc, want)
        np.testing.assert_array_equal(shown.targets_um, want)
        np.testing.assert_allclose(shown.lengths_um, want, rtol=0, atol=ENCODER_UM)
        assert shown.answered == tuple(c.name for c in svc.cfg.controllers)
        assert shown.missing == () and shown.max_length_um > 0

        blocks = _blocks(shown_png(shown), rows, cols)
        green = blocks[..., 1].astype(int)
        assert np.unravel_index(green.argmax(), green.shape) == (0, cols - 1)
        # brighter green for longer grass, pixel by pixel in display order
        order = np.argsort(shown.lengths_um.ravel(), kind="stable")
        assert (np.diff(green.ravel()[order]) >= 0).all()

        svc.features.get("content")._shown_at = float("-inf")  # due now, as after SHOWN_EVERY_S
        svc.reconcile()  # the service writes its page while content plays
        page = svc.operator.page.read_text("utf-8")
        m = _PNG.search(page)
        assert m, "the status page holds no picture of the display"
        assert "from 2 of 2 controller(s)" in m.group(2)
        page_blocks = _blocks(base64.b64decode(m.group(1)), rows, cols)
        np.testing.assert_array_equal(page_blocks, blocks)
        first = svc.features.get("content").last_shown
        svc.reconcile()  # within SHOWN_EVERY_S of the last reading: the lines are not read
        assert svc.features.get("content").last_shown is first

        # one line's controller unplugged: its pixels grey, named in the caption
        gone = svc.cfg.controllers[1]
        sim.buses.pop(1).stop()  # its pty gone, as a cable pulled
        shown = _shown(svc)
        assert shown is not None
        assert [m.name for m in shown.missing] == [gone.name]
        assert shown.answered == (svc.cfg.controllers[0].name,)
        lost = np.zeros(rows * cols, bool)
        for a, b in gone.pixels:
            lost[a:b + 1] = True
        lost = lost.reshape(rows, cols)
        assert np.isnan(shown.lengths_um[lost]).all()
        assert np.isnan(shown.targets_um[lost]).all()
        np.testing.assert_array_equal(shown.targets_um[~lost], want[~lost])
        rgb = _blocks(shown_png(shown), rows, cols)
        assert (rgb[lost] == MISSING_RGB8).all() and not (rgb[~lost] == MISSING_RGB8).all(-1).any()
        svc.features.get("content")._shown_at = float("-inf")
        svc.reconcile()
        caption = _PNG.search(svc.operator.page.read_text("utf-8")).group(2)
        assert "from 1 of 2 controller(s)" in caption and gone.name in caption
        # content stopped: nothing is read, the page keeps the last picture with its time
        assert svc.handle_request({"cmd": "content_stop"})["ok"]
        deadline = time.monotonic() + 5
        while _shown(svc) is not None and time.monotonic() < deadline:
            time.sleep(0.05)
        assert _shown(svc) is None
    finally:
        svc.shutdown()
        sim.stop()


def test_predicted_colours_follow_the_table():
    """With the active table's predicted colours, each pixel is drawn in the colour predicted
    for its length (the level whose length it stands at)."""
    table = np.linspace(0, 20000, 256)
    lab = np.stack([np.linspace(30, 70, 256), np.linspace(0, -40, 256),
                    np.linspace(40, 20, 256)], axis=-1)
    colours = LengthColours.from_table(table, lab)
    assert colours is not None
    lengths = table[[0, 64, 128, 255, 10, 200]].reshape(2, 3)
    shown = ShownDisplay(lengths, lengths, 0.0, 20000, ("a",), (), colours)
    want = np.rint(lab_to_srgb(lab[[0, 64, 128, 255, 10, 200]]) * 255).reshape(2, 3, 3)
    np.testing.assert_array_equal(shown_rgb8(shown), want)
    assert picture_scale(shown) * 3 <= 256
    assert LengthColours.from_table(np.zeros((4, 256)), lab) is None  # per-pixel tables
