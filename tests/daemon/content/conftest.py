"""Fixtures of the content tests: a capturing sink, free UDP ports, and real sACN senders
(the ``sacn`` library's) on 127.0.0.1."""

from __future__ import annotations

from collections.abc import Callable, Iterator

import pytest
from content_helpers import CapturingSink, free_udp_port


@pytest.fixture
def sink() -> CapturingSink:
    return CapturingSink()


@pytest.fixture
def ports() -> tuple[int, int]:
    """Free UDP ports for the sACN and the Art-Net receiver."""
    a = free_udp_port()
    b = free_udp_port()
    while b == a:
        b = free_udp_port()
    return a, b


@pytest.fixture
def sacn_senders(monkeypatch) -> Iterator[Callable[..., object]]:
    """Makes started ``sacn.sACNsender`` s that send unicast to 127.0.0.1:``port`` (the
    library always sends to 5568: its module constant is pointed at the test's port)."""
    import sacn
    from sacn.sending import sender_socket_udp

    made = []

    def make(port: int, *, priority: int = 100, universes=(1,), fps: int = 40,
             name: str = "test sender"):
        monkeypatch.setattr(sender_socket_udp, "DEFAULT_PORT", port)
        s = sacn.sACNsender(bind_address="127.0.0.1", bind_port=0, source_name=name,
                            fps=fps, universeDiscovery=True)
        s.start()
        for u in universes:
            s.activate_output(u)
            s[u].multicast = False
            s[u].destination = "127.0.0.1"
            s[u].priority = priority
        made.append(s)
        return s

    yield make
    for s in made:
        s.stop()
