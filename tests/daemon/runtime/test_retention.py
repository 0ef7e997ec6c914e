"""[retention]: archived/rejected bundles, run reports and history rows are pruned after every
run, while the active table, its report and the latest archived bundle (the light of scheduled
runs) always stay. In-process daemon, real renders, simulated controllers on ptys, pymodbus."""

from __future__ import annotations

import re
import time

import pytest
from daemon_harness import drop, service, truncated_exr, write_config

from grassd.daemon.core.config.settings import (
    RetentionConfig,
    default_config_text,
    parse_config,
)
from grassd.daemon.core.errors import ConfigError


def reports(svc) -> list[str]:
    """The run reports kept in reports/ (beside them the status page, index.html)."""
    return sorted(p.name for p in svc.reports_dir.iterdir() if p.name != "index.html")


def corrupt_bundle(inbox, name: str) -> None:
    """A bundle whose EXR is cut short after a sound header: the run starts and is rejected by
    the renderer's reader (a run row with status rejected)."""
    d = inbox / f".{name}"
    d.mkdir()
    (d / "sky.exr").write_bytes(truncated_exr())
    (d / "manifest.toml").write_text('timestamp = 2026-03-01T12:00:00+01:00\nhdri = "sky.exr"\n'
                                     "ambient_lux = 900.0\n")
    d.rename(inbox / name)


def test_counts_are_bounded_and_the_active_table_survives(tmp_path, hw):
    _, cfg = hw
    conf = write_config(tmp_path / "g.toml", tmp_path / "state", cfg,
                        extra="[retention]\nkeep_reports = 1\nkeep_runs = 1\n")
    svc = service(conf)
    inbox = svc.cfg.light.inbox
    for name, lux in (("b1", 1000.0), ("b2", 1100.0)):
        drop(inbox, name, lux=lux)
        svc.tick()
    r1, r2 = 1, 2
    assert svc.history.current_table().id == r2
    assert reports(svc) == [f"run-{r2:06d}.json", f"run-{r2:06d}.png"]
    assert [r.id for r in svc.history.runs(10)] == [r2]
    assert svc.history.pushes(r1) == [] and svc.history.pushes(r2)  # pushes went with the run
    assert svc.inbox.counts()["archive"] == 2  # keep_days (30) not reached

    corrupt_bundle(inbox, "b3")
    svc.tick()
    r3 = svc.history.runs(1)[0]
    assert r3.status == "rejected" and r3.id == 3
    # the newest row is the failed run, but the active table's run is never pruned
    assert [r.id for r in svc.history.runs(10)] == [3, r2]
    assert svc.history.current_table().id == r2
    assert reports(svc) == [f"run-{r2:06d}.json", f"run-{r2:06d}.png"]

    out = svc.scheduled_run("interval")  # the latest archived bundle's light is still there
    assert out.status == "ok", out
    assert [r.id for r in svc.history.runs(10)] == [out.run_id]
    assert reports(svc) == [f"run-{out.run_id:06d}.json", f"run-{out.run_id:06d}.png"]
    assert (svc.reports_dir / "index.html").is_file()  # retention leaves the status page
    svc.shutdown()


def test_old_bundles_and_reports_expire_but_the_latest_bundle_stays(tmp_path, hw):
    _, cfg = hw
    keep_days = 2.0 / 86400  # two seconds
    conf = write_config(tmp_path / "g.toml", tmp_path / "state", cfg,
                        extra=f"[retention]\nkeep_days = {keep_days!r}\n")
    svc = service(conf)
    inbox = svc.cfg.light.inbox
    drop(inbox, "old")
    (inbox / "bad").mkdir()
    (inbox / "bad" / "manifest.toml").write_text("this is not TOML [")
    svc.tick()
    assert svc.inbox.counts() == {"inbox": 0, "processing": 0, "archive": 1, "rejected": 1}
    first = svc.history.current_table()
    assert first.report_path is not None
    time.sleep(2.3)
    drop(inbox, "new", lux=1300.0)
    svc.tick()
    counts = svc.inbox.counts()
    assert (counts["archive"], counts["rejected"]) == (1, 0)
    assert [p.name.split("-", 1)[1] for p in svc.inbox.archive.iterdir()] == ["new"]
    old = svc.history.run(first.id)  # the row stays (keep_runs), its expired report does not
    assert old.report_path is None and old.plot_path is None
    assert not any(p.name.startswith(f"run-{first.id:06d}") for p in svc.reports_dir.iterdir())
    time.sleep(2.3)
    out = svc.scheduled_run("interval")  # the latest archived bundle never expires
    assert out.status == "ok", out
    assert [p.name.split("-", 1)[1] for p in svc.inbox.archive.iterdir()] == ["new"]
    assert svc.history.run(out.run_id).input_hashes["bundle"] == \
        svc.history.latest_archived().bundle_hash
    svc.shutdown()


@pytest.mark.parametrize("key, value", [("keep_days", "0"), ("keep_reports", "0"),
                                        ("keep_runs", "-3"), ("keep_forever", "true")])
def test_retention_keys_are_validated(key, value):
    text = re.sub(r"\n\[retention\][^\[]*", "\n", default_config_text())
    assert parse_config(text).retention == RetentionConfig()  # documented defaults
    text += f"\n[retention]\n{key} = {value}\n"
    with pytest.raises(ConfigError, match=rf"g.toml:\d+: retention.{key}"):
        parse_config(text, source="g.toml")
