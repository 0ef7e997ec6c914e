"""A bundle whose sky EXR is truncated is rejected with grassd's one-line reason, which carries
OpenEXR's own (EXR_ERR_...); the library's lines themselves never reach the daemon's stdout or
stderr (its log), since sim.hdri captures them (sim.native_output)."""

from __future__ import annotations

from daemon_harness import SITE, after_first_bundle, drop, journal_entry


def test_daemon_rejects_a_truncated_sky_with_our_line_only(tmp_path, hw, capfd):
    _, cfg = hw
    svc, _ = after_first_bundle(tmp_path, cfg)
    capfd.readouterr()
    bundle = drop(svc.cfg.light.inbox, "cut", lux=900.0)
    data = SITE.read_bytes()
    (bundle / "sky.exr").write_bytes(data[: len(data) // 2])
    svc.tick()
    j = journal_entry(svc, "cut")
    assert j.state == "rejected" and "corrupt or truncated OpenEXR pixel data" in j.reason
    assert "EXR_ERR_BAD_CHUNK_LEADER" in j.reason
    out, err = capfd.readouterr()
    assert "EXR_ERR" not in out + err.replace(j.reason, "")
    assert "Warning: Exception raised" not in out + err
