"""End to end with the C firmware: `grassd run` pushes a calibrated table to the controllers of
the embedded default configuration's two buses, each a grassfw-posix process on a pty or a
QEMU mps2-an500 instance behind the bus relay, and the table becomes active and in sync."""

from __future__ import annotations

import pytest
from firmware_tiers import firmware_params
from test_grassd_run_end_to_end import Daemon, manifest, wait_for


@pytest.mark.parametrize("firmware", firmware_params("posix", "qemu"))
def test_bundle_becomes_active_on_c_firmware_controllers(tmp_path, firmware):
    d = Daemon(tmp_path, firmware=firmware)
    try:
        d.start()
        d.drop("first", manifest(1, lux=9000.0))
        wait_for(lambda: d.status()["health"] == "ok", 120, "table on every controller", d)
        st = d.status()
        table = st["desired_table"]
        assert d.crcs() == [table["table_crc"]] * 2  # read from the controllers' storage
        assert [c["in_sync"] for c in st["controllers"]] == [True, True]
        with d.history() as h:
            assert [p.ok for p in h.pushes(table["run_id"])] == [True, True]
    finally:
        d.close()
    assert all(b.errors == 0 for b in d.hw.buses)
