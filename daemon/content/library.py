"""The playlist's and the idle picture's files, read off the player's thread: a picture that
takes long to decode never delays a frame (a live one included).

:meth:`PictureLibrary.get` answers at once: the animation once it is read, None while it is
being read or when it cannot be (logged once, with the reason). Each file is read once; the
library holds the animations of the configured files only (each bounded by
:mod:`~grassd.daemon.content.pictures`).
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from pathlib import Path

from grassd.daemon.content.pictures import Animation, PictureError, load_animation

log = logging.getLogger(__name__)


class PictureLibrary:
    """Reads ``paths`` (pictures or animations) in a thread of its own, resized to ``rows`` x
    ``cols``, each file at most ``max_bytes``."""

    def __init__(self, paths: list[Path], rows: int, cols: int, max_bytes: int) -> None:
        self.rows, self.cols, self.max_bytes = rows, cols, max_bytes
        self._done: dict[Path, Animation | None] = {}
        self._lock = threading.Lock()
        self._todo: queue.Queue[Path | None] = queue.Queue()
        self._paths = list(dict.fromkeys(paths))
        for p in self._paths:
            self._todo.put(p)
        self._thread = threading.Thread(target=self._run, name="content-pictures",
                                        daemon=True)

    def start(self) -> PictureLibrary:
        """Start reading."""
        self._thread.start()
        return self

    def _run(self) -> None:
        while (path := self._todo.get()) is not None:
            try:
                anim: Animation | None = load_animation(path, self.rows, self.cols,
                                                        self.max_bytes)
            except PictureError as exc:
                log.warning("content: %s is left out: %s", path, exc)
                anim = None
            except Exception:  # a bug must not stop the others from loading
                log.exception("content: cannot read %s", path)
                anim = None
            with self._lock:
                self._done[path] = anim

    def get(self, path: Path) -> Animation | None:
        """The animation of ``path`` if it has been read, else None."""
        with self._lock:
            return self._done.get(path)

    def failed(self, path: Path) -> bool:
        """Whether ``path`` was tried and cannot be shown."""
        with self._lock:
            return path in self._done and self._done[path] is None

    def wait(self, timeout_s: float) -> bool:
        """Wait up to ``timeout_s`` s until every file was tried; whether they were."""
        deadline = time.monotonic() + timeout_s
        while True:
            with self._lock:
                if all(p in self._done for p in self._paths):
                    return True
            if time.monotonic() >= deadline:
                return False
            time.sleep(0.01)

    def stop(self) -> None:
        """Stop reading (a file being read is finished first)."""
        self._todo.put(None)
        if self._thread.is_alive():
            self._thread.join(5)
