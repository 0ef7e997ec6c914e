"""A live receiver: one UDP socket and one thread that decodes each datagram
(:mod:`~grassd.daemon.content.packets`) and hands it to a
:class:`~grassd.daemon.content.merge.LiveMerger`.

Whatever arrives costs bounded work and no memory: datagrams are read into one fixed buffer
(one larger than any packet of the format is dropped as oversized, whatever its real size),
every drop is a count in :class:`ReceiverStats`, and the merger's state is capped. The socket's
receive buffer is the kernel's: a flood beyond what the thread decodes is dropped there.
"""

from __future__ import annotations

import contextlib
import enum
import logging
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

from grassd.daemon.content.merge import LiveMerger, Outcome
from grassd.daemon.content.packets import (
    ARTDMX_MAX,
    E131_MAX,
    DmxPacket,
    Malformed,
    NotDmx,
    decode_artdmx,
    decode_e131,
)
from grassd.daemon.core.errors import DaemonError

log = logging.getLogger(__name__)


class ReceiverBindError(DaemonError):
    """A live receiver cannot listen on its address and port (in use, or not this host's)."""


class Protocol(enum.Enum):
    """The live wire formats."""

    SACN = "sacn"
    ARTNET = "artnet"


@dataclass
class ReceiverStats:
    """Counts since the receiver started: datagrams in, accepted, dropped by kind
    (``malformed``, ``oversized``, ``ignored``: well formed but not levels or not our
    universes, ``late``: out of sequence, ``refused``: a sender beyond the cap)."""

    datagrams: int = 0
    accepted: int = 0
    malformed: int = 0
    oversized: int = 0
    ignored: int = 0
    late: int = 0
    refused: int = 0
    terminated: int = 0

    def to_json(self) -> dict[str, int]:
        """The counts as a JSON object."""
        return dict(self.__dict__)


class LiveReceiver:
    """Listens on UDP ``bind``:``port`` for ``protocol`` and feeds ``merger``; ``on_packet``
    is called (in the receiver's thread) after each accepted packet of the stream's last
    universe (a whole frame) and each stream-terminated one. With multicast
    ``groups`` the socket listens on every address at ``port`` and joins each group on the
    interface whose address is ``bind`` ("0.0.0.0": the kernel's choice)."""

    def __init__(self, protocol: Protocol, bind: str, port: int, merger: LiveMerger,
                 on_packet: Callable[[], None] | None = None,
                 groups: tuple[str, ...] = ()) -> None:
        self.protocol = protocol
        self.merger = merger
        self.on_packet = on_packet
        self.stats = ReceiverStats()
        self._max = E131_MAX if protocol is Protocol.SACN else ARTDMX_MAX
        self._buf = bytearray(self._max + 1)
        self._stop = threading.Event()
        try:
            self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
            self._sock.bind(("0.0.0.0" if groups else bind, port))
            for group in groups:  # on the interface whose address is ``bind``
                mreq = socket.inet_aton(group) + socket.inet_aton(bind)
                self._sock.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP, mreq)
        except OSError as exc:
            self._sock.close()
            raise ReceiverBindError(
                f"{protocol.value} receiver cannot listen on {bind}:{port}: {exc.strerror}; "
                f"set [content.{protocol.value}] bind/port to a free address of this host, or "
                "enabled = false") from None
        self._sock.settimeout(0.2)  # how soon stop() is noticed
        self.address = self._sock.getsockname()
        self._thread = threading.Thread(target=self._serve, name=f"content-{protocol.value}",
                                        daemon=True)

    def start(self) -> LiveReceiver:
        """Start the receiving thread."""
        self._thread.start()
        return self

    def _serve(self) -> None:
        view = memoryview(self._buf)
        while not self._stop.is_set():
            try:
                n, peer = self._sock.recvfrom_into(self._buf)
            except TimeoutError:
                continue
            except OSError:
                if self._stop.is_set():
                    return
                time.sleep(0.05)
                continue
            try:
                self._take(view[:n], n, peer)
            except Exception:  # a bug here must not stop the receiver
                log.exception("%s receiver: unexpected error (still receiving)",
                              self.protocol.value)

    def _take(self, data: memoryview, n: int, peer: tuple[str, int]) -> None:
        st = self.stats
        st.datagrams += 1
        if n > self._max:
            st.oversized += 1
            return
        try:
            pkt: DmxPacket = (decode_e131(data) if self.protocol is Protocol.SACN
                              else decode_artdmx(data, f"{peer[0]}:{peer[1]}"))
        except Malformed:
            st.malformed += 1
            return
        except NotDmx:
            st.ignored += 1
            return
        frames = self.merger.frames_in
        out = self.merger.offer(pkt, time.monotonic())
        if out is Outcome.ACCEPTED:
            st.accepted += 1
            # the player is woken by the stream's last universe: a frame over several
            # universes goes out whole (the next tick takes a partial one at the latest)
            if self.on_packet is not None and self.merger.frames_in != frames:
                self.on_packet()
        elif out is Outcome.LATE:
            st.late += 1
        elif out is Outcome.REFUSED:
            st.refused += 1
        elif out is Outcome.TERMINATED:
            st.terminated += 1
            if self.on_packet is not None:
                self.on_packet()
        else:
            st.ignored += 1

    def stop(self) -> None:
        """Stop the thread and close the socket."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(2)
        with contextlib.suppress(OSError):
            self._sock.close()
