"""How the service runs its features (:mod:`grassd.daemon.core.runtime.features`): names are
distinct, each gets its turn until the service stops, a feature that takes the display holds
the others off it (and gives it back when it fails), commands reach the feature that has them,
and the cards come in the features' order."""

from __future__ import annotations

import threading
from types import SimpleNamespace

import pytest

from grassd.daemon.core.monitoring.page_parts import Card, Clock
from grassd.daemon.core.runtime.features import Feature, Features


class _Recorder(Feature):
    def __init__(self, name: str, log: list[str], svc=None) -> None:
        self.name, self.log, self.svc = name, log, svc

    def tick(self, svc) -> None:
        self.log.append(f"tick {self.name}")
        if self.name == "stopper":
            svc.stop_event.set()

    def hold(self) -> None:
        self.log.append(f"hold {self.name}")

    def release(self) -> None:
        self.log.append(f"release {self.name}")

    def handles(self, cmd: str) -> bool:
        return cmd == f"{self.name}_go"

    def card(self, svc, clock) -> Card | None:
        return None if self.name == "quiet" else Card(self.name, "<p>x</p>", "Active table")


def _svc() -> SimpleNamespace:
    return SimpleNamespace(stop_event=threading.Event())


def test_names_must_be_distinct_and_given():
    with pytest.raises(ValueError, match="distinct names"):
        Features([_Recorder("a", []), _Recorder("a", [])])
    with pytest.raises(ValueError, match="distinct names"):
        Features([Feature()])


def test_each_feature_gets_its_turn_until_the_service_stops():
    log: list[str] = []
    features = Features([_Recorder(n, log) for n in ("a", "stopper", "b")])
    features.tick(_svc())
    assert log == ["tick a", "tick stopper"]


def test_the_display_is_held_by_the_others_and_given_back_after_a_failure():
    log: list[str] = []
    a, b, c = (_Recorder(n, log) for n in "abc")
    features = Features([a, b, c])
    with pytest.raises(RuntimeError), features.display_held(by=b):
        log.append("measuring")
        raise RuntimeError("the camera went away")
    assert log == ["hold a", "hold c", "measuring", "release c", "release a"]


def test_commands_reach_the_feature_that_has_them_and_cards_come_in_order():
    features = Features([_Recorder(n, []) for n in ("a", "quiet", "b")])
    assert features.for_command("b_go").name == "b" and features.for_command("x") is None
    assert features.get("quiet").name == "quiet" and features.get("nothing") is None
    cards = features.page_cards(_svc())
    assert [c.title for c in cards.cards(Clock("UTC"))] == ["a", "b"]
    assert cards.news() is False  # no feature had news
