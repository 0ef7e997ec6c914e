"""One studio: a configuration's display and pixel, its lights and the daemon's active table,
and the job that turns a :class:`~grassd.daemon.studio.inputs.Condition` into the views,
streamed as they refine.

The order of a job is set by the latency goals (first characteristic within 150 ms,
first image of the pixel within 300 ms, converged within 1 s, warm, 2 cores; the sizes named
here are :mod:`grassd.daemon.studio.pace`'s):

1. the characteristic's first round, :data:`FIRST_REPLICATES` replicates of
   :data:`STUDIO_SAMPLES` paths (about 75 ms for 11 lengths); where the blades splay (nearly
   every length traced, 2.3x the time), replicates of :data:`SPLAY_SAMPLES` paths, 4x as many;
2. the pixel's first image, :data:`FIRST_IMAGE` (width, paths per image pixel) (about 40 ms),
   or its refined image where one is kept for the condition;
3. further rounds until every OGCD standard error is at most the target
   (:func:`~grassd.daemon.core.calibration.simulation.simulate_curve`'s adaptive rounds of at most
   :data:`ROUND_REPLICATES`, each sent); where, under a sun, the first paths say the target
   needs many (a low sun's light and shadow on the blades), a new series of larger
   replicates, whose error falls faster per path
   (:class:`~grassd.daemon.core.calibration.simulation.LargerReplicates`), sent once it has
   :data:`FIRST_REPLICATES`;
4. the table, the contrast, the display showing the uploaded picture: its colours mapped to
   levels as the daemon maps content (``[content] map`` and ``normalise``, through
   :func:`~grassd.daemon.content.colour_map.levels_for_picture`) onto the colours of the
   condition's characteristic at the reference viewpoint (the condition's own where its eye
   is there, else one more characteristic run to its target there and kept), at the table's
   lengths;
5. the audience map: the OGCD range from each place of the audience region;
6. the condition pinned as B, if the page sent one (``pinned`` messages): its characteristic
   (kept, else run to its target) and its image refined to :data:`PINNED_PASSES` passes; one
   with an ``error`` where B cannot be computed, and A goes on;
7. the pixel's image refined: :data:`REFINE_PASSES` passes of :data:`REFINE_IMAGE`
   accumulated; then ``done``.

Converged characteristics, audience maps (:data:`KEPT_CURVES`) and images summed over their
passes (:data:`KEPT_IMAGES`) are kept, so a condition seen again, B's among them, goes on from
what it had (pinning sends A again: only its table, contrast and display view are redone). So
are characteristics a newer input stopped before they converged
(:class:`~grassd.daemon.core.calibration.simulation.CurveRun`): the condition's next job shows the
curve so far at once and goes on from its last complete round.

Every step checks whether a newer request superseded this one. In the simulator process a newer
request also stops the renderer's launch in flight (:attr:`Studio.interrupts`), so a launch
takes a whole round; elsewhere the renderer checks between its launches of
:data:`STUDIO_LAUNCH_PATHS` to :data:`STUDIO_MAX_LAUNCH_PATHS` camera paths.
"""

from __future__ import annotations

import itertools
import logging
import math
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import replace
from datetime import UTC, datetime
from typing import TYPE_CHECKING, Literal, Required, TypedDict, TypeVar

import numpy as np

from grassd.daemon.studio import views
from grassd.daemon.studio.inputs import Condition, JsonValue, StudioInputError, parse_condition
from grassd.daemon.studio.lights import Lights
from grassd.daemon.studio.messages import (
    AudienceMessage,
    CurveMessage,
    ImageMessage,
    LightMessage,
    Materials,
    PageMessage,
    PictureUpload,
    PinnedMessage,
    StudioState,
    SunPosition,
)
from grassd.daemon.studio.pace import (
    FIRST_IMAGE,
    FIRST_REPLICATES,
    MAX_REPLICATES,
    PINNED_PASSES,
    REFINE_IMAGE,
    REFINE_PASSES,
    ROUND_REPLICATES,
    STUDIO_LAUNCH_PATHS,
    STUDIO_MAX_LAUNCH_PATHS,
    STUDIO_SAMPLES,
    studio_pace,
)
from grassd.daemon.studio.worker import Check

if TYPE_CHECKING:
    from grassd.calib.characteristic import FittedCharacteristic
    from grassd.daemon.content.colour_map import DisplayColours
    from grassd.daemon.content.config import ContentConfig
    from grassd.daemon.core.calibration.simulation import CurveRun, SimulatedCurve
    from grassd.daemon.core.config.settings import PixelValue
    from grassd.sim.interrupt import Interrupt
    from grassd.sim.lighting import Lighting
    from grassd.sim.renderer import Renderer
    from grassd.sim.scene import DisplaySpec, PixelSpec

log = logging.getLogger(__name__)

#: Refined images kept (summed over their passes) for conditions seen again.
KEPT_IMAGES: int = 8
#: Converged characteristics kept for conditions seen again (the length shown, the tables or the
#: picture changed, or the eye came back).
KEPT_CURVES: int = 16
#: Places of the audience map: a grid of about this many points over the region.
AUDIENCE_POINTS: int = 36
#: The region mapped when the config has no ``[audience]``: x -3..3 m, y -5..-0.5 m (in front of
#: the display, whose centre is the origin; +y north, the audience towards -y).
DEFAULT_REGION: tuple[tuple[float, float], ...] = ((-3.0, -5.0), (3.0, -5.0), (3.0, -0.5),
                                                   (-3.0, -0.5))

class CharacteristicArgs(TypedDict, total=False):
    """The settings of a characteristic's run (:meth:`Studio.characteristic`'s keywords) that
    a request gives: the OGCD standard error to refine to (dE00; None: one round), paths a
    replicate and replicates a round, the lengths (mm)."""

    target_stderr: Required[float | None]
    samples: int | None
    replicates: int
    lengths_mm: Sequence[float]


#: Where a job's messages go, as they are ready.
Emit = Callable[[PageMessage], None]
_Kept = TypeVar("_Kept")


def _rounded(a: np.ndarray, digits: int = 4) -> list[float]:
    return np.round(np.asarray(a, np.float64), digits).tolist()


def _keep(kept: dict[tuple, _Kept], key: tuple, value: _Kept, most: int) -> _Kept:
    """Keep ``value`` under ``key`` in ``kept`` as its newest entry, dropping the oldest beyond
    ``most``; returns ``value``."""
    kept.pop(key, None)
    kept[key] = value
    while len(kept) > most:
        kept.pop(next(iter(kept)))
    return value


def _scene_key(cond: Condition) -> tuple:
    """What a condition's characteristic and its pixel's images both depend on: the light, the
    eye and the pixel (the kept curves' and images' keys add their own fields)."""
    return (cond.light, cond.ambient_lux, cond.sun, cond.viewpoint, cond.pixel,
            cond.splay_deg)


def _curve_key(cond: Condition) -> tuple:
    """The key of ``cond``'s characteristic among the kept ones: its scene, lengths and
    target."""
    return (*_scene_key(cond), cond.lengths_mm, cond.target_stderr)


def _image_key(cond: Condition) -> tuple:
    """The key of ``cond``'s refined image among the kept ones: its scene and length shown."""
    return (*_scene_key(cond), cond.length_mm)


def _fit(curve: SimulatedCurve) -> tuple[FittedCharacteristic | None, str | None]:
    """The fitted characteristic of a simulated curve
    (:func:`grassd.calib.characteristic.fit_characteristic`) and None, or None and why there
    is none (a CalibError's message: no monotone fit)."""
    from grassd.calib.characteristic import fit_characteristic
    from grassd.calib.errors import CalibError
    from grassd.daemon.core.calibration.display_model import curve_characteristic

    try:
        return fit_characteristic(curve_characteristic(curve)), None
    except CalibError as exc:
        return None, str(exc)


def _light_message(lighting: Lighting, white: np.ndarray) -> LightMessage:
    """The light of a condition as the page is told it: the lighting's notes, where it put
    the sun (compass degrees; None: no sun), the radiance of a white under it."""
    from grassd.sim.lighting import azimuth_elevation_from_direction

    sun: SunPosition | None = None
    if lighting.sun_direction is not None:
        az, el = azimuth_elevation_from_direction(lighting.sun_direction)
        sun = {"azimuth_deg": float(az), "elevation_deg": float(el)}
    return {"type": "light", "notes": list(getattr(lighting, "notes", ())), "sun": sun,
            "white_nits": _rounded(white)}


def _image_message(kind: Literal["pixel", "pinned"], total: np.ndarray, done: int, passes: int,
                   white: np.ndarray) -> ImageMessage:
    """A refined image of ``done`` passes summed in ``total`` (linear Rec.709 nits, scaled by
    ``white`` for the page) as a ``kind`` message; ``final`` once it has ``passes``."""
    return {"type": kind, "image": views.pixel_png(total / done, white),
            "width": REFINE_IMAGE[0], "spp": REFINE_IMAGE[1] * done, "final": done >= passes}


class Studio:
    """The studio's model of one site. Its simulation methods run on the worker thread only
    (the renderer is one per process); the rest may be called from the server's thread."""

    def __init__(self, cfg, lights: Lights, *,
                 pixel_fields: dict[str, PixelValue] | None = None,
                 pixel_source: str = "config", active_um: np.ndarray | None = None,
                 arch: str = "cpu",
                 interrupts: Callable[[Check], Interrupt] | None = None) -> None:
        from grassd.daemon.core.calibration.calibrate import Calibrator

        self.cfg = cfg
        self.lights = lights
        self.arch = arch
        #: The renderer's interrupt for a job's ``check`` (the simulator process's,
        #: :class:`~grassd.daemon.studio.superseding.Superseding`): a newer input stops the
        #: launch in flight, so launches take whole rounds. None (in the server's process, in
        #: tests), or on a GPU (``Renderer.interruptible``): ``check`` runs between launches
        #: of :data:`STUDIO_LAUNCH_PATHS` to :data:`STUDIO_MAX_LAUNCH_PATHS` paths.
        self.interrupts = interrupts
        display, self.centre = Calibrator(cfg).display()
        #: the pixels a condition may choose: the config's, and a fit result's when given
        self.displays = {"config": display}
        if pixel_fields:
            self.displays["fit"] = replace(display, pixel=replace(display.pixel,
                                                                  **pixel_fields))
        self.default_pixel = "fit" if pixel_fields else "config"
        self.display = self.displays[self.default_pixel]
        self.pixel_source = pixel_source
        self.active_um = None if active_um is None else np.asarray(active_um, np.uint16)
        self.region = np.asarray(cfg.audience.polygon if cfg.audience is not None
                                 else DEFAULT_REGION, np.float64)
        #: uploaded pictures, (rows, cols, 3) uint8 sRGB each, by id
        self.pictures: dict[str, np.ndarray] = {}
        self._picture_ids = itertools.count(1)
        self._lock = threading.Lock()
        self.ready = False
        #: converged characteristics of recent conditions
        self._curves: dict[tuple, SimulatedCurve] = {}
        #: characteristics a newer input stopped before they converged, to go on from
        self._runs: dict[tuple, CurveRun] = {}
        #: refined images of recent conditions: (sum of the passes, passes)
        self._images: dict[tuple, tuple[np.ndarray, int]] = {}
        #: audience maps of recent conditions (their messages; None: no place to map)
        self._audiences: dict[tuple, AudienceMessage | None] = {}

    # ------------------------------------------------------------------ what the page needs
    @property
    def site(self) -> tuple[float, float]:
        """(latitude, longitude) deg of the display."""
        return self.cfg.site.latitude, self.cfg.site.longitude

    def state(self) -> StudioState:
        """What the page draws its inputs from (``GET /api/state``)."""
        from grassd.daemon.studio.inputs import TARGET_STDERR, default_lengths

        d = self.cfg.display
        p = self.display.pixel
        return {
            "ready": self.ready, "arch": self.arch,
            "display": {"rows": d.rows, "cols": d.cols, "pitch_mm": d.pitch_mm,
                        "green_max_mm": p.green_max_mm},
            "site": {"latitude": self.cfg.site.latitude, "longitude": self.cfg.site.longitude,
                     "timezone": self.cfg.site.timezone},
            "viewpoints": [[v.h_cm, v.d_m, v.theta_deg] for v in self.cfg.viewpoints],
            "region": self.region.tolist(),
            "region_is_default": self.cfg.audience is None,
            "lights": self.lights.describe(), "light": self.lights.default,
            "pixel": {"source": self.pixel_source, "default": self.default_pixel,
                      "choices": {name: _materials(d.pixel, "config" if name == "config"
                                                   else self.pixel_source)
                                  for name, d in self.displays.items()},
                      **_materials(p, self.pixel_source)},
            "tables": {"active": self.active_um is not None},
            "lengths_mm": list(default_lengths(p.green_max_mm)),
            "target_stderr": TARGET_STDERR,
            "jnd_de00": views.JND_DE00, "contrast_loss": views.CONTRAST_LOSS,
        }

    def picture(self, key: str | None) -> np.ndarray | None:
        """The colours (rows, cols, 3) uint8 sRGB of uploaded picture ``key`` (None: none
        chosen); StudioInputError for an id this studio never gave (or has dropped: the 16
        newest are kept)."""
        if key is None:
            return None
        with self._lock:
            rgb = self.pictures.get(key)
        if rgb is None:
            raise StudioInputError(f"no picture {key!r}: upload it again")
        return rgb

    def add_picture(self, data: bytes) -> PictureUpload:
        """Read an uploaded picture as one sRGB colour per display pixel
        (:func:`~grassd.daemon.studio.views.picture_rgb`); its id for the conditions and those
        colours (``rgb``, rows x cols x 3). StudioInputError for bytes that are not a readable
        picture or too large."""
        d = self.cfg.display
        try:
            rgb = views.picture_rgb(data, d.rows, d.cols)
        except ValueError as exc:
            raise StudioInputError(f"cannot show that picture: {exc}") from None
        with self._lock:
            key = f"picture-{next(self._picture_ids)}"
            self.pictures[key] = rgb
            while len(self.pictures) > 16:
                self.pictures.pop(next(iter(self.pictures)))
        return {"image": key, "rows": d.rows, "cols": d.cols, "rgb": rgb.tolist()}

    @property
    def content(self) -> ContentConfig:
        """The config's ``[content]`` (its defaults where it has none): how a picture's
        colours become levels, as the daemon's content is mapped."""
        from grassd.daemon.content.config import ContentConfig

        return self.cfg.content or ContentConfig()

    def picture_levels(self, rgb: np.ndarray, cond: Condition, curve: SimulatedCurve,
                       table_mm: np.ndarray, check: Check
                       ) -> tuple[np.ndarray, DisplayColours | None]:
        """The levels (rows, cols) uint8 the daemon shows for the picture ``rgb`` (rows, cols,
        3; sRGB) under ``cond``, and the colours they were mapped onto (None unless ``[content]
        map`` is "nearest_de00"): :func:`~grassd.daemon.content.colour_map.levels_for_picture`
        by ``[content] map`` and ``normalise`` onto the D50 CIELAB per length of the
        characteristic at the reference viewpoint under ``cond``'s light and pixel (``curve``
        where ``cond``'s eye is there, else a run of its own to ``cond``'s target, kept as the
        others are), at the levels of ``table_mm`` (256,) [mm]."""
        from grassd.daemon.content.colour_map import (
            REFERENCE_VIEWPOINT,
            DisplayColours,
            levels_for_picture,
        )

        content = self.content
        colours = None
        if content.map == "nearest_de00":
            ref = curve
            if tuple(cond.viewpoint) != REFERENCE_VIEWPOINT:
                at = replace(cond, viewpoint=REFERENCE_VIEWPOINT)
                ref = self._curves.get(_curve_key(at))
                if ref is None:
                    ref = self._converged(at, check)
            h, d, t = REFERENCE_VIEWPOINT
            colours = DisplayColours.from_curve(
                table_mm, ref.lengths_mm, ref.lab,
                f"the studio's characteristic at ({h:g}, {d:g}, {t:g}), {ref.replicates} "
                "replicates")
        return levels_for_picture(rgb, content.map, colours, content.normalise), colours

    # ------------------------------------------------------------------ simulation (worker)
    def warm_up(self) -> float:
        """Initialise Taichi and compile (or load from the cache) the kernels the views use,
        with and without splay (the renderer specialises its kernels on it: a first splay
        would otherwise cost a 2.5 s compile in the middle of a session); seconds taken.
        Runs on the worker thread."""
        from grassd.sim import backend

        t0 = time.perf_counter()
        backend.init(self.arch, cache_dir=self.cfg.cache_dir / "taichi")
        splay = self.display.pixel.splay_deg
        for s in (splay, 5.0 if splay == 0 else 0.0):
            cond = self.parse({"ambient_lux": 1000.0, "viewpoint": [170, 2, 0],
                               "splay_deg": s})
            try:
                self.characteristic(cond, target_stderr=None, replicates=2)
                self._image(cond, self._display(cond), FIRST_IMAGE, 0)
            except StudioInputError as exc:  # a broken first light: the page says so later
                log.warning("warm-up skipped: %s", exc)
                break
        # pvlib's solar position takes 0.75 s on its first call, 4 ms later
        from grassd.daemon.studio.lights import solar_position

        solar_position(*self.site, datetime.now(UTC))
        self.ready = True
        return time.perf_counter() - t0

    def parse(self, data: JsonValue) -> Condition:
        """The page's or a script's condition (JSON) checked against this studio's pixel, site
        and lights (StudioInputError naming what is wrong)."""
        cond = parse_condition(data, green_max_mm=self.display.pixel.green_max_mm,
                               timezone=self.cfg.site.timezone, lights=self.lights.names,
                               default_light=self.lights.default)
        if cond.tables == "active" and self.active_um is None:
            raise StudioInputError("this studio has no active table: ask for tables \"live\", "
                                   "or start it with --state-dir of a daemon that has pushed "
                                   "one")
        return cond

    def _scene(self, cond: Condition) -> tuple[Lighting, DisplaySpec, np.ndarray]:
        """The lighting of ``cond``, its display and the radiance of a white lying flat under
        that light (linear Rec.709 nits: what the pixel's images are scaled by);
        StudioInputError where the condition's light cannot be (its sun below the horizon)."""
        from grassd.daemon.core.calibration.simulation import white_radiance

        lighting = self.lights.lighting(cond, self.site)
        return lighting, self._display(cond), white_radiance(lighting)

    def splay_deg(self, cond: Condition) -> float:
        """The splay (deg) ``cond``'s blades have: its own, else its pixel's (0 for a pixel
        the studio does not have: parsing refuses those)."""
        if cond.splay_deg is not None:
            return cond.splay_deg
        base = self.displays.get(cond.pixel or self.default_pixel)
        return 0.0 if base is None else base.pixel.splay_deg

    def _display(self, cond: Condition) -> DisplaySpec:
        """The display patch of ``cond``: its pixel choice, with its splay."""
        base = self.displays.get(cond.pixel or self.default_pixel)
        if base is None:
            raise StudioInputError(f"pixel {cond.pixel!r} is not one of the studio's: "
                                   + ", ".join(self.displays))
        if cond.splay_deg is None:
            return base
        return replace(base, pixel=replace(base.pixel, splay_deg=cond.splay_deg))

    def characteristic(self, cond: Condition, *, target_stderr: float | None,
                       samples: int | None = None, replicates: int = FIRST_REPLICATES,
                       on_round: Callable | None = None,
                       lengths_mm: Sequence[float] | None = None,
                       check: Check | None = None,
                       resume: CurveRun | None = None) -> SimulatedCurve:
        """The simulated characteristic of ``cond`` (:func:`simulate_curve` at the centre
        pixel of the display's patch) at ``lengths_mm`` (mm; default the condition's),
        ``samples`` paths x ``replicates`` per round, refined to ``target_stderr``
        (CIEDE2000) when given. ``samples`` None: the studio's pace (:func:`studio_pace`:
        fewer paths a replicate and more replicates a round where the blades splay).
        ``check`` is called between the renderer's launches, and before each one (it raises
        to stop the run: a newer input came in); with :attr:`interrupts`, a newer input also
        stops the launch in flight, and a launch takes a whole round. ``resume``: the run's
        state, to go on from where a newer input stopped it (:class:`CurveRun`)."""
        from grassd.daemon.core.calibration.simulation import LargerReplicates, simulate_curve
        from grassd.sim.scene import RenderSettings, Viewpoint

        lighting = self.lights.lighting(cond, self.site)
        display = self._display(cond)
        lengths = np.asarray(cond.lengths_mm if lengths_mm is None else lengths_mm, float)
        larger = None
        if samples is None:
            samples, per_round, most = studio_pace(display.pixel.splay_deg, len(lengths))
            larger = LargerReplicates()
        else:
            per_round, most = ROUND_REPLICATES, MAX_REPLICATES
        settings = RenderSettings(samples=samples, replicates=replicates,
                                  seed=self.cfg.simulation.seed)
        progress = None if check is None else (lambda _done, _total: check())
        with self._renderer(check, samples) as renderer:
            return simulate_curve(renderer, display, lighting, Viewpoint(*cond.viewpoint),
                                  lengths, settings, pixel_index=self.centre,
                                  target_stderr=target_stderr, max_replicates=most,
                                  on_round=on_round, round_replicates=per_round,
                                  progress=progress, larger=larger, resume=resume)

    @contextmanager
    def _renderer(self, check: Check | None,
                  samples: int = STUDIO_SAMPLES) -> Iterator[Renderer]:
        """The process's renderer, set up for a job's ``check`` (None: nothing checks) and
        replicates of ``samples`` paths while the block runs: interrupted by a newer input and
        launching whole rounds where :attr:`interrupts` allow, else in launches that ``check``
        runs between. Its earlier set-up comes back after the block (the pixel's first image
        is drawn inside the characteristic's run)."""
        from grassd.sim.renderer import Renderer

        renderer = Renderer.shared()
        kept = renderer.interrupt, renderer.min_launch_paths, renderer.max_launch_paths
        if check is not None and self.interrupts is not None and renderer.interruptible:
            renderer.interrupt = self.interrupts(check)
            renderer.launch_paths()
        else:
            renderer.interrupt = None
            renderer.launch_paths(STUDIO_LAUNCH_PATHS,
                                  STUDIO_MAX_LAUNCH_PATHS * samples // STUDIO_SAMPLES)
        try:
            yield renderer
        finally:
            renderer.interrupt = kept[0]
            renderer.launch_paths(*kept[1:])

    def _image(self, cond: Condition, display, size: tuple[int, int], seed: int,
               check: Check | None = None) -> np.ndarray:
        """The pixel path-traced from the eye: (width, width, 3) linear Rec.709 [nits]; a
        newer input stops it where :attr:`interrupts` allow (``check`` raises)."""
        from grassd.sim.scene import RenderSettings, Viewpoint

        lighting = self.lights.lighting(cond, self.site)
        with self._renderer(check) as renderer:
            img, _quad = renderer.preview(
                display, lighting, Viewpoint(*cond.viewpoint), cond.length_mm, width=size[0],
                spp=size[1], settings=RenderSettings(seed=seed))
        return img

    def run(self, cond: Condition, emit: Emit, check: Check,
            picture: np.ndarray | None = None, pinned: Condition | None = None) -> None:
        """Compute every view of ``cond`` in the order of the module docstring, sending each as
        it is ready (``emit``); ``check`` raises when a newer request supersedes this one.
        ``picture``: the (rows, cols, 3) sRGB picture the display view shows, if any
        (:meth:`picture_levels`);
        ``pinned``: the condition the page shows beside it as B, whose characteristic and image
        follow A's views."""
        t0 = time.perf_counter()

        def send(msg: PageMessage) -> None:
            msg["ms"] = round((time.perf_counter() - t0) * 1000.0, 1)
            emit(msg)

        lighting, display, white = self._scene(cond)
        send(_light_message(lighting, white))
        curve, kept_shown = self._curve_and_first_image(cond, display, white, send, check)
        check()
        self._fitted_views(cond, curve, picture, send, check)
        if pinned is not None:
            self._pinned(pinned, send, check)
        self._refine_image(cond, display, white, send, check, show_kept=not kept_shown)
        send({"type": "done"})

    def _curve_and_first_image(self, cond: Condition, display: DisplaySpec, white: np.ndarray,
                               send: Emit, check: Check) -> tuple[SimulatedCurve, bool]:
        """``cond``'s characteristic, kept or run to its target with each round sent, and the
        pixel's first image sent after its first round (a kept curve's at once); with whether
        that image was the refined one kept for the condition."""
        first = [True]
        kept_shown = [False]

        def first_image() -> None:
            kept = self._images.get(_image_key(cond))
            if kept is not None:  # refined before: shown as it was, refined on below
                send(_image_message("pixel", *kept, REFINE_PASSES, white))
                kept_shown[0] = True
                return
            img = self._image(cond, display, FIRST_IMAGE, 0, check)
            send({"type": "pixel", "image": views.pixel_png(img, white),
                  "width": FIRST_IMAGE[0], "spp": FIRST_IMAGE[1]})
            check()

        def on_round(curve: SimulatedCurve) -> None:
            check()
            send(curve_message(curve, cond.target_stderr))
            if first[0]:
                first[0] = False
                first_image()

        curve = self._curves.get(_curve_key(cond))
        if curve is not None:  # only the length shown, the tables or the picture changed
            send(curve_message(curve, cond.target_stderr, kept=True))
            first_image()
        else:
            curve = self._converged(cond, check, on_round)
        return curve, kept_shown[0]

    def _fitted_views(self, cond: Condition, curve: SimulatedCurve, picture: np.ndarray | None,
                      send: Emit, check: Check) -> None:
        """What the fitted characteristic of ``cond``'s ``curve`` shows: the table (or why there
        is none), the contrast, the display showing ``picture`` (if any) and the audience
        map (kept: :data:`KEPT_CURVES`)."""
        fit, why = _fit(curve)
        if fit is None:
            send({"type": "table", "error": why})
            return
        table = views.table_view(fit, self.active_um if cond.tables == "active" else None)
        send({"type": "table", **table})
        send({"type": "contrast", **views.contrast_view(fit.ogcd_range)})
        if picture is not None:
            table_mm = np.asarray(table["lengths_mm"])
            levels, colours = self.picture_levels(picture, cond, curve, table_mm, check)
            check()
            eye = np.asarray(cond_eye(cond), float)
            send({"type": "display", "image": views.display_view(
                levels, table_mm, curve.lengths_mm, curve.lab, self.cfg.display.pitch_mm,
                eye), "levels": levels.tolist(), "map": self.content.map,
                "colours": None if colours is None else colours.source})
        # the audience's places are judged as the eye is: the reference vs the longest
        key = _curve_key(cond)
        if key in self._audiences:
            audience = self._audiences[key]
        else:
            ends = curve.ogcd[int(np.argmax(curve.lengths_mm))] - curve.ogcd[0]
            audience = _keep(self._audiences, key, self._audience(cond, float(ends), check),
                             KEPT_CURVES)
        if audience is not None:
            send(audience.copy())

    def _converged(self, cond: Condition, check: Check,
                   on_round: Callable | None = None) -> SimulatedCurve:
        """``cond``'s characteristic run to its target, and kept (:data:`KEPT_CURVES`). A run
        that a newer input stops is kept too, and the next job of the condition goes on from
        its last complete round (showing its curve so far at once) instead of starting over."""
        from grassd.daemon.core.calibration.simulation import CurveRun

        key = _curve_key(cond)
        run = self._runs.pop(key, None) or CurveRun()
        try:
            curve = self.characteristic(cond, target_stderr=cond.target_stderr,
                                        on_round=on_round, check=check, resume=run)
        except BaseException:
            if run.settings is not None:  # begun: its complete rounds are worth keeping
                _keep(self._runs, key, run, KEPT_CURVES)
            raise
        return _keep(self._curves, key, curve, KEPT_CURVES)

    def _pinned(self, cond: Condition, send: Emit, check: Check) -> None:
        """The views of the condition pinned as B, as ``pinned`` messages: its characteristic
        (kept, else run to its target: B may have been pinned before it converged) with its
        OGCD range, then its image refined to :data:`PINNED_PASSES`; one with an ``error``
        where B cannot be computed (its sun set), and A goes on."""
        try:
            _lighting, display, white = self._scene(cond)
            curve = self._curves.get(_curve_key(cond))
            kept = curve is not None
            if curve is None:
                curve = self._converged(cond, check)
        except StudioInputError as exc:
            send({"type": "pinned", "error": str(exc), "final": True})
            return
        msg: PinnedMessage = {"type": "pinned",
                              "curve": curve_message(curve, cond.target_stderr, kept=kept)}
        fit, _why = _fit(curve)
        if fit is not None:  # else no monotone fit: the curve alone
            msg["ogcd_range"] = fit.ogcd_range
        send(msg)
        self._refine_image(cond, display, white, send, check, PINNED_PASSES, "pinned")

    def _audience(self, cond: Condition, eye_range: float,
                  check: Check) -> AudienceMessage | None:
        """The OGCD range from places over the audience region at the eye's height (two
        lengths each: the reference and the longest), as one map's message (None where no
        place of the region is far enough from the display)."""
        from grassd.daemon.core.calibration.audience import points_in_polygon

        region = self.region
        lo, hi = region.min(axis=0), region.max(axis=0)
        step = math.sqrt(float(np.prod(hi - lo)) / AUDIENCE_POINTS)
        xs = np.arange(lo[0] + step / 2, hi[0], step)
        ys = np.arange(lo[1] + step / 2, hi[1], step)
        grid = np.array([(x, y) for y in ys for x in xs])
        inside = grid[points_in_polygon(grid, region)] if grid.size else grid
        ends = (cond.lengths_mm[0], max(cond.lengths_mm))
        places = []
        for x, y in inside:
            d = math.hypot(x, y)
            if d < 0.05:
                continue
            theta = math.degrees(math.atan2(x, -y))
            at = replace(cond, viewpoint=(cond.viewpoint[0], min(d, 1000.0), theta))
            c = self.characteristic(at, target_stderr=None, lengths_mm=ends,
                                    samples=STUDIO_SAMPLES, check=check)
            places.append((float(x), float(y), float(c.ogcd[1] - c.ogcd[0]),
                           float(c.ogcd_stderr[1])))
            check()
        if not places:
            return None
        ranges = np.array([p[2] for p in places])
        warn = views.audience_warning(ranges, eye_range)
        return {"type": "audience", "step_m": step, "eye_range": eye_range,
                "h_cm": cond.viewpoint[0],
                "places": [{"x": p[0], "y": p[1], "range": round(p[2], 3),
                            "stderr": round(p[3], 3), "warn": bool(w)}
                           for p, w in zip(places, warn, strict=True)],
                "warned": int(warn.sum()), "loss": views.CONTRAST_LOSS}

    def _refine_image(self, cond: Condition, display, white: np.ndarray, send: Emit,
                      check: Check, passes: int = REFINE_PASSES,
                      kind: Literal["pixel", "pinned"] = "pixel",
                      show_kept: bool = True) -> None:
        """Refine the pixel's image of ``cond`` to ``passes`` passes of :data:`REFINE_IMAGE`,
        going on from the passes kept for it, and send it (a ``kind`` message, ``final`` once
        it has ``passes``) after each pass, and first where passes were kept (unless
        ``show_kept`` is False: the job's first image was that one). A pass that a newer
        request stops is lost; the passes completed are kept, the last perhaps unsent (the
        image is sent after ``check``), so a run seen again starts by sending it."""
        key = _image_key(cond)
        total, done = self._images.pop(key, (None, 0))

        def show(total: np.ndarray) -> None:
            send(_image_message(kind, total, done, passes, white))

        try:
            if done and show_kept and total is not None:
                show(total)
            for k in range(done, passes):
                img = self._image(cond, display, REFINE_IMAGE, 1 + k, check)
                total = img if total is None else total + img
                done = k + 1
                check()
                show(total)
        finally:
            if total is not None:
                _keep(self._images, key, (total, done), KEPT_IMAGES)


def _materials(p: PixelSpec, source: str) -> Materials:
    """A pixel's materials as the page shows them (8-bit sRGB albedos, gloss, splay)."""
    return {"source": source, "splay_deg": p.splay_deg, "specular": p.specular,
            "smoothness": p.smoothness, "green_srgb": list(p.green_srgb),
            "yellow_srgb": list(p.yellow_srgb), "base_srgb": list(p.base_srgb)}


def cond_eye(cond: Condition) -> tuple[float, float, float]:
    """The eye of ``cond`` in metres, the display's centre at the origin."""
    from grassd.sim.scene import Viewpoint

    return tuple(Viewpoint(*cond.viewpoint).eye_m())


def curve_message(curve: SimulatedCurve, target: float | None, *, kept: bool = False
                  ) -> CurveMessage:
    """A characteristic as the page and the API send it: lengths (mm), OGCD and its standard
    error (CIEDE2000), the simulated pixel's colour per length (sRGB, and ``lab_d50``: D50
    CIELAB unrounded, as a calibration report keeps it), replicates so far;
    ``kept``: computed for an earlier input with the same light, eye, pixel and lengths."""
    worst = float(np.max(curve.ogcd_stderr))
    return {"type": "curve", "lengths_mm": _rounded(curve.lengths_mm),
            "ogcd": _rounded(curve.ogcd), "ogcd_stderr": _rounded(curve.ogcd_stderr, 5),
            "srgb": views.lab_to_srgb8(curve.lab).tolist(),
            "lab_d50": np.asarray(curve.lab, np.float64).tolist(), "replicates": curve.replicates,
            "max_stderr": worst, "converged": target is not None and worst <= target,
            "kept": kept}
