"""Attacks on a running ``grassd studio`` from 127.0.0.1, for the bounded-server tests and
``bench_hostile``: connections that never finish their headers or send too many, a page's
WebSocket that floods small frames and never reads, and requests sent several at once.

Each attack returns what the server answered; the caller judges it (the tests assert the
refusal and its reason, the benchmark prints it beside the studio's peak resident set).
"""

from __future__ import annotations

import base64
import contextlib
import os
import socket
import struct
import threading
import time
import urllib.parse
from collections.abc import Callable
from typing import TypeVar

T = TypeVar("T")

#: the WebSocket opcode of a close frame (RFC 6455 section 5.5.1)
CLOSE = 0x8


def address(url: str) -> tuple[str, int]:
    """(host, port) of a studio's base ``url``."""
    u = urllib.parse.urlsplit(url)
    return u.hostname or "127.0.0.1", int(u.port or 80)


def read_until_closed(conn: socket.socket, timeout_s: float) -> bytes:
    """Everything the server sends until it closes ``conn`` (or ``timeout_s`` passes)."""
    conn.settimeout(max(timeout_s, 0.01))
    got = b""
    with contextlib.suppress(ConnectionResetError, TimeoutError):
        while chunk := conn.recv(65536):
            got += chunk
    return got


def answers(conns: list[socket.socket], deadline: float) -> list[bytes]:
    """What the server sent on each connection by ``deadline`` (time.monotonic()); closes them."""
    out = [read_until_closed(c, deadline - time.monotonic()) for c in conns]
    for c in conns:
        c.close()
    return out


def unfinished_headers(url: str, count: int) -> list[socket.socket]:
    """``count`` connections that each send half a request's headers and wait."""
    host, port = address(url)
    opened = []
    for i in range(count):
        c = socket.create_connection((host, port))
        c.sendall(b"GET /api/state HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow-" + str(i).encode())
        opened.append(c)
    return opened


def header_flood(url: str, count: int, lines: int = 120,
                 line_bytes: int = 8000) -> list[socket.socket]:
    """``count`` connections each sending a request of ``lines`` header lines of
    ``line_bytes`` bytes (sent as far as the server reads it)."""
    host, port = address(url)
    head = b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\n" + b"".join(
        b"X-%d: %s\r\n" % (i, b"a" * line_bytes) for i in range(lines))
    conns = []
    for _ in range(count):
        c = socket.create_connection((host, port))
        c.settimeout(5)
        with contextlib.suppress(OSError):  # closed before all of it was sent
            c.sendall(head)
        conns.append(c)
    return conns


def ws_frame(payload: bytes, opcode: int = 0x2) -> bytes:
    """One masked client frame (RFC 6455) of up to 125 bytes."""
    mask = os.urandom(4)
    masked = bytes(b ^ mask[i % 4] for i, b in enumerate(payload))
    return bytes([0x80 | opcode, 0x80 | len(payload)]) + mask + masked


def server_frames(data: bytes, start: int = 0) -> tuple[list[tuple[int, bytes]], int]:
    """(opcode, payload) of the server's (unmasked) whole frames in ``data`` from offset
    ``start``, and the offset after the last whole one."""
    out, i = [], start
    while i + 2 <= len(data):
        op, n, at = data[i] & 0x0F, data[i + 1] & 0x7F, i + 2
        if n == 126:
            n, at = struct.unpack(">H", data[at:at + 2])[0], at + 2
        elif n == 127:
            n, at = struct.unpack(">Q", data[at:at + 8])[0], at + 8
        if at + n > len(data):
            break
        out.append((op, data[at:at + n]))
        i = at + n
    return out, i


class NotDropped(AssertionError):
    """The studio did not drop a page that never reads within the time given."""


def never_reading_page(url: str, dropped: Callable[[], bool], frames: int = 200_000,
                       limit_s: float = 20.0) -> list[tuple[int, bytes]]:
    """A page's WebSocket (a 4 KiB receive buffer) that sends up to ``frames`` small binary
    frames, each answered with an error, and reads nothing until ``dropped()`` (the server
    says it dropped it) is true; then reads what it was sent. Returns the server's frames
    ((opcode, payload), ending with its close frame). Raises :class:`NotDropped` after
    ``limit_s`` seconds."""
    host, port = address(url)
    c = socket.socket()
    c.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    c.connect((host, port))
    key = base64.b64encode(os.urandom(16))
    c.sendall(b"GET /ws HTTP/1.1\r\nHost: 127.0.0.1\r\nUpgrade: websocket\r\n"
              b"Connection: Upgrade\r\nSec-WebSocket-Key: " + key
              + b"\r\nSec-WebSocket-Version: 13\r\n\r\n")
    head = b""
    while b"\r\n\r\n" not in head:
        head += c.recv(1)
    if not head.startswith(b"HTTP/1.1 101"):
        c.close()
        raise NotDropped(f"the studio did not open the WebSocket: {head[:200]!r}")
    flood = memoryview(ws_frame(b"\x00\x01") * frames)
    c.settimeout(0.2)
    t0 = time.monotonic()
    while not dropped():
        if time.monotonic() - t0 > limit_s:
            c.close()
            raise NotDropped(f"the page was not dropped in {limit_s:g} s")
        if not flood:
            time.sleep(0.1)
            continue
        with contextlib.suppress(TimeoutError):  # the server stops reading once it drops it
            flood = flood[c.send(flood[:65536]):]
    c.settimeout(20)
    got, at, out = b"", 0, []
    with contextlib.suppress(ConnectionResetError, TimeoutError):  # its messages, the close
        while not any(op == CLOSE for op, _ in out[-1:]) and (chunk := c.recv(65536)):
            got += chunk
            more, at = server_frames(got, at)
            out += more
    c.close()
    return out


def close_of(frames: list[tuple[int, bytes]]) -> tuple[int, str] | None:
    """(code, reason) of the first close frame among ``frames``, or None."""
    for op, payload in frames:
        if op == CLOSE and len(payload) >= 2:
            return struct.unpack(">H", payload[:2])[0], payload[2:].decode("utf-8", "replace")
    return None


def post_headers(path: str, length: int, content_type: str = "application/octet-stream"
                 ) -> bytes:
    """The headers of a POST of ``length`` bytes to ``/path`` (its body to follow)."""
    return (f"POST /{path} HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: {content_type}\r\n"
            f"Content-Length: {length}\r\n\r\n").encode()


def at_once(send: Callable[[], T], count: int, timeout_s: float = 120.0) -> list[T]:
    """``send()`` from ``count`` threads started together; their results, in the order they
    came (a thread not done within ``timeout_s`` is left out)."""
    results: list[T] = []
    lock = threading.Lock()

    def one() -> None:
        r = send()
        with lock:
            results.append(r)

    threads = [threading.Thread(target=one, daemon=True) for _ in range(count)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout_s)
    return results
