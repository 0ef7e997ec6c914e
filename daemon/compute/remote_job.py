"""The job one calibration on a Dask worker receives: what the simulation reads, nothing else.

A :class:`CalibrationJob` holds the configuration sections a run reads
(:class:`RunSections`: site, display, controllers, viewpoints, the HDRI's orientation,
simulation, calibration, tables, audience), the light, the bytes of the bundle's HDRI and
checker RAW, and the run's own arguments. It never holds the daemon's paths, its
``[capture]`` or ``[measure]`` camera (URLs, user names, passwords), ``[alerts]``,
``[metrics]`` or ``[compute]``: a worker learns nothing it does not simulate with. On the worker
:meth:`RunSections.config` makes a :class:`~grassd.daemon.core.config.settings.Config` of them whose
paths lie in the run's temporary directory.
"""

from __future__ import annotations

import copyreg
import io
import pickle
import types
from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from grassd.daemon.core.config.settings import (
    AudienceConfig,
    CalibrationConfig,
    Config,
    ControllerConfig,
    DisplayConfig,
    LightConfig,
    ScheduleConfig,
    SimulationConfig,
    SiteConfig,
    TablesConfig,
    ViewpointConfig,
)
from grassd.sim.light_input import LightInput

if TYPE_CHECKING:
    from numpy.typing import NDArray

    from grassd.calib.ccm import ColourCorrection
    from grassd.daemon.core.calibration.result import CalibrationResult
    from grassd.daemon.core.store.manifest import CheckerPhoto

__all__ = ["CalibrationJob", "RunSections", "dumps", "loads"]

#: the name a worker's configuration is reported under
JOB_SOURCE = "<dask job>"


@dataclass(frozen=True)
class RunSections:
    """The sections of a configuration that :class:`~grassd.daemon.core.calibration.calibrate.
    Calibrator` reads (``hdri_flip`` / ``hdri_rotation_deg`` [deg] from ``[light]``)."""

    site: SiteConfig
    display: DisplayConfig
    controllers: tuple[ControllerConfig, ...]
    viewpoints: tuple[ViewpointConfig, ...]
    hdri_flip: bool
    hdri_rotation_deg: float
    simulation: SimulationConfig
    calibration: CalibrationConfig
    tables: TablesConfig
    audience: AudienceConfig | None

    @classmethod
    def of(cls, cfg: Config) -> RunSections:
        """The sections of ``cfg`` a run reads."""
        return cls(site=cfg.site, display=cfg.display, controllers=cfg.controllers,
                   viewpoints=cfg.viewpoints, hdri_flip=cfg.light.hdri_flip,
                   hdri_rotation_deg=cfg.light.hdri_rotation_deg, simulation=cfg.simulation,
                   calibration=cfg.calibration, tables=cfg.tables, audience=cfg.audience)

    def config(self, work_dir: Path) -> Config:
        """A configuration of these sections whose state, cache and inbox lie in ``work_dir``
        (a worker's temporary directory; a run writes nothing there)."""
        return Config(site=self.site, display=self.display, controllers=self.controllers,
                      viewpoints=self.viewpoints,
                      light=LightConfig(inbox=work_dir / "inbox", hdri_flip=self.hdri_flip,
                                        hdri_rotation_deg=self.hdri_rotation_deg),
                      schedule=ScheduleConfig(), simulation=self.simulation,
                      calibration=self.calibration, state_dir=work_dir, cache_dir=work_dir,
                      control_socket=work_dir / "control.sock", source=JOB_SOURCE,
                      tables=self.tables, audience=self.audience)


@dataclass(frozen=True)
class CalibrationJob:
    """One run for a worker: the sections it reads, the light (ambient lux resolved), the
    HDRI's bytes and, with a colour checker, its photo and the RAW's bytes, and the
    arguments of ``Calibrator.run`` that travel (tables in uint16 um)."""

    sections: RunSections
    light: LightInput
    hdri: bytes
    checker: CheckerPhoto | None = None
    checker_raw: bytes | None = None
    previous_um: NDArray | None = None
    previous_ccm: ColourCorrection | None = None
    force: bool = False
    previous_tables: Mapping[str, NDArray] | None = None

    @classmethod
    def of(cls, cfg: Config, light: LightInput, checker: CheckerPhoto | None = None, *,
           previous_um: NDArray | None = None, previous_ccm: ColourCorrection | None = None,
           force: bool = False, previous_tables: Mapping[str, NDArray] | None = None
           ) -> CalibrationJob:
        """The job of one run of ``cfg`` for ``light``; reads the HDRI and the checker RAW.
        Raises OSError when one cannot be read."""
        return cls(sections=RunSections.of(cfg), light=light,
                   hdri=Path(light.hdri).read_bytes(), checker=checker,
                   checker_raw=None if checker is None else Path(checker.raw).read_bytes(),
                   previous_um=previous_um, previous_ccm=previous_ccm, force=force,
                   previous_tables=None if previous_tables is None else dict(previous_tables))

    def run(self, work_dir: Path) -> CalibrationResult:
        """Run it (on the worker, Taichi initialised): write the HDRI and the RAW into
        ``work_dir`` under their own names and calibrate on them; the display's correction
        is left to the daemon. Raises what ``Calibrator.run`` raises."""
        from grassd.daemon.core.calibration.calibrate import Calibrator

        hdri = work_dir / Path(self.light.hdri).name
        hdri.write_bytes(self.hdri)
        checker = self.checker
        if checker is not None and self.checker_raw is not None:
            raw = work_dir / Path(checker.raw).name
            raw.write_bytes(self.checker_raw)
            checker = replace(checker, raw=raw)
        return Calibrator(self.sections.config(work_dir)).run(
            replace(self.light, hdri=hdri), checker=checker, previous_um=self.previous_um,
            previous_ccm=self.previous_ccm, force=self.force,
            previous_tables=self.previous_tables, correction=None)


# --------------------------------------------------------------------------- serialisation


def _mapping_proxy(d: dict[str, Any]) -> Mapping[str, Any]:
    """A read-only view of ``d`` (how a pickled ``types.MappingProxyType`` comes back)."""
    return types.MappingProxyType(d)


def _reduce_mapping_proxy(m: Mapping[str, Any]) -> tuple[Any, tuple[dict[str, Any]]]:
    return _mapping_proxy, (dict(m),)


def dumps(job: CalibrationJob) -> bytes:
    """Pickle ``job`` for the worker (the daemon's own data; its configuration sections hold
    read-only mappings, which plain pickle refuses: they travel as dicts and come back
    read-only)."""
    buf = io.BytesIO()
    p = pickle.Pickler(buf, protocol=pickle.HIGHEST_PROTOCOL)
    p.dispatch_table = {**copyreg.dispatch_table, types.MappingProxyType: _reduce_mapping_proxy}
    p.dump(job)
    return buf.getvalue()


def loads(data: bytes) -> CalibrationJob:
    """The job :func:`dumps` pickled (on the worker: it comes from the client)."""
    job = pickle.loads(data)
    if not isinstance(job, CalibrationJob):
        raise TypeError(f"a grassd calibration job was expected, got {type(job).__name__}")
    return job
