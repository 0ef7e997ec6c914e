"""The pyserial client against simulated controllers on real pseudo-terminals."""

from __future__ import annotations

import numpy as np
import pytest
from firmware_tiers import CLEAN_LINK, firmware_params

from grassd.firmware_proto import client as client_mod
from grassd.firmware_proto.client import ControllerClient, RetryPolicy
from grassd.firmware_proto.errors import (
    AddressError,
    ControllerTimeout,
    NakError,
    PortConfigError,
    PortUnavailable,
    TableError,
    TransientError,
)
from grassd.firmware_proto.messages import GetPositions, Nak, NakCode
from grassd.firmware_proto.tables import table_crc
from grassd.rigs.sim_backends import open_bus
from grassd.rigs.simulator import SimulatedBus, make_controllers, start_buses

FAST = RetryPolicy(timeout_s=0.05, retries=2, backoff_s=0.005)


@pytest.fixture(params=firmware_params("model", "posix", "qemu"))
def bus(request, tmp_path):
    """Controllers 1-3 (4 pixels) on one pty: the Python model or the C firmware
    (posix process, QEMU image)."""
    with open_bus(request.param, tmp_path / "state", [1, 2, 3], n_pixels=4,
                  link_path=tmp_path / "ttyGRASS0") as b:
        yield b
        assert b.errors == 0


def rand_table(seed, shape=(256,)):
    return np.random.default_rng(seed).integers(0, 20001, shape).astype(np.uint16)


def test_scan_push_status_on_a_shared_bus(bus):
    with ControllerClient(bus.path, policy=CLEAN_LINK, seed=1) as c:
        found = c.scan(range(1, 7), timeout_s=0.02, retries=0)
        assert sorted(found) == [1, 2, 3]
        assert found[2].uid == 0x6A5D0002 and found[2].firmware_version == "1.0.0"
        tables = {a: rand_table(a) for a in (1, 2, 3)}
        for a, t in tables.items():
            st = c.push_table(a, t, table_id=100 + a)
            assert (st.table_id, st.table_crc, st.generation) == (100 + a, table_crc(t), 1)
        for ctl in bus.controllers:
            assert np.array_equal(ctl.active_table(), tables[ctl.config.address])
            assert c.read_status(ctl.config.address).table_id == 100 + ctl.config.address
        # pushing what is already active changes nothing
        assert c.push_table(2, tables[2], table_id=102).generation == 1
        # per-pixel tables, default id = CRC
        pp = rand_table(9, (4, 256))
        st = c.push_table(3, pp)
        assert st.kind == 1 and st.n_tables == 4 and st.table_id == table_crc(pp)
        assert np.array_equal(bus.controllers[2].active_table(), pp)
        assert c.retransmissions == 0


def test_module_level_helpers(bus):
    t = rand_table(5)
    st = client_mod.push_table(bus.path, 1, t, table_id=7, policy=FAST)
    assert st.table_id == 7
    assert client_mod.read_status(bus.path, 1, policy=FAST) == st
    assert client_mod.hello(bus.path, 2, policy=FAST).n_pixels == 4
    assert sorted(client_mod.scan(bus.path, range(1, 5), timeout_s=0.02)) == [1, 2, 3]


def test_levels_and_positions(bus):
    with ControllerClient(bus.path, policy=FAST) as c:
        c.push_table(1, np.arange(256, dtype=np.uint16) * 40)
        c.set_levels(1, [0, 10, 100, 255])
        pos = c.read_positions(1)
        assert pos.shape == (4, 2)
        assert pos[:, 1].tolist() == [0, 400, 4000, 10200]
        with pytest.raises(NakError, match="BAD_PIXEL") as exc:
            c.set_levels(1, [1, 2], first_pixel=3)
        assert exc.value.code == NakCode.BAD_PIXEL
        reply = c.request(1, GetPositions(0, 0))
        assert isinstance(reply, Nak) and reply.error == NakCode.BAD_PAYLOAD
        with pytest.raises(NakError, match="NO_TABLE"):
            c.set_levels(2, [1])


def test_tables_the_controller_cannot_take_are_refused_before_sending(bus):
    with ControllerClient(bus.path, policy=FAST) as c:
        c.push_table(1, rand_table(1), table_id=1)
        # 2 chunks and 2 headers, or more where a loaded machine made the client retransmit
        written = bus.controllers[0].eeprom.writes
        assert written >= 4
        with pytest.raises(TableError, match="per-pixel tables must have shape"):
            c.push_table(1, rand_table(2, (3, 256)))
        with pytest.raises(TableError, match="at most 20000 um"):
            c.push_table(1, np.full(256, 25000))
        with pytest.raises(TableError, match="shape"):
            c.push_table(1, np.zeros(10))
        with pytest.raises(TableError, match="table_id"):
            c.push_table(1, rand_table(3), table_id=-1)
        assert c.read_status(1).generation == 1  # nothing changed
        assert bus.controllers[0].eeprom.writes == written  # nothing of the refused tables


def test_absent_controller_times_out_with_a_clear_error(bus):
    with ControllerClient(bus.path, policy=FAST) as c:
        with pytest.raises(ControllerTimeout, match="controller 9 on .*HELLO failed after 3 tries"):
            c.hello(9)
        assert c.retransmissions == 2
        with pytest.raises(AddressError, match="address must be 1..247"):
            c.hello(0)


def test_missing_port_is_unavailable(tmp_path):
    with ControllerClient(str(tmp_path / "nope"), policy=FAST) as c:
        with pytest.raises(PortUnavailable, match="cannot open serial port") as exc:
            c.read_status(1)
        assert isinstance(exc.value, TransientError)


def test_unplug_and_replug_is_survived(bus):
    t1, t2 = rand_table(1), rand_table(2)
    policy = RetryPolicy(timeout_s=0.05, retries=6, backoff_s=0.01)
    with ControllerClient(bus.path, policy=policy) as c:
        c.push_table(1, t1)
        bus.unplug(0.08)  # while the client holds the port open
        st = c.push_table(1, t2)
        assert st.table_crc == table_crc(t2)
        assert bus.unplugs == 1 and bus.device.startswith("/dev/")
        assert c.link.opens == 2
        assert bus.controllers[0].boots == 2  # USB power went away with the port


def test_separate_ports(tmp_path):
    buses = start_buses(tmp_path / "s", 2, shared=False, link_dir=tmp_path / "links",
                        n_pixels=2)
    try:
        for i, b in enumerate(buses):
            assert b.path == str(tmp_path / "links" / f"bus{i}")
            st = client_mod.push_table(b.path, 1, rand_table(i), policy=FAST)
            assert st.table_crc == table_crc(rand_table(i))
    finally:
        for b in buses:
            b.stop()


def test_timeouts_scale_with_a_slow_paced_line(tmp_path):
    """At 9600 baud a 256-byte chunk takes ~0.29 s on the wire: the client must wait for it
    rather than retransmit, although its turn-around margin is only half of that (more would
    hide the scaling; less lets a loaded machine's scheduling retransmit)."""
    ctrls = make_controllers(tmp_path, [4], n_pixels=1)
    margin = RetryPolicy(timeout_s=0.15, retries=2, backoff_s=0.005)
    with SimulatedBus(ctrls, link_path=tmp_path / "slow", baud=9600) as slow, \
            ControllerClient(slow.path, baudrate=9600, policy=margin) as c:
        t = rand_table(11)
        assert c.push_table(4, t).table_crc == table_crc(t)
        assert c.retransmissions == 0
        wire = slow.bytes_from_host + slow.bytes_to_host
        assert 512 < wire < 800


def test_rs485_mode_on_a_pty_is_a_clear_permanent_error(bus):
    with ControllerClient(bus.path, policy=FAST, rs485=True) as c:
        with pytest.raises(PortConfigError, match="does not support the kernel's RS-485 mode"):
            c.hello(1)
        assert not c.link.is_open
    with ControllerClient(bus.path, policy=FAST) as c:  # without it the same pty works
        assert c.hello(1).n_pixels == 4


def test_local_echo_of_the_host_is_ignored(tmp_path):
    """An RS-485 adapter with local echo returns every request to the host; it must not be
    mistaken for an answer."""
    ctrls = make_controllers(tmp_path, [1], n_pixels=1)
    with SimulatedBus(ctrls, link_path=tmp_path / "echo", echo=True) as b, \
            ControllerClient(b.path, policy=CLEAN_LINK) as c:
        t = rand_table(12)
        assert c.push_table(1, t).table_crc == table_crc(t)
        assert c.retransmissions == 0 and c.stale_frames >= 5  # the echoed requests
