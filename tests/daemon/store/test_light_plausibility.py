"""Light that cannot have been is refused at ingest, with the reason: light stamped in the future
(a camera clock never set would otherwise outrank, and so supersede, every later bundle), a sun
giving lux from below the horizon, more sun than sunlight has, and a sun direction far from the
sun's position at the site and time. A daemon whose active table was made from future light
(by a version before this check) lets the next real bundle through.
Inbox with real EXR files and a fake wall clock; in-process daemon with simulated hardware."""

from __future__ import annotations

from datetime import UTC, datetime
from pathlib import Path

import pytest
from daemon_harness import drop, journal_entry, reported, service, write_config
from test_ingest import Clock, make_dir_bundle, settle

from grassd.daemon.core.config.limits import FUTURE_TOLERANCE_S
from grassd.daemon.core.errors import ManifestError
from grassd.daemon.core.store.history import History
from grassd.daemon.core.store.ingest import Inbox
from grassd.daemon.core.store.manifest import check_light, parse_manifest

NOW = datetime(2026, 11, 25, 9, 0, tzinfo=UTC).timestamp()
TOKYO = (35.0, 139.0)


def manifest(**kw):
    data = {"timestamp": "2026-11-25T09:00:00Z", "hdri": "sky.exr", "ambient_lux": 5000.0, **kw}
    return parse_manifest(data, Path("/b"))


@pytest.mark.parametrize("stamp, ok", [
    ("2026-11-25T09:04:59Z", True),     # within the default 300 s
    ("2026-11-25T09:05:01Z", False),
    ("2099-01-01T00:00:00Z", False),    # a camera clock never set
    ("2026-11-25T18:00:00Z", False),    # Tokyo time labelled UTC: 9 h ahead
    ("2001-01-01T00:00:00Z", True),     # far in the past is fine: it is simply superseded
])
def test_light_from_the_future_is_refused(stamp, ok):
    m = manifest(timestamp=stamp)
    if ok:
        check_light(m, now=NOW)
        return
    with pytest.raises(ManifestError, match="light from the future") as info:
        check_light(m, now=NOW)
    text = str(info.value)
    assert "ahead of the daemon's clock (2026-11-25T09:00:00+00:00)" in text
    assert "future_tolerance_s" in text and "clock" in text


def test_future_tolerance_is_configurable():
    m = manifest(timestamp="2026-11-25T10:00:00Z")
    check_light(m, now=NOW, future_tolerance_s=3600.0)
    with pytest.raises(ManifestError, match=r"1\.0 h|60\.0 min|3600 s"):
        check_light(m, now=NOW, future_tolerance_s=0.0)
    assert FUTURE_TOLERANCE_S == 300.0


@pytest.mark.parametrize("kw, site, words", [
    # a sun giving lux from below the horizon, reported ...
    (dict(sun_lux=40000.0, sun_azimuth_deg=180.0, sun_elevation_deg=-10.0), None,
     "below the horizon gives no light"),
    # ... or computed from the site and time: 09:00 UTC is 18:00 in Tokyo in November
    (dict(sun_lux=40000.0), TOKYO, "below the horizon at the site"),
    # more light than the sun gives perpendicular to it (40000 lx at 5 deg: 459 klx)
    (dict(sun_lux=40000.0, sun_azimuth_deg=180.0, sun_elevation_deg=5.0), None,
     "more than sunlight can give"),
    # a direction far from where the sun stands at the site then (an hour's error is 15 deg)
    (dict(timestamp="2026-06-21T12:00:00+09:00", sun_lux=40000.0, sun_azimuth_deg=90.0,
          sun_elevation_deg=40.0), TOKYO, "from where the sun stands at the site"),
])
def test_impossible_sun_is_refused(kw, site, words):
    with pytest.raises(ManifestError, match="impossible sun: .*" + words):
        check_light(manifest(**kw), now=NOW, site=site)


def test_possible_sun_passes():
    noon = "2026-06-21T12:00:00+09:00"  # Tokyo noon in June: sun high in the south
    check_light(manifest(timestamp=noon, sun_lux=90000.0), now=NOW, site=TOKYO)
    from grassd.sim.sun import sun_position
    az, el = sun_position(*TOKYO, datetime.fromisoformat(noon))
    check_light(manifest(timestamp=noon, sun_lux=90000.0, sun_azimuth_deg=round(az + 2, 1),
                         sun_elevation_deg=round(el - 2, 1)), now=NOW, site=TOKYO)
    check_light(manifest(sun_lux=0.0), now=NOW, site=TOKYO)  # no sun: nothing to check
    check_light(manifest(sun_lux=30000.0, sun_azimuth_deg=180.0, sun_elevation_deg=40.0),
                now=NOW)  # no site: only self-consistency


def test_inbox_rejects_future_light_against_its_wall_clock(tmp_path):
    clock = Clock()
    h = History(tmp_path / "state" / "state.db")
    try:
        inbox = Inbox(tmp_path / "inbox", tmp_path / "state", h, settle_s=1.0,
                      clock=clock, wall_clock=lambda: NOW)
        make_dir_bundle(inbox.inbox, "unset-clock",
                        'timestamp = 2099-01-01T00:00:00Z\nhdri = "sky.exr"\n'
                        "ambient_lux = 900.0\n")
        make_dir_bundle(inbox.inbox, "real",
                        'timestamp = 2026-11-25T08:55:00Z\nhdri = "sky.exr"\n'
                        "ambient_lux = 900.0\n")
        [b] = settle(inbox, clock)
        assert b.name == "real"
        [rej] = list(inbox.rejected.iterdir())
        reason = (rej / "reason.txt").read_text()
        assert reason.startswith("light from the future: timestamp 2099-01-01T00:00:00+00:00")
        assert "72.1 years ahead of the daemon's clock (2026-11-25T09:00:00+00:00)" in reason
        assert (rej / "sky.exr").is_file()  # nothing lost
    finally:
        h.close()


def test_future_bundle_cannot_pin_the_active_table(tmp_path, hw):
    """The bundle from 2099 is rejected; the real one after it becomes the active table."""
    _, cfg = hw
    svc = service(write_config(tmp_path / "g.toml", tmp_path / "state", cfg))
    inbox = svc.cfg.light.inbox
    drop(inbox, "unset-clock", lux=1000.0, timestamp="2099-01-01T00:00:00Z")
    svc.tick()
    j = journal_entry(svc, "unset-clock")
    assert j.state == "rejected" and j.reason.startswith("light from the future"), j
    assert svc.history.current_table() is None
    now = datetime.now(UTC).isoformat(timespec="seconds")
    drop(inbox, "real", lux=1500.0, timestamp=now)
    svc.tick()
    cur = svc.history.current_table()
    assert cur is not None and cur.bundle_hash == journal_entry(svc, "real").bundle_hash
    assert reported(svc) == {(cur.table_id, cur.table_crc)}


def test_active_table_from_future_light_supersedes_nothing(tmp_path, hw):
    """A state from before the check: the active table's run has light from 2099. A bundle with
    today's light is applied, not archived as superseded."""
    _, cfg = hw
    svc = service(write_config(tmp_path / "g.toml", tmp_path / "state", cfg))
    inbox = svc.cfg.light.inbox
    drop(inbox, "first", lux=1000.0, timestamp="2026-03-01T12:00:00+01:00")
    svc.tick()
    first = svc.history.current_table()
    assert first is not None
    svc.history._db.execute("UPDATE runs SET light_at = ? WHERE id = ?",
                            (datetime(2099, 1, 1, tzinfo=UTC).timestamp(), first.id))
    svc.history._db.commit()
    drop(inbox, "today", lux=1500.0, timestamp=datetime.now(UTC).isoformat(timespec="seconds"))
    svc.tick()
    j = journal_entry(svc, "today")
    assert j.state == "archived" and j.reason is None, j
    cur = svc.history.current_table()
    assert cur.id != first.id and cur.bundle_hash == j.bundle_hash
    assert reported(svc) == {(cur.table_id, cur.table_crc)}
