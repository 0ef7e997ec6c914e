"""How a feature joins the daemon: one small declared interface (as Klipper's ``extras/`` each
read their own config section), so that the service names no feature.

A :class:`Feature` reads its own config section (:attr:`Feature.name`), starts and stops with
the service, is restarted after a reload (it decides from the configs before and after whether
that changes anything for it), gets a turn in every pass of the main loop for what is due, may
answer control-socket commands of its own, may take the display from the others (a
measurement holds the content), may offer the calibrator the service runs with (a Dask
cluster's), and gives its status under its name in ``status --json``.
A feature may reach into the service it is given (its config, fleet, history, operator view,
progress) but never into another feature.

The command line composes the service with its features (``grassd.daemon.cli.features``);
the core imports none of them.
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Iterator, Mapping, Sequence
from typing import TYPE_CHECKING, Any

from grassd.daemon.core.monitoring.page_parts import Card, Clock

if TYPE_CHECKING:
    from grassd.daemon.core.calibration.calibrate import Calibrates
    from grassd.daemon.core.config.settings import Config
    from grassd.daemon.core.runtime.control_commands import Answer, Request
    from grassd.daemon.core.runtime.service import Service

log = logging.getLogger(__name__)


class Feature:
    """One feature as the service runs it; every method does nothing unless the feature
    overrides it. ``name``: its config section, and its key in the daemon part of
    ``status --json``."""

    name: str = ""

    def restart(self, svc: Service, old: Config | None) -> None:
        """(Re)start for ``svc.cfg``: at the daemon's start (``old`` None) and after every
        reload, accepted or refused (``old``: the config before; :meth:`pause` came first)."""

    def pause(self, svc: Service) -> None:
        """A reload is about to close the fleet and the lux sensor: let go of what uses
        them (:meth:`restart` follows)."""

    def tick(self, svc: Service) -> None:
        """Run what is due now (in the main loop, after the runs and before reconcile)."""

    def calibrator(self, cfg: Config) -> Calibrates | None:
        """What runs ``cfg``'s calibrations instead of the service's own (a Dask cluster's),
        or None; asked whenever the service is built for a config."""
        return None

    def stop(self) -> None:
        """The daemon stops: end every thread of the feature."""

    def status(self) -> Mapping[str, Any] | None:
        """The feature's part of the daemon's status (JSON-ready), or None when it runs
        nothing now."""
        return None

    def last_success_at(self) -> float | None:
        """When the feature last delivered (epoch s; the operator's metrics), or None."""
        return None

    def handles(self, cmd: str) -> bool:
        """Whether the control-socket command ``cmd`` is this feature's."""
        return False

    def handle(self, svc: Service, req: Request) -> Answer:
        """Answer one of the feature's commands (in a control-socket thread; its answer type
        adds the command's keys to :class:`~grassd.daemon.core.runtime.control_commands.Answer`)."""
        raise NotImplementedError(req.get("cmd"))

    def hold(self) -> None:
        """Another feature takes the display (a measurement): send nothing to it until
        :meth:`release`."""

    def release(self) -> None:
        """The display is given back."""

    def card(self, svc: Service, clock: Clock) -> Card | None:
        """The feature's section of the status page (its times in ``clock``), or None."""
        return None

    def card_news(self, svc: Service) -> bool:
        """Whether the feature's card has news since the page was last written (called
        after every reconcile; the page is then written again)."""
        return False



class Features:
    """The service's features, in the order they were given (started in that order)."""

    def __init__(self, features: Sequence[Feature] = ()) -> None:
        names = [f.name for f in features]
        if len(set(names)) != len(names) or "" in names:
            raise ValueError(f"features need distinct names, got {names}")
        self._all = tuple(features)

    def __iter__(self) -> Iterator[Feature]:
        return iter(self._all)

    def get(self, name: str) -> Feature | None:
        """The feature ``name``, or None when the service has none by that name."""
        return next((f for f in self._all if f.name == name), None)

    def restart(self, svc: Service, old: Config | None) -> None:
        """:meth:`Feature.restart` of each."""
        for f in self._all:
            f.restart(svc, old)

    def pause(self, svc: Service) -> None:
        """:meth:`Feature.pause` of each."""
        for f in self._all:
            f.pause(svc)

    def tick(self, svc: Service) -> None:
        """:meth:`Feature.tick` of each, until the service stops."""
        for f in self._all:
            if svc.stop_event.is_set():
                return
            f.tick(svc)

    def stop(self) -> None:
        """:meth:`Feature.stop` of each, the last started first."""
        for f in reversed(self._all):
            f.stop()

    def status(self) -> dict[str, Mapping[str, Any] | None]:
        """Each feature's status by name."""
        return {f.name: f.status() for f in self._all}

    def page_cards(self, svc: Service) -> FeatureCards:
        """The features' sections of ``svc``'s status page."""
        return FeatureCards(self, svc)

    def calibrator(self, cfg: Config) -> Calibrates | None:
        """The first calibrator a feature offers for ``cfg``, or None."""
        return next((c for f in self._all if (c := f.calibrator(cfg)) is not None), None)

    def for_command(self, cmd: str) -> Feature | None:
        """The feature whose command ``cmd`` is, or None."""
        return next((f for f in self._all if f.handles(cmd)), None)

    @contextlib.contextmanager
    def display_held(self, by: Feature | None = None) -> Iterator[None]:
        """Every feature but ``by`` holds off the display while the block runs."""
        held = [f for f in self._all if f is not by]
        for f in held:
            f.hold()
        try:
            yield
        finally:
            for f in reversed(held):
                f.release()


class FeatureCards:
    """The status page's cards of ``features`` in ``svc`` (the operator view's
    :class:`~grassd.daemon.core.monitoring.operator_view.PageCards`)."""

    def __init__(self, features: Features, svc: Service) -> None:
        self.features, self.svc = features, svc

    def news(self) -> bool:
        """Whether any feature's card has news (each is asked)."""
        return any([f.card_news(self.svc) for f in self.features])

    def cards(self, clock: Clock) -> list[Card]:
        """Every feature's card, in the features' order."""
        return [c for f in self.features if (c := f.card(self.svc, clock)) is not None]
