"""A write failure while committing a run (full disk: a real 16 KiB tmpfs mounted over the
reports directory when we may mount, else a read-only reports directory) is a failed run with
a clear error in status; the daemon lives on, the active table, the controllers and the history
keep what they had, and the bundle waits in processing/ and succeeds once space is back."""

from __future__ import annotations

import contextlib
import errno
import os
import subprocess
import time
from pathlib import Path

import pytest
from daemon_harness import after_first_bundle, drop

from grassd.firmware_proto.tables import table_crc


@contextlib.contextmanager
def unwritable(d: Path):
    """Make directory ``d`` refuse new files: a full tmpfs over it (root), else mode 0555.
    Yields the errno name the daemon should report."""
    mounted = os.geteuid() == 0 and subprocess.run(
        ["mount", "-t", "tmpfs", "-o", "size=16k,mode=0755", "tmpfs", str(d)],
        capture_output=True).returncode == 0
    if mounted:
        try:
            with contextlib.suppress(OSError), open(d / "filler", "wb") as fh:
                while True:  # fill it to the last block
                    fh.write(b"\0" * 4096)
                    fh.flush()
            with pytest.raises(OSError) as full:
                (d / "probe").write_bytes(b"\0" * 8192)
            assert full.value.errno == errno.ENOSPC
            yield "ENOSPC"
        finally:
            subprocess.run(["umount", "-l", str(d)], check=True)
    else:
        if os.geteuid() == 0:
            pytest.skip("root without mount: neither ENOSPC nor EACCES can be produced")
        os.chmod(d, 0o555)
        try:
            yield "EACCES"
        finally:
            os.chmod(d, 0o755)


def test_full_disk_fails_the_run_not_the_daemon(tmp_path, hw):
    sim, cfg = hw
    svc, good = after_first_bundle(tmp_path, cfg, retry_s=0.5)
    inbox = svc.cfg.light.inbox
    assert good.status == "ok"
    crcs = {table_crc(dev.active_table()) for bus in sim.buses for dev in bus.controllers}
    assert crcs == {good.table_crc}
    runs_before = svc.history.run_count()

    with unwritable(svc.reports_dir) as code:
        drop(inbox, "b2", lux=1500.0)
        svc.tick()  # must not raise
        failed = svc.history.runs(1)[0]
        assert failed.status == "failed" and code in failed.error
        assert str(svc.reports_dir) in failed.error
        assert svc.history.current_table().id == good.id  # the active table is untouched
        assert svc.history.run_count() == runs_before + 1
        assert {table_crc(dev.active_table()) for bus in sim.buses
                for dev in bus.controllers} == {good.table_crc}
        assert svc.inbox.counts()["processing"] == 1  # the bundle waits, not rejected
        st = svc.status().to_json()
        [w] = st["waiting_bundles"]
        assert w["bundle"] == "b2" and code in w["reason"]
        assert st["runs"][0]["error"] == failed.error
        svc.tick()  # within the backoff: no new run
        assert svc.history.run_count() == runs_before + 1
        time.sleep(0.6)
        svc.tick()  # retried once, still full: backoff doubles
        assert svc.history.run_count() == runs_before + 2
        assert svc.status().to_json()["waiting_bundles"][0]["retry_in_s"] > 0.5

    time.sleep(1.1)  # space is back
    svc.tick()
    new = svc.history.current_table()
    assert new.id > failed.id and new.report_path and Path(new.report_path).is_file()
    assert svc.inbox.counts()["processing"] == 0 and svc.inbox.counts()["archive"] == 2
    assert svc.status().to_json()["waiting_bundles"] == []
    assert svc.history.run(good.id).status == "ok"  # history kept
    svc.shutdown()
