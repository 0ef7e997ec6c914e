"""Where the studio's light comes from: an HDRI file given on the command line, the daemon's
archived bundles (newest first) when a state directory is given, HDRIs uploaded in the page,
and the embedded default site when there is nothing else.

A source holds its panorama as loaded (linear Rec.709, relative units), reduced to at most
:data:`STUDIO_WIDTH` texels wide as it is decoded when it is wider (a map that size or smaller
is simulated as the daemon simulates it, texel for texel), and what was measured with it
(lux, sun). Building the :class:`~grassd.sim.lighting.Lighting` of a condition scales it
(:meth:`Lights.lighting`, the last few kept).

What is kept is capped (:class:`~grassd.daemon.studio.limits.StudioLimits`): the panoramas
loaded (``kept_maps``, the least recently used unloaded and read again when chosen), and the
uploads (``kept_uploads`` of them, ``kept_upload_mib`` of files together: the oldest are
dropped, their files removed, and the page lists them no more).
"""

from __future__ import annotations

import functools
import logging
import shutil
import tempfile
import threading
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from grassd.daemon.studio.inputs import Condition, StudioInputError
from grassd.daemon.studio.limits import DEFAULT_LIMITS, StudioLimits
from grassd.daemon.studio.messages import LightDescription

if TYPE_CHECKING:
    from grassd.sim.lighting import Lighting

log = logging.getLogger(__name__)

#: Widest panorama the studio simulates (texels): wider maps (a camera's 8K) are box-filtered
#: down so that a change of light is rebuilt in tens of milliseconds, not seconds.
STUDIO_WIDTH: int = 2048
#: Largest HDRI upload accepted (bytes).
MAX_HDRI_BYTES: int = 256 * 2**20
#: Lightings kept built (one per recent light, lux and sun).
KEPT_LIGHTINGS: int = 8


@dataclass
class LightSource:
    """One panorama and what was measured with it: ``ambient_lux`` [lx] (None: not measured),
    the sun (``sun_lux`` [lx], compass ``sun_azimuth_deg``, ``sun_elevation_deg``) when the
    bundle has one, ``taken`` (ISO 8601) when known, ``flip``/``rotation_deg`` its
    orientation (the config's ``[light]`` for bundles)."""

    name: str
    label: str
    path: Path
    ambient_lux: float | None = None
    sun_lux: float | None = None
    sun_azimuth_deg: float | None = None
    sun_elevation_deg: float | None = None
    taken: str | None = None
    flip: bool = False
    rotation_deg: float = 0.0
    image: np.ndarray | None = None

    def check(self, shown: str | None = None) -> None:
        """See that the panorama can light the studio: read and validated by the loader as
        the simulator reads it (:func:`load_panorama`: reduced as it is decoded), else
        StudioInputError with the loader's reason, naming the file ``shown`` (default: its
        path). The map is not kept: the server builds its own Lights from the same sources and
        never renders, and the simulator reads the file again on first use (an upload is
        checked by the simulator alone, which keeps what it read). Costs one read of the file;
        nothing when the map is already loaded."""
        if self.image is None:
            load_panorama(self.path, shown, warn=False)  # the simulator warns

    def describe(self) -> LightDescription:
        """The source as the page lists it."""
        return {"name": self.name, "label": self.label, "ambient_lux": self.ambient_lux,
                "sun_lux": self.sun_lux, "sun_azimuth_deg": self.sun_azimuth_deg,
                "sun_elevation_deg": self.sun_elevation_deg, "taken": self.taken}


def load_panorama(path: Path, shown: str | None = None, *, warn: bool = True) -> np.ndarray:
    """An HDRI file as the studio simulates it: box-filtered to at most :data:`STUDIO_WIDTH`
    texels wide as it is decoded (:func:`grassd.sim.hdri.load_hdri`'s ``max_width``: the
    full-size map is never held); StudioInputError with the loader's reason for a file that
    is not a usable panorama (missing, not a regular file, neither OpenEXR nor Radiance,
    truncated, too large by its header, no whole factor to the studio's width, NaN or infinite
    texels, a black sky), naming it ``shown`` (default: the path). ``warn``: the loader's
    warning of clamped compression noise (:func:`grassd.sim.hdri.check_env`)."""
    from grassd.sim.errors import SimError
    from grassd.sim.hdri import load_hdri

    try:
        return load_hdri(path, warn=warn, max_width=STUDIO_WIDTH)
    except SimError as exc:
        name = shown or str(path)
        reason = str(exc).replace(str(path), name)
        raise StudioInputError(f"cannot use {name} as the light: {reason}") from None


def archived_sources(state_dir: Path, cfg) -> list[LightSource]:
    """The light of every usable archived bundle in ``state_dir``, newest (directory mtime)
    first, the first labelled "current: " (the light the studio starts with). A bundle is left
    out, with a warning naming it and why, when its manifest cannot be read or its panorama is
    missing, and so is a newer one whose panorama cannot light the studio (not a readable HDR:
    :meth:`LightSource.check`, which reads the file) until the first that can: that one
    becomes the default light; an older bundle's broken panorama is said when it is chosen
    (reading each would take minutes on a month's archive). A directory without a manifest is
    not a bundle and is passed over. StudioInputError when the archive cannot be
    listed."""
    from zoneinfo import ZoneInfo

    from grassd.daemon.core.errors import DaemonError
    from grassd.daemon.core.store.manifest import load_bundle_manifest

    archive = Path(state_dir) / "archive"
    if not archive.is_dir():
        return []
    try:
        dirs = []
        for d in archive.iterdir():
            try:  # one pruned by the daemon's retention meanwhile is passed over
                if d.is_dir():
                    dirs.append((d.stat().st_mtime, d))
            except FileNotFoundError:
                continue
    except OSError as exc:
        raise StudioInputError(f"cannot list the archived bundles in {archive}: "
                               f"{exc.strerror or exc}; give a state directory this user can "
                               f"read") from None
    dirs.sort(key=lambda t: t[0], reverse=True)
    tz = ZoneInfo(cfg.site.timezone)
    out: list[LightSource] = []
    for _, d in dirs:
        try:
            m = load_bundle_manifest(d, tz)
        except DaemonError as exc:
            log.warning("archived bundle %s left out: %s", d.name, exc)
            continue
        if m is None:
            continue
        light = m.light
        src = LightSource(
            name=f"bundle:{d.name}", label=("" if out else "current: ") + d.name,
            path=light.hdri, ambient_lux=light.ambient_lux, sun_lux=light.sun_lux,
            sun_azimuth_deg=light.sun_azimuth_deg, sun_elevation_deg=light.sun_elevation_deg,
            taken=m.timestamp.astimezone(UTC).isoformat(), flip=cfg.light.hdri_flip,
            rotation_deg=cfg.light.hdri_rotation_deg)
        shown = f"{d.name}/{Path(light.hdri).name}"
        try:
            if out:  # behind the first usable one only its file is looked for: one read per
                if not Path(light.hdri).is_file():  # bundle of a month's archive took minutes
                    raise StudioInputError(f"cannot use {shown} as the light: its file is "
                                           f"missing")
            else:  # the light the studio starts with (and warms up on) is read whole
                src.check(shown)
        except StudioInputError as exc:
            log.warning("archived bundle %s left out: %s", d.name, exc)
            continue
        out.append(src)
    return out


@functools.lru_cache(maxsize=64)
def solar_position(latitude: float, longitude: float, when) -> tuple[float, float]:
    """(compass azimuth, elevation) deg of the sun (:func:`grassd.sim.sun.sun_position`), kept
    for recent times: a job builds its lighting for every characteristic and image it traces
    (about 60 with the audience map), and pvlib takes 4 ms a call."""
    from grassd.sim.sun import sun_position

    return sun_position(latitude, longitude, when)


class Lights:
    """The studio's light sources by name, loaded on first use, and the lightings built from
    them (thread-safe: the server lists and adds, the worker builds); what is kept is capped
    by ``limits`` (see the module docstring)."""

    def __init__(self, sources: list[LightSource], upload_dir: Path | None = None,
                 limits: StudioLimits = DEFAULT_LIMITS) -> None:
        if not sources:
            raise StudioInputError("the studio needs at least one light")
        self._sources: dict[str, LightSource] = {s.name: s for s in sources}
        self.default = sources[0].name
        self._built: OrderedDict[tuple, Lighting] = OrderedDict()
        self._lock = threading.Lock()
        self._limits = limits
        self._loaded: OrderedDict[str, None] = OrderedDict()  # least recently used first
        #: the uploads kept and their bytes, oldest first
        self._upload_sizes: OrderedDict[str, int] = OrderedDict()
        self._uploads = 0
        self._upload_dir = None if upload_dir is None else Path(upload_dir)
        self._own_dir = upload_dir is None

    @property
    def names(self) -> set[str]:
        """The names a condition may give."""
        with self._lock:
            return set(self._sources)

    def describe(self) -> list[LightDescription]:
        """Every source as the page lists it (in the order they came)."""
        with self._lock:
            return [s.describe() for s in self._sources.values()]

    def source(self, name: str, shown: str | None = None) -> LightSource:
        """The source ``name``, its panorama loaded (StudioInputError when it is broken, naming
        the file ``shown``, default its path); the least recently used beyond ``kept_maps``
        are unloaded."""
        with self._lock:
            src = self._sources.get(name)
        if src is None:
            raise StudioInputError(f"no light named {name!r}"
                                   + (": it was dropped for newer uploads; upload it again"
                                      if name.startswith("upload:") else ""))
        if src.image is None:
            src.image = load_panorama(src.path, shown)
        with self._lock:
            self._loaded[name] = None
            self._loaded.move_to_end(name)
            while len(self._loaded) > self._limits.kept_maps:
                old, _ = self._loaded.popitem(last=False)
                self._unload(old)
        return src

    def loaded(self) -> list[str]:
        """The names of the sources whose panorama is kept loaded, least recently used first."""
        with self._lock:
            return list(self._loaded)

    def _unload(self, name: str) -> None:
        """Let go of ``name``'s panorama and the lightings built from it (under the lock)."""
        src = self._sources.get(name)
        if src is not None:
            src.image = None
        for key in [k for k in self._built if k[0] == name]:
            del self._built[key]

    def upload_path(self, filename: str) -> Path:
        """Where the next upload named ``filename`` is written (not yet created);
        StudioInputError when it is not an .exr or .hdr file."""
        suffix = Path(filename or "").suffix.lower()
        if suffix not in (".exr", ".hdr"):
            raise StudioInputError(f"an HDRI must be an .exr or .hdr file, got {filename!r}")
        with self._lock:
            self._uploads += 1
            n = self._uploads
            if self._upload_dir is None:  # made on the first upload, removed by cleanup()
                self._upload_dir = Path(tempfile.mkdtemp(prefix="grassd-studio-"))
            return self._upload_dir / f"upload-{n}{suffix}"

    def add_upload(self, filename: str, path: Path) -> tuple[LightSource, list[str]]:
        """Check the uploaded HDRI written to ``path`` (:meth:`upload_path`) here
        (:meth:`LightSource.check`, not kept) and add it as a source: :meth:`new_upload`,
        the check, then :meth:`keep_upload`'s (the source, the names of the older uploads
        dropped). StudioInputError, the file removed and nothing added, for a file that is not
        a usable panorama. The server does not decode it: its simulator checks it instead."""
        src = self.new_upload(filename, path)
        try:
            src.check(Path(filename).name)
        except BaseException:
            src.path.unlink(missing_ok=True)
            raise
        return src, self.keep_upload(src)

    def new_upload(self, filename: str, path: Path) -> LightSource:
        """The source of the uploaded HDRI written to ``path`` (:meth:`upload_path`), named for
        its number, not yet checked nor added; StudioInputError, the file removed, when it is
        larger than :data:`MAX_HDRI_BYTES`."""
        path = Path(path)
        try:
            size = path.stat().st_size
            if size > MAX_HDRI_BYTES:
                raise StudioInputError(f"the HDRI is {size / 2**20:.0f} MiB; at most "
                                       f"{MAX_HDRI_BYTES // 2**20} MiB")
        except BaseException:
            path.unlink(missing_ok=True)
            raise
        return LightSource(name=f"upload:{path.stem.rpartition('-')[2]}",
                           label=f"uploaded: {Path(filename).name}", path=path)

    def keep_upload(self, src: LightSource) -> list[str]:
        """Add the checked upload ``src`` (:meth:`new_upload`); the names of the older uploads
        dropped to keep within the caps (count, bytes of files together), oldest first, their
        files removed. StudioInputError when its file has gone meanwhile."""
        try:
            size = src.path.stat().st_size
        except OSError:
            raise StudioInputError(f"the upload {src.label} was removed before it was "
                                   f"added; upload it again") from None
        dropped = []
        with self._lock:
            self._sources[src.name] = src
            self._upload_sizes[src.name] = size
            while len(self._upload_sizes) > self._limits.kept_uploads or (
                    len(self._upload_sizes) > 1
                    and sum(self._upload_sizes.values()) > self._limits.kept_upload_bytes):
                old = next(iter(self._upload_sizes))
                dropped.append(old)
                self._forget(old)
        return dropped

    def holds(self, path: Path) -> bool:
        """Whether a source's panorama is the file ``path``."""
        with self._lock:
            return any(s.path == Path(path) for s in self._sources.values())

    def forget(self, name: str) -> None:
        """Drop the source ``name`` (an upload the server dropped): its panorama, lightings
        and, when this object made the uploads' folder, its file."""
        with self._lock:
            self._forget(name)

    def _forget(self, name: str) -> None:
        self._unload(name)
        self._loaded.pop(name, None)
        self._upload_sizes.pop(name, None)
        src = self._sources.pop(name, None)
        if src is not None and self._own_dir and self._upload_dir is not None \
                and src.path.parent == self._upload_dir:
            src.path.unlink(missing_ok=True)

    def cleanup(self) -> None:
        """Remove the uploads' temporary folder (when this object made it)."""
        if self._own_dir and self._upload_dir is not None:
            shutil.rmtree(self._upload_dir, ignore_errors=True)
            self._upload_dir = None

    def add_source(self, src: LightSource) -> None:
        """Add a source checked elsewhere (an upload the server has read)."""
        with self._lock:
            self._sources[src.name] = src

    def lighting(self, cond: Condition, site: tuple[float, float]) -> Lighting:
        """The :class:`~grassd.sim.lighting.Lighting` of ``cond`` (its source scaled to its
        lux, with its sun); ``site`` = (latitude, longitude) deg for a sun placed by time.
        StudioInputError for readings that cannot be (lux out of range, sun below the
        horizon)."""
        from grassd.sim.light_input import LightInput
        from grassd.sim.lighting import add_sun

        src = self.source(cond.light)
        image = src.image  # held here: a dropped upload's is let go meanwhile
        sun = cond.sun
        lux, az, el = None, None, None
        if sun.mode == "measured":
            if src.sun_lux is None or src.sun_azimuth_deg is None:
                raise StudioInputError(f"{src.label} has no measured sun; choose the sun by "
                                       f"time of day or none")
            lux, az, el = src.sun_lux, src.sun_azimuth_deg, src.sun_elevation_deg
        elif sun.mode == "site":
            az, el = solar_position(site[0], site[1], sun.when)
            if el <= 0:
                raise StudioInputError(f"the sun is below the horizon at {sun.when:%H:%M} "
                                       f"(elevation {el:.1f} deg); choose another time or no sun")
            lux = sun.lux
        elif sun.mode == "direction":
            lux, az, el = sun.lux, sun.azimuth_deg, sun.elevation_deg
        if lux == 0:
            lux, az, el = None, None, None
        # the map scaled to the lux, kept apart from the sun: a new time of day only adds its
        # sun to it (courtyard.exr, 2 cores: a new time's light took 16-30 ms, median 18, to
        # check, scale and sum the map; now 2 ms, mostly the sun's position)
        base = self._kept((src.name, cond.ambient_lux), lambda: LightInput(
            src.path, cond.ambient_lux, rotation_deg=src.rotation_deg,
            flip=src.flip).lighting(image))
        if lux is None:
            return base
        return self._kept((src.name, cond.ambient_lux, lux, az, el),
                          lambda: add_sun(base, lux, az, el))

    def _kept(self, key: tuple, build: Callable[[], Lighting]) -> Lighting:
        """The light built for ``key`` (kept: the :data:`KEPT_LIGHTINGS` last used), or
        ``build()``'s; StudioInputError for readings that cannot be."""
        from grassd.sim.errors import LightingError

        with self._lock:
            if key in self._built:
                self._built.move_to_end(key)
                return self._built[key]
        try:
            lighting = build()
        except LightingError as exc:
            raise StudioInputError(f"the light cannot be built: {exc}") from None
        with self._lock:
            self._built[key] = lighting
            while len(self._built) > KEPT_LIGHTINGS:
                self._built.popitem(last=False)
        return lighting
