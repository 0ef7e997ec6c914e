"""The studio's display view maps a picture as the daemon's content does: a real ``grassd
studio`` on 127.0.0.1 gets the picture over HTTP and the conditions over its WebSocket, and the
levels of its ``display`` message equal those the daemon's content path (the picture file read
as ``grassd show`` reads it, mapped as its player maps it) gives for the same picture, the
studio's characteristic at the reference viewpoint and the same ``[content] map``."""

from __future__ import annotations

import asyncio

import numpy as np
from conftest import GOOD, png_bytes, ws_session


def _views(studio, cond: dict, tag: int) -> dict[str, dict]:
    """The last message of each kind of one job of ``cond`` (over the WebSocket)."""
    got = asyncio.run(ws_session(studio.url, [{"type": "inputs", "id": tag,
                                               "condition": cond}], until_id=tag))
    mine = {m["type"]: m for m in got if m["id"] == tag}
    assert "error" not in mine and "done" in mine, got
    return mine


def _shown_by_the_daemon(tmp_path, rgb: np.ndarray, table_mm: list, curve: dict
                         ) -> tuple[np.ndarray, str]:
    """The levels (rows, cols) ``grassd show`` shows for the picture ``rgb`` (written to a
    PNG file and read back as the daemon reads it) when its table is ``table_mm`` and its
    characteristic ``curve`` (a curve message: lengths and D50 Lab); and the map used."""
    from grassd.daemon.content.colour_map import DisplayColours
    from grassd.daemon.content.config import ContentConfig
    from grassd.daemon.content.mapping import MappedAnimation
    from grassd.daemon.content.pictures import load_animation
    from grassd.daemon.core.config.settings import resolve_config

    content = resolve_config(None, None).content or ContentConfig()
    path = tmp_path / "picture.png"
    path.write_bytes(png_bytes(rgb, "RGB"))
    rows, cols = rgb.shape[:2]
    anim = load_animation(path, rows, cols, content.max_picture_mib << 20)
    colours = DisplayColours.from_curve(table_mm, curve["lengths_mm"], curve["lab_d50"],
                                        "the studio's curve message")
    mapped = MappedAnimation(anim, content.map, content.normalise)
    assert mapped.wait(colours, 60.0)
    return mapped.levels(colours)[0].reshape(rows, cols), content.map


def _de00(lab: np.ndarray, level_lab: np.ndarray) -> np.ndarray:
    """(N, 256) CIEDE2000 of each colour against each level's (colour-science's)."""
    import colour

    return colour.delta_E(lab[:, None, :], level_lab[None, :, :], method="CIE 2000")


def _srgb8_to_lab(rgb8: np.ndarray) -> np.ndarray:
    """8-bit sRGB (N, 3) -> D50 CIELAB through colour-science (Bradford adaptation)."""
    import colour

    d50 = colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D50"]
    xyz = colour.RGB_to_XYZ(colour.cctf_decoding(rgb8 / 255.0, "sRGB"),
                            colour.RGB_COLOURSPACES["sRGB"], d50, "Bradford")
    return colour.XYZ_to_Lab(xyz, d50)


def _picture(on_axis_srgb: list, rows: int, cols: int) -> tuple[np.ndarray, np.ndarray]:
    """A rows x cols picture: its first row the display's own colours (``on_axis_srgb``,
    repeated), the rest colours off the display's axis; and which pixels are off it."""
    off = np.array([[0, 0, 255], [255, 0, 255], [255, 0, 0], [0, 255, 255], [255, 255, 0],
                    [40, 40, 160], [200, 120, 220], [255, 255, 255], [0, 0, 0],
                    [128, 128, 128], [230, 40, 90], [10, 200, 40]], np.uint8)
    rgb = np.empty((rows, cols, 3), np.uint8)
    axis = np.asarray(on_axis_srgb, np.uint8)
    rgb[0] = axis[np.arange(cols) % len(axis)]
    rest = rgb[1:].reshape(-1, 3)
    rest[:] = off[np.arange(len(rest)) % len(off)]
    off_axis = np.zeros((rows, cols), bool)
    off_axis[1:] = True
    return rgb, off_axis


def test_the_studios_display_shows_what_grassd_show_shows(studio, tmp_path):
    # the characteristic at the reference viewpoint (170 cm, 2 m, 0 deg) first, no picture
    ref = _views(studio, GOOD, 1)
    assert ref["curve"]["converged"] and len(ref["curve"]["lab_d50"]) == len(GOOD["lengths_mm"])
    status, state = studio.request("api/state")
    assert status == 200
    rows, cols = state["display"]["rows"], state["display"]["cols"]
    rgb, off_axis = _picture(ref["curve"]["srgb"], rows, cols)
    status, pic = studio.request("api/picture", png_bytes(rgb, "RGB"))
    assert status == 200, pic
    assert np.array_equal(np.asarray(pic["rgb"], np.uint8), rgb)  # one colour a pixel

    # the eye at the reference viewpoint: the condition's own characteristic is the one
    here = _views(studio, {**GOOD, "image": pic["image"]}, 2)
    shown = np.asarray(here["display"]["levels"], np.uint8)
    expected, mode = _shown_by_the_daemon(tmp_path, rgb, here["table"]["lengths_mm"],
                                          here["curve"])
    assert here["display"]["map"] == mode == "nearest_de00"
    assert "(170, 2, 0)" in here["display"]["colours"]
    assert shown.shape == (rows, cols) and np.array_equal(shown, expected)

    # colours off the display's axis take the nearest reachable level, not their luminance
    from grassd.daemon.content.colour_map import DisplayColours

    level_lab = DisplayColours.from_curve(here["table"]["lengths_mm"],
                                          here["curve"]["lengths_mm"],
                                          here["curve"]["lab_d50"], "test").level_lab
    de = _de00(_srgb8_to_lab(rgb.reshape(-1, 3).astype(np.float64)), level_lab)
    flat = shown.ravel()
    chosen = de[np.arange(flat.size), flat]
    assert np.all(chosen <= de.min(axis=1) + 0.01), (chosen - de.min(axis=1)).max()
    r, g, b = (rgb.reshape(-1, 3)[:, k].astype(np.int64) for k in range(3))
    luma = (r * 19595 + g * 38470 + b * 7471 + 0x8000) >> 16  # ITU-R BT.601, as Pillow's "L"
    luma_de = de[np.arange(flat.size), luma]
    off = off_axis.ravel()
    assert np.count_nonzero(flat[off] != luma[off]) >= off.sum() // 2
    assert np.mean(luma_de[off] - chosen[off]) > 1.0

    # the eye elsewhere under another light: the studio runs the reference viewpoint's
    # characteristic too, keeps it, and maps onto its colours; the view is drawn from the eye
    lit = {**GOOD, "ambient_lux": 6000.0}
    elsewhere = _views(studio, {**lit, "viewpoint": [160, 3, 25], "image": pic["image"]}, 3)
    kept = _views(studio, lit, 4)["curve"]
    assert kept["kept"]  # run for job 3's picture, not for job 4
    shown = np.asarray(elsewhere["display"]["levels"], np.uint8)
    table = elsewhere["table"]["lengths_mm"]
    expected, _mode = _shown_by_the_daemon(tmp_path, rgb, table, kept)
    assert np.array_equal(shown, expected)
    by_the_eye, _mode = _shown_by_the_daemon(tmp_path, rgb, table, elsewhere["curve"])
    assert not np.array_equal(shown, by_the_eye)  # the eye's own colours would differ


def test_an_uploaded_picture_has_the_colours_grassd_show_reads(studio, tmp_path):
    """PNG, baseline and progressive JPEG, GIF: the studio's colours per display pixel are those
    the daemon's content reads from the same file."""
    import io

    from PIL import Image

    from grassd.daemon.content.pictures import load_animation

    status, state = studio.request("api/state")
    rows, cols = state["display"]["rows"], state["display"]["cols"]
    y, x = np.mgrid[0:600, 0:1200]
    noise = np.random.default_rng(1).integers(-20, 20, (600, 1200, 3))
    img = (np.stack([x * 255 // 1200, y * 255 // 600, (x + y) % 255], -1) + noise)
    img = Image.fromarray(img.clip(0, 255).astype(np.uint8))
    for kind, kw in (("png", {"format": "PNG"}), ("jpg", {"format": "JPEG", "quality": 90}),
                     ("progressive.jpg", {"format": "JPEG", "quality": 90,
                                          "progressive": True}),
                     ("gif", {"format": "GIF"})):
        buf = io.BytesIO()
        img.save(buf, **kw)
        path = tmp_path / f"picture.{kind}"
        path.write_bytes(buf.getvalue())
        status, pic = studio.request("api/picture", buf.getvalue())
        assert status == 200, (kind, pic)
        daemon = load_animation(path, rows, cols, 64 << 20).frames[0]
        assert np.array_equal(np.asarray(pic["rgb"], np.uint8), daemon), kind
