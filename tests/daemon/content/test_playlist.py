"""The playlist: entries in order for their durations, looping, only within their hours; an
animation's frames at their own durations; a broken entry skipped; a picture asked for
above it for its duration, then the playlist again."""

from __future__ import annotations

import time

import numpy as np
import pytest
from content_helpers import CapturingSink
from PIL import Image

from grassd.daemon.content.config import ContentConfig, PlaylistEntry
from grassd.daemon.content.pictures import PictureError, load_animation
from grassd.daemon.content.player import ContentPlayer
from grassd.daemon.content.status import ContentSource

ROWS, COLS = 2, 4


def _still(path, g: int):
    Image.new("RGB", (COLS * 4, ROWS * 4), (0, g, 0)).save(path)
    return path


def _gif(path, greens, ms: int):
    frames = [Image.new("RGB", (COLS * 4, ROWS * 4), (0, g, 0)) for g in greens]
    frames[0].save(path, save_all=True, append_images=frames[1:], duration=ms, loop=0)
    return path


def _player(entries, hour=lambda: 12, **kw):
    cfg = ContentConfig(enabled=True, map="green", playlist=tuple(entries), **kw)
    sink = CapturingSink()
    return ContentPlayer(cfg, ROWS, COLS, sink, hour=hour, live=False), sink


def _shown(p: ContentPlayer, t: float) -> int:
    """The (uniform) level the player shows at monotonic ``t``."""
    f = p.tick(t)
    assert f is not None and len(set(f.tolist())) == 1
    return int(f[0])


def test_entries_in_order_loop_and_hours(tmp_path):
    a = PlaylistEntry(_still(tmp_path / "a.png", 10), duration_s=1.0)
    night = PlaylistEntry(_still(tmp_path / "n.png", 20), duration_s=1.0, start_hour=22,
                          end_hour=6)
    anim = PlaylistEntry(_gif(tmp_path / "b.gif", [30, 40], 200), duration_s=1.0)
    broken = tmp_path / "broken.png"
    broken.write_bytes(b"\x89PNG\r\n\x1a\n not really")
    hour = [12]
    p, _ = _player([a, night, PlaylistEntry(broken, 1.0), anim], hour=lambda: hour[0])
    assert p.library.start().wait(10)  # read off the player's thread
    assert p.library.failed(broken) and not p.library.failed(a.file)
    t0 = 1000.0
    assert _shown(p, t0) == 10 and p.source is ContentSource.PLAYLIST
    assert _shown(p, t0 + 0.9) == 10
    # the night entry is left out at noon, the broken one skipped: the animation, its frames
    # 0.2 s each
    assert [_shown(p, t0 + 1.0 + d) for d in (0.0, 0.1, 0.25, 0.45, 0.65)] == [30, 30, 40,
                                                                              30, 40]
    assert _shown(p, t0 + 2.05) == 10  # looped
    hour[0] = 23
    assert _shown(p, t0 + 3.1) == 20  # at night the night entry plays
    assert p.status().detail == "n.png"


def test_picture_asked_for_then_playlist_again(tmp_path):
    p, sink = _player([PlaylistEntry(_still(tmp_path / "a.png", 10), duration_s=60.0)],
                      fps=20)
    p.start()
    try:
        sink.wait_for(lambda f: np.all(f == 10))
        p.show(load_animation(_still(tmp_path / "s.png", 99), ROWS, COLS, 1 << 20), 0.5)
        sink.wait_for(lambda f: np.all(f == 99))
        assert p.status().source is ContentSource.SCRIPT
        t0 = time.monotonic()
        sink.wait_for(lambda f: np.all(f == 10), timeout_s=3)
        assert 0.3 < time.monotonic() - t0 < 0.8
        rate = np.diff(sink.times(t0))
        assert abs(1 / np.median(rate) - 20) < 3  # frames at fps meanwhile
    finally:
        p.stop()


def test_a_picture_too_large_or_missing_is_refused_with_the_reason(tmp_path):
    big = _still(tmp_path / "big.png", 1)
    with pytest.raises(PictureError, match="max_picture_mib"):
        load_animation(big, ROWS, COLS, 10)
    with pytest.raises(PictureError, match="cannot read picture"):
        load_animation(tmp_path / "nope.png", ROWS, COLS, 1 << 20)
    huge = tmp_path / "huge.png"
    Image.new("L", (4097, 4096)).save(huge)  # small on disk, 16.8 M pixels to decode
    with pytest.raises(PictureError, match="at most 16777216 pixels a frame"):
        load_animation(huge, ROWS, COLS, 64 << 20)


def test_apng_and_jpeg_are_read(tmp_path):
    frames = [Image.new("RGB", (COLS * 4, ROWS * 4), (0, g, 0)) for g in (50, 150, 250)]
    frames[0].save(tmp_path / "a.png", save_all=True, append_images=frames[1:],
                   duration=[100, 200, 300], loop=0)
    anim = load_animation(tmp_path / "a.png", ROWS, COLS, 1 << 20)
    assert anim.frames.shape == (3, ROWS, COLS, 3)
    assert anim.frames[:, 0, 0, 1].tolist() == [50, 150, 250]
    assert anim.durations_s.tolist() == pytest.approx([0.1, 0.2, 0.3])
    assert [anim.index_at(t) for t in (0.05, 0.15, 0.35, 0.65)] == [0, 1, 2, 0]
    Image.new("RGB", (COLS * 40, ROWS * 40), (10, 200, 30)).save(tmp_path / "a.jpg",
                                                                 quality=95)
    jpg = load_animation(tmp_path / "a.jpg", ROWS, COLS, 1 << 20)
    assert jpg.frames.shape == (1, ROWS, COLS, 3)
    assert abs(int(jpg.frames[0, 0, 0, 1]) - 200) <= 3
