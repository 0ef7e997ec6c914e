"""systemd's notify protocol (sd_notify(3)) without libsystemd.

A service of ``Type=notify`` reports its state by sending newline-separated ``KEY=VALUE``
assignments in one datagram to the AF_UNIX socket named by ``$NOTIFY_SOCKET``: ``READY=1``
after start-up, ``STATUS=...`` free text for ``systemctl status``, ``WATCHDOG=1`` at least every
``$WATCHDOG_USEC`` microseconds when ``WatchdogSec=`` is set, ``RELOADING=1`` and
``STOPPING=1``. A socket name starting with ``@`` is in the Linux abstract namespace (the ``@``
stands for a leading NUL byte). Without ``$NOTIFY_SOCKET`` (not run by systemd) every call is a
silent no-op that returns False.

Notifying is never fatal: a value is made one line by
:func:`~grassd.daemon.core.safe_text.one_line` (a newline in ``STATUS=`` would end the assignment
and start another: a bundle's name could forge ``READY=1`` or ``MAINPID=``) and cut to
:data:`MAX_VALUE_CHARS` (systemd ignores a datagram over 4096 bytes); a send that fails for any
reason returns False, logged once as a warning and then at debug level.
"""

from __future__ import annotations

import logging
import os
import socket
import time

from grassd.daemon.core.safe_text import one_line

log = logging.getLogger(__name__)

#: characters kept of one value (a UTF-8 character has up to 4 bytes; systemd drops a
#: notification of 4096 bytes or more whole)
MAX_VALUE_CHARS = 900


class Notifier:
    """Sends sd_notify messages to ``socket_path`` (default: ``$NOTIFY_SOCKET``).

    Also tracks the watchdog: :attr:`watchdog_interval_s` is half of ``$WATCHDOG_USEC`` (the
    interval systemd recommends), ``None`` when no watchdog is configured for this process.
    """

    def __init__(self, socket_path: str | None = None, *, env: dict[str, str] | None = None):
        env = dict(os.environ) if env is None else env
        self.socket_path = socket_path if socket_path is not None else env.get("NOTIFY_SOCKET")
        self.watchdog_interval_s: float | None = None
        usec = env.get("WATCHDOG_USEC")
        pid = env.get("WATCHDOG_PID")
        if usec and usec.isdigit() and int(usec) > 0 and (not pid or pid == str(os.getpid())):
            self.watchdog_interval_s = int(usec) / 2e6
        self._last_ping = 0.0
        self._sock: socket.socket | None = None
        self._warned = False

    @property
    def enabled(self) -> bool:
        """True when a notify socket is configured."""
        return bool(self.socket_path)

    def _address(self) -> str | bytes:
        assert self.socket_path
        if self.socket_path.startswith("@"):
            return b"\0" + self.socket_path[1:].encode()
        return self.socket_path

    def send(self, **fields: str | int) -> bool:
        """Send ``KEY=VALUE`` lines (keys upper-cased, each value made one line and cut to
        :data:`MAX_VALUE_CHARS`); returns True when a datagram was sent. Never raises: a
        failure (no socket, systemd gone, its queue full) returns False.

        >>> Notifier(env={}).send(READY=1)
        False
        """
        if not self.enabled:
            return False
        try:
            lines = [f"{key.upper()}={one_line(value, MAX_VALUE_CHARS)}"
                     for key, value in fields.items()]
            if self._sock is None:
                self._sock = socket.socket(socket.AF_UNIX,
                                           socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
                self._sock.setblocking(False)  # a full receiver must never stall the service
            self._sock.sendto("\n".join(lines).encode(), self._address())
        except (OSError, ValueError) as exc:  # systemd gone, socket missing or its queue
            # full, a name that cannot be encoded: never fatal
            self._failed(exc)
            return False
        return True

    def _failed(self, exc: Exception) -> None:
        """Log a failed send: the first as a warning, later ones at debug level (a full
        queue repeats at every status change)."""
        if self._warned:
            log.debug("sd_notify to %s failed: %s", one_line(self.socket_path), one_line(exc))
            return
        self._warned = True
        log.warning("sd_notify to %s failed: %s (the daemon goes on; further failures are "
                    "logged at debug level)", one_line(self.socket_path), one_line(exc))

    def ready(self, status: str | None = None) -> bool:
        """Tell systemd that start-up finished (``READY=1``), with an optional status line."""
        fields: dict[str, str | int] = {"READY": 1}
        if status is not None:
            fields["STATUS"] = status
        fields["MAINPID"] = os.getpid()
        return self.send(**fields)

    def status(self, text: str) -> bool:
        """Set the free-text status shown by ``systemctl status``."""
        return self.send(STATUS=text)

    def watchdog(self, *, force: bool = False) -> bool:
        """Send ``WATCHDOG=1`` if half the watchdog interval has passed (or ``force``)."""
        if self.watchdog_interval_s is None and not force:
            return False
        now = time.monotonic()
        if not force and now - self._last_ping < (self.watchdog_interval_s or 0):
            return False
        self._last_ping = now
        return self.send(WATCHDOG=1)

    def reloading(self) -> bool:
        """Announce a configuration reload (``RELOADING=1``); follow with :meth:`ready`."""
        return self.send(RELOADING=1)

    def stopping(self, status: str | None = None) -> bool:
        """Announce a clean shutdown (``STOPPING=1``)."""
        fields: dict[str, str | int] = {"STOPPING": 1}
        if status is not None:
            fields["STATUS"] = status
        return self.send(**fields)

    def close(self) -> None:
        """Close the datagram socket."""
        if self._sock is not None:
            self._sock.close()
            self._sock = None
