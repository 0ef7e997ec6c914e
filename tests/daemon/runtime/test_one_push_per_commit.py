"""A committed run reaches every controller through one code path: the main loop's pass that
commits a bundle makes exactly one table transfer (TABLE_BEGIN, chunks, TABLE_COMMIT) per
controller, after exactly one status read, and later reconciles find the table in place and
transfer nothing (simulated controllers on ptys)."""

from __future__ import annotations

from collections import defaultdict

from daemon_harness import drop, service, write_config

from grassd.firmware_proto.messages import MsgType


class WireLog:
    """The requests each simulated controller dispatched (retransmissions answered from its
    reply cache are not dispatched again), by controller address."""

    def __init__(self, sim) -> None:
        self.requests: dict[int, list[MsgType]] = defaultdict(list)
        for bus in sim.buses:
            for ctrl in bus.controllers:
                self._spy(ctrl)

    def _spy(self, ctrl) -> None:
        dispatch, address = ctrl._dispatch, ctrl.config.address

        def logged(version: int, msg_type: int, payload: bytes):
            self.requests[address].append(MsgType(msg_type))
            return dispatch(version, msg_type, payload)

        ctrl._dispatch = logged

    def clear(self) -> None:
        """Forget what was logged so far."""
        self.requests.clear()

    def transfers(self, address: int) -> int:
        """Complete TABLE_BEGIN .. TABLE_COMMIT sequences controller ``address`` received."""
        n, open_ = 0, False
        for m in self.requests[address]:
            if m is MsgType.TABLE_BEGIN:
                open_ = True
            elif m is MsgType.TABLE_COMMIT and open_:
                n, open_ = n + 1, False
        return n

    def begins(self, address: int) -> int:
        """TABLE_BEGIN requests controller ``address`` received."""
        return self.requests[address].count(MsgType.TABLE_BEGIN)

    def status_reads_before_transfer(self, address: int) -> int:
        """GET_STATUS requests controller ``address`` received before its first TABLE_BEGIN."""
        seen = self.requests[address]
        first = seen.index(MsgType.TABLE_BEGIN) if MsgType.TABLE_BEGIN in seen else len(seen)
        return seen[:first].count(MsgType.GET_STATUS)


def test_a_commit_makes_one_transfer_per_controller(tmp_path, hw):
    sim, cfg = hw
    conf = write_config(tmp_path / "g.toml", tmp_path / "state", cfg)
    svc = service(conf, reconcile_s=0.0)  # every pass reconciles
    try:
        wire = WireLog(sim)
        svc.tick()  # nothing to do yet: the controllers hold no table, none is desired
        assert not any(wire.begins(c.address) for c in svc.cfg.controllers)
        wire.clear()
        drop(svc.cfg.light.inbox, "b1")
        svc.tick()  # claims, calibrates, commits and pushes the bundle's table
        cur = svc.history.current_table()
        assert cur is not None and cur.status == "ok"
        addresses = [c.address for c in svc.cfg.controllers]
        assert len(addresses) == 2
        for a in addresses:
            assert wire.transfers(a) == 1 and wire.begins(a) == 1, wire.requests[a]
            assert wire.status_reads_before_transfer(a) == 1, wire.requests[a]
        rows = svc.history.pushes(cur.id)
        assert sorted(r.controller for r in rows if r.ok) == sorted(
            c.name for c in svc.cfg.controllers)
        wire.clear()
        for _ in range(3):  # later passes: the table is in place, nothing is sent again
            svc.tick()
        for a in addresses:
            assert wire.begins(a) == 0, wire.requests[a]
            assert set(wire.requests[a]) == {MsgType.GET_STATUS}
    finally:
        svc.shutdown()
