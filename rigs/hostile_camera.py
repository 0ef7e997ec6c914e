"""A hostile OSC camera (or anyone on its Wi-Fi) for the hostile-input tests and benchmarks: a
real HTTP server on 127.0.0.1 that, by the first component of the path, redirects elsewhere,
sends a 300 MiB body (with or without Content-Length, or as an error), trickles one byte a
second (in the body or in the headers), sends nested JSON, garbage instead of HTTP, or a
malformed Content-Length; any other path is an honest camera's small file.

Used by ``tests/daemon/camera/test_camera_hostile_responses.py`` and ``bench_hostile``.
"""

from __future__ import annotations

import json
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

MiB = 1 << 20
HUGE = 300 * MiB
_BLOCK = b"\0" * MiB


class Hostile(BaseHTTPRequestHandler):
    """Answers by the path's first component (``/<mode>/...``); counts requests and bytes."""

    protocol_version = "HTTP/1.1"
    server: HostileServer

    def log_message(self, *args) -> None:  # quiet
        pass

    def do_GET(self) -> None:
        self._serve()

    def do_POST(self) -> None:
        length = int(self.headers.get("Content-Length") or 0)
        self.rfile.read(length)
        self._serve()

    def _send_huge(self, declare: bool, status: int = 200) -> None:
        self.send_response(status)
        if declare:
            self.send_header("Content-Length", str(HUGE))
        else:
            self.send_header("Connection", "close")  # body ends at close, no length
        self.end_headers()
        for _ in range(HUGE // MiB):
            if self.server.stop.is_set():
                return
            self.wfile.write(_BLOCK)
            self.server.sent += MiB

    def _trickle(self, data: bytes) -> None:
        for i in range(len(data)):
            if self.server.stop.wait(self.server.trickle_s):
                return
            self.wfile.write(data[i:i + 1])
            self.wfile.flush()
            self.server.sent += 1

    def _serve(self) -> None:
        srv = self.server
        srv.hits.append(self.path)
        mode = self.path.split("/")[1]
        try:
            if mode == "redirect":
                self.send_response(302)
                self.send_header("Location", srv.redirect_to)
                self.send_header("Content-Length", "0")
                self.end_headers()
            elif mode in ("huge", "huge-declared"):
                self._send_huge(declare=mode == "huge-declared")
            elif mode == "huge-error":
                self._send_huge(declare=False, status=500)
            elif mode == "trickle-body":
                body = json.dumps({"state": {}, "pad": "x" * 200}).encode()
                self.send_response(200)
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                self._trickle(body)
            elif mode == "trickle-head":
                self.close_connection = True
                self._trickle(b"HTTP/1.1 200 OK\r\nContent-Length: 2\r\n" + b"X-Pad: a\r\n" * 50)
            elif mode == "nested":
                body = b"[" * 200_000 + b"]" * 200_000
                self.send_response(200)
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                self.wfile.write(body)
            elif mode == "garbage":
                self.close_connection = True
                self.wfile.write(b"\x00\xffNOT HTTP AT ALL\r\n\r\n")
            elif mode == "bad-length":
                self.close_connection = True
                self.send_response(200)
                self.send_header("Content-Length", "lots")
                self.send_header("Connection", "close")
                self.end_headers()
                self.wfile.write(b'{"state": {}}')
            else:  # an honest camera's file
                body = b"\xff\xd8 a small shot \xff\xd9"
                self.send_response(200)
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                self.wfile.write(body)
        except OSError:  # the client hung up: what it should do
            srv.client_hung_up = True


class HostileServer(ThreadingHTTPServer):
    daemon_threads = True

    def __init__(self) -> None:
        super().__init__(("127.0.0.1", 0), Hostile)
        self.hits: list[str] = []
        self.sent = 0
        self.stop = threading.Event()
        self.client_hung_up = False
        self.redirect_to = ""
        self.trickle_s = 1.0  # one byte a second
        self.thread = threading.Thread(target=self.serve_forever, kwargs={"poll_interval": 0.05},
                                       daemon=True)

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.server_address[1]}"

    def __enter__(self) -> HostileServer:
        self.thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop.set()
        self.shutdown()
        self.server_close()
        self.thread.join(timeout=5)
        assert not self.thread.is_alive()
