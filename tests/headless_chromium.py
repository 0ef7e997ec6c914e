"""Headless Chromium driven over the DevTools protocol through a pipe (``--remote-debugging-pipe``:
the browser reads commands on its fd 3 and answers on fd 4, NUL-separated JSON; no port is
opened). Used by the tests of pages the project writes: load a file:// URL at a given
viewport width, collect console messages, uncaught exceptions and log errors, evaluate
JavaScript, and take a full-page screenshot."""

from __future__ import annotations

import base64
import fcntl
import json
import os
import shutil
import subprocess
import tempfile
import time
from pathlib import Path
from typing import Any

CHROMIUM = next((p for p in (shutil.which(n) for n in ("chromium", "chromium-browser",
                                                       "google-chrome")) if p), None)
#: the one line a test tier prints when the browser is missing
MISSING = ("browser tests need Chromium: apt-get install -y chromium (Debian), then run again")


class Browser:
    """One headless Chromium process; use as a context manager."""

    def __init__(self, timeout_s: float = 30.0) -> None:
        assert CHROMIUM is not None, MISSING
        self.timeout_s = timeout_s
        self._profile = tempfile.mkdtemp(prefix="grassd-chromium-")
        to_r, self._to_w = os.pipe()  # we write commands, the browser reads them on fd 3
        self._from_r, from_w = os.pipe()  # the browser answers on fd 4

        def fds() -> None:  # in the child, before exec (close_fds runs after: keep 3, 4)
            a, b = (fcntl.fcntl(fd, fcntl.F_DUPFD, 10) for fd in (to_r, from_w))
            os.dup2(a, 3)
            os.dup2(b, 4)

        args = [CHROMIUM, "--headless=new", "--remote-debugging-pipe", "--no-sandbox",
                "--disable-gpu", "--no-first-run", "--no-default-browser-check",
                "--disable-extensions", "--hide-scrollbars", "--mute-audio",
                f"--user-data-dir={self._profile}", "about:blank"]
        self.proc = subprocess.Popen(args, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                     stderr=subprocess.PIPE, preexec_fn=fds,
                                     pass_fds=(3, 4))
        os.close(to_r)
        os.close(from_w)
        self._buf = b""
        self._id = 0
        self.events: list[dict[str, Any]] = []

    def __enter__(self) -> Browser:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """End the browser and remove its profile."""
        try:
            self.send("Browser.close")
        except Exception:  # already gone: fine
            pass
        try:
            self.proc.wait(10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        for fd in (self._to_w, self._from_r):
            try:
                os.close(fd)
            except OSError:
                pass
        shutil.rmtree(self._profile, ignore_errors=True)

    # ------------------------------------------------------------------ protocol
    def _read_message(self, deadline: float) -> dict[str, Any]:
        import select

        while b"\0" not in self._buf:
            left = deadline - time.monotonic()
            if left <= 0:
                raise TimeoutError("no answer from Chromium")
            ready, _, _ = select.select([self._from_r], [], [], left)
            if ready:
                chunk = os.read(self._from_r, 1 << 20)
                if not chunk:
                    err = self.proc.stderr.read().decode(errors="replace") if self.proc.stderr \
                        else ""
                    raise RuntimeError(f"Chromium closed the pipe: {err[-2000:]}")
                self._buf += chunk
        msg, self._buf = self._buf.split(b"\0", 1)
        return json.loads(msg)

    def send(self, method: str, session: str | None = None, **params: Any) -> dict[str, Any]:
        """Send one command; return its result (events meanwhile go to :attr:`events`)."""
        self._id += 1
        msg: dict[str, Any] = {"id": self._id, "method": method, "params": params}
        if session is not None:
            msg["sessionId"] = session
        os.write(self._to_w, json.dumps(msg).encode() + b"\0")
        deadline = time.monotonic() + self.timeout_s
        while True:
            m = self._read_message(deadline)
            if m.get("id") == self._id:
                if "error" in m:
                    raise RuntimeError(f"{method}: {m['error']}")
                return m.get("result", {})
            self.events.append(m)

    def wait_event(self, method: str, session: str) -> dict[str, Any]:
        """Wait for event ``method`` of ``session`` (also looking at those already seen)."""
        deadline = time.monotonic() + self.timeout_s
        while True:
            for m in self.events:
                if m.get("method") == method and m.get("sessionId") == session:
                    m["_seen"] = True
                    return m
            self.events.append(self._read_message(deadline))

    # ------------------------------------------------------------------ pages
    def open(self, url: str, width: int, height: int = 800, mobile: bool = False) -> Page:
        """A new tab showing ``url`` at a ``width`` x ``height`` CSS-pixel viewport, loaded."""
        target = self.send("Target.createTarget", url="about:blank")["targetId"]
        session = self.send("Target.attachToTarget", targetId=target,
                            flatten=True)["sessionId"]
        for domain in ("Page", "Runtime", "Log"):
            self.send(f"{domain}.enable", session)
        self.send("Emulation.setDeviceMetricsOverride", session, width=width, height=height,
                  deviceScaleFactor=1, mobile=mobile)
        self.send("Page.navigate", session, url=url)
        self.wait_event("Page.loadEventFired", session)
        return Page(self, session)


class Page:
    """A loaded tab of :class:`Browser`."""

    def __init__(self, browser: Browser, session: str) -> None:
        self.browser = browser
        self.session = session

    def evaluate(self, expression: str) -> Any:
        """The value of JavaScript ``expression`` in the page."""
        r = self.browser.send("Runtime.evaluate", self.session, expression=expression,
                              returnByValue=True)
        if "exceptionDetails" in r:
            raise RuntimeError(f"{expression}: {r['exceptionDetails']}")
        return r["result"].get("value")

    def problems(self) -> list[str]:
        """Console messages, uncaught exceptions and log entries of level warning or error."""
        out = []
        for m in self.browser.events:
            if m.get("sessionId") != self.session:
                continue
            p = m.get("params", {})
            if m.get("method") == "Runtime.consoleAPICalled":
                out.append(f"console.{p.get('type')}: {p.get('args')}")
            elif m.get("method") == "Runtime.exceptionThrown":
                d = p.get("exceptionDetails", {})
                out.append(f"exception: {d.get('exception', {}).get('description') or d}")
            elif m.get("method") == "Log.entryAdded" and p["entry"]["level"] in ("warning",
                                                                                  "error"):
                e = p["entry"]
                out.append(f"log {e['level']}: {e.get('text')} ({e.get('url', '')})")
        return out

    def screenshot(self, path: Path) -> Path:
        """A PNG of the whole page (the viewport stretched to the content height)."""
        metrics = self.browser.send("Page.getLayoutMetrics", self.session)
        size = metrics["cssContentSize"]
        width = int(self.evaluate("window.innerWidth"))
        r = self.browser.send("Page.captureScreenshot", self.session, format="png",
                              captureBeyondViewport=True,
                              clip={"x": 0, "y": 0, "width": width,
                                    "height": int(size["height"]), "scale": 1})
        path.write_bytes(base64.b64decode(r["data"]))
        return path

    def wait_for(self, expression: str, timeout_s: float = 60.0, poll_s: float = 0.1) -> Any:
        """Poll JavaScript ``expression`` until it is truthy; its value (AssertionError with
        the page's problems on timeout)."""
        deadline = time.monotonic() + timeout_s
        while True:
            value = self.evaluate(expression)
            if value:
                return value
            if time.monotonic() > deadline:
                raise AssertionError(f"{expression!r} still false after {timeout_s} s; "
                                     f"page problems: {self.problems()}")
            time.sleep(poll_s)

    def set_files(self, selector: str, paths: list[Path]) -> None:
        """Choose ``paths`` in the file input ``selector`` (as a person picking files does:
        its change event fires)."""
        root = self.browser.send("DOM.getDocument", self.session)["root"]["nodeId"]
        node = self.browser.send("DOM.querySelector", self.session, nodeId=root,
                                 selector=selector)["nodeId"]
        self.browser.send("DOM.setFileInputFiles", self.session, nodeId=node,
                          files=[str(p) for p in paths])

    def drag(self, start: tuple[float, float], end: tuple[float, float], steps: int = 8) -> None:
        """Press the mouse at ``start`` (CSS px in the viewport), move to ``end`` in ``steps``
        and release."""
        def mouse(kind: str, x: float, y: float, buttons: int) -> None:
            self.browser.send("Input.dispatchMouseEvent", self.session, type=kind, x=x, y=y,
                              button="left", buttons=buttons, clickCount=1)

        mouse("mousePressed", *start, 1)
        for k in range(1, steps + 1):
            t = k / steps
            mouse("mouseMoved", start[0] + t * (end[0] - start[0]),
                  start[1] + t * (end[1] - start[1]), 1)
        mouse("mouseReleased", *end, 0)
