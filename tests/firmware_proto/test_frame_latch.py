"""The frame latch (PROTOCOL.md section 3): what the vector conversation ``latch.json`` shows,
checked against the spec's rules rather than against itself; the client's STAGE_LEVEL / SHOW
with the Python model on a pty, including a controller from before the latch."""

from __future__ import annotations

import numpy as np
import pytest

from grassd.firmware_proto.client import ControllerClient, ControllerUnsupported
from grassd.firmware_proto.codec import decode_frame
from grassd.firmware_proto.messages import MsgType, NakCode
from grassd.rigs.firmware import Controller, simulated_config
from grassd.rigs.golden import example_table, load_vectors
from grassd.rigs.simulator import SimulatedBus


def _steps():
    steps = load_vectors()["latch.json"]["steps"]
    out = []
    for s in steps:
        req = decode_frame(bytes.fromhex(s["request"]["hex"])[:-1])
        ans = None if s["answer"] is None else decode_frame(bytes.fromhex(s["answer"]["hex"])[:-1])
        out.append((req, ans))
    return out


def test_the_latch_vectors_follow_the_spec():
    t = example_table()
    half = t // 2
    steps = _steps()
    targets = [np.array([p[1] for p in a.message.pairs()]) for r, a in steps
               if r.message.TYPE == MsgType.GET_POSITIONS]
    # every broadcast is unanswered, every frame to address 3 answered
    assert all((a is None) == (r.address == 0) for r, a in steps)
    assert steps[1][1].message.error == NakCode.NO_TABLE  # STAGE without a table
    assert not targets[0].any()  # staged: nothing moves
    assert not targets[1].any()  # SHOW of another frame: nothing shown
    np.testing.assert_array_equal(targets[2], t[[0, 64, 128, 255]])  # broadcast SHOW
    np.testing.assert_array_equal(targets[3], targets[2])  # shown already: no change
    np.testing.assert_array_equal(targets[4], [t[0], t[64], t[200], t[200]])  # frame 8 dropped
    np.testing.assert_array_equal(targets[5], targets[4])  # a commit moves nothing
    np.testing.assert_array_equal(targets[6], half[[255] * 4])  # the table at the SHOW
    nak = [a for r, a in steps if r.message.TYPE == MsgType.STAGE_LEVEL][-1]
    assert (nak.message.error, nak.message.detail) == (NakCode.BAD_PIXEL, 16)
    np.testing.assert_array_equal(targets[7], targets[6])  # a broadcast SET_LEVEL: ignored


def test_client_stages_and_shows_and_refuses_a_controller_without_the_latch(tmp_path):
    ctrls = [Controller(simulated_config(1, n_pixels=4), tmp_path / "a"),
             Controller(simulated_config(2, n_pixels=4, latch=False), tmp_path / "b")]
    table = np.arange(256, dtype=np.uint16) * 70
    with SimulatedBus(ctrls, link_path=tmp_path / "tty") as bus, \
            ControllerClient(bus.path) as client:
        for a in (1, 2):
            client.push_table(a, table)
        assert client.supports_latch(1) and not client.supports_latch(2)
        client.stage_levels(1, 0x1FFFF, [1, 2, 3, 4])  # frame numbers wrap at 16 bits
        assert not ctrls[0].targets_um().any()
        client.set_levels(2, [9, 9, 9, 9])
        sent = client.link.bytes_sent
        with pytest.raises(ControllerUnsupported, match="features bit 1"):
            client.stage_levels(2, 1, [5, 5, 5, 5])
        assert client.link.bytes_sent == sent  # refused before sending
        client.show(0xFFFF)
        client.read_status(1)  # the SHOW was on the line before this answer
        np.testing.assert_array_equal(ctrls[0].targets_um(), table[[1, 2, 3, 4]])
        np.testing.assert_array_equal(ctrls[1].targets_um(), table[[9] * 4])  # ignored it
        assert client.retransmissions == 0
