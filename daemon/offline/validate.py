"""``grassd validate``: compare the simulated grass colour characteristic with real captures.

A *capture directory* holds what a user photographs on site (the paper's real-environment
process, section 3.4.1) and a manifest ``capture.toml`` describing it. Its light and checker
keys are those of a light bundle's ``manifest.toml``, with the same checks
(:mod:`grassd.daemon.core.config.manifest_fields`); file names are paths, relative to the capture
directory or absolute::

    hdri = "env.exr"                      # the panorama taken with the photos (.exr or .hdr)
    ambient_lux = 500.0                   # horizontal illuminance, sun shaded (lux)
    # sun_lux, sun_azimuth_deg, sun_elevation_deg: optional, as in a bundle; and, for
    # capture.toml only, sun_from_hdri (find the sun in the map), rotation_deg (of the map)
    checker_raw = "checker.dng"           # one RAW of the colour checker at the measuring point
    checker_corners = [[x, y], [x, y], [x, y], [x, y]]   # patch area: TL, TR, BR, BL (pixels)
    checker_chart = "spydercheckr-24"     # reference chart name or CSV file (optional)
    camera_sensitivities = "camera.csv"   # the camera's spectral sensitivities (optional)

    [pixel]                               # optional PixelSpec fields of the simulation model
    splay_deg = 0.0

    [[series]]                            # one per viewpoint
    viewpoint = [170.0, 2.0, 0.0]         # h cm, d m, theta deg
    corners = [[x, y], ...]               # the pixel's top quad (default for its photos)
    reference = true                      # the viewpoint M is reported for (default 170, 2, 0)
    photos = [{ file = "v0_00.dng", length_mm = 0.0 }, ...]   # lengths strictly increasing

Older capture directories wrote ``chart``, a ``[light]`` table (``hdri``, ``lux``, ...) and a
``[checker]`` table (``photo``, ``corners``): :data:`OLD_NAMES` are still read, with a warning.

Corners are pixel coordinates (x = column, y = row) of the developed image as LibRaw outputs
it (i.e. after the camera's orientation flag is applied), pixel (0, 0) covering [0, 1) x [0, 1).
All photos must come from one camera with one exposure setting (manual mode): the checker's grey
sets the exposure of every photo.

Steps (:func:`validate_capture`): every RAW is developed linearly to 16-bit ProPhoto RGB with one
fixed white balance, measured from the checker's grey patch on the undeveloped Bayer data; the
checker's grey sets the exposure (Y = 0.18) for all photos; the mean colour inside each photo's
quad gives the real characteristic (CIELAB, OGCD). The same scene is simulated (averaged over
``layouts`` random tuft layouts, as ``grassd fit`` averages them), the 3x3 matrix M
is fitted from the virtual to the real checker patches (one M for every viewpoint, as in the
paper), and per viewpoint we report the discrete Frechet distance, the maximum OGCD error and
where it occurs, both OGCD ranges, and the paper's Figure 11 experiment: the R^2 of OGCD vs
8-bit level before calibration, after calibrating with the real characteristic, and after
calibrating with the simulated one (evaluated on the real pixel).

Colour chain of the simulation, kept identical to the real one: radiance / white-card radiance
(von Kries in linear Rec.709, the white card reads 1) -> ProPhoto -> scaled so the virtual
checker's grey reads Y = 0.18 -> M -> CIELAB. The virtual checker is analytic: a flat Lambertian
patch of albedo ``a`` (the chart's reference colour) reads ``a`` after the same normalisation.
Where ``camera_sensitivities`` names the camera's spectral sensitivities, the simulation is read
through the camera itself instead (spectral transport into its raw RGB, developed as the photos
are; :mod:`grassd.daemon.offline.colour_chain`), and M is only reported.
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, NotRequired, TypedDict

import numpy as np
import tomli_w
from numpy.typing import NDArray

from grassd.calib.ccm import ColourCorrection, select_ccm
from grassd.calib.characteristic import Characteristic, fit_characteristic, floor_stderr
from grassd.calib.charts import CHARTS, ReferenceChart, get_chart
from grassd.calib.checker_photo import check_inside, checker_white_balance, virtual_checker
from grassd.calib.colour_spaces import luminance, prophoto_to_lab
from grassd.calib.compare import frechet_characteristics
from grassd.calib.errors import CalibError
from grassd.calib.exposure import GREY_CARD_Y
from grassd.calib.length_table import LEVELS, build_length_table, r_squared
from grassd.calib.ogcd import ogcd_from_lab
from grassd.calib.raw import develop_raw, open_raw
from grassd.daemon.core.config import manifest_fields, schema
from grassd.daemon.core.errors import DaemonError, LocatedError, ManifestError
from grassd.daemon.offline.colour_chain import CorrectedChain, simulation_chain
from grassd.sim.light_input import LightInput

if TYPE_CHECKING:
    from grassd.calib.ogcd import OGCDResult
    from grassd.daemon.core.config.settings import PixelValue
    from grassd.daemon.offline.colour_chain import ColourChain
    from grassd.sim.lighting import Lighting
    from grassd.sim.renderer import Renderer
    from grassd.sim.scene import PixelSpec, RenderSettings, Viewpoint

log = logging.getLogger(__name__)

#: File name of the manifest inside a capture directory.
MANIFEST_NAME: str = "capture.toml"
#: The paper's reference viewpoint (h cm, d m, theta deg).
REFERENCE_VIEWPOINT: tuple[float, float, float] = (170.0, 2.0, 0.0)


class ValidateError(DaemonError):
    """A capture directory cannot be validated; the message says what to fix."""


class CaptureManifestError(ValidateError, LocatedError):
    """``capture.toml`` is missing, malformed, or holds an unknown key or a bad value."""


class MissingPhotoError(ValidateError):
    """A photo named in the manifest does not exist."""


class LengthOrderError(ValidateError):
    """The green lengths of a series are not strictly increasing."""


class MixedCamerasError(ValidateError):
    """The photos were not all taken with the same camera (make, model, sensor layout)."""


def default_renderer(arch: str = "cpu") -> Renderer:
    """The process's shared :class:`grassd.sim.renderer.Renderer` (Taichi initialised on
    ``arch`` first if needed): every further instance would compile its kernels again."""
    from grassd.sim import backend

    if not backend.is_initialised():
        backend.init(arch)
    from grassd.sim.renderer import Renderer

    return Renderer.shared()


# ----------------------------------------------------------------------------- manifest
@dataclass(frozen=True)
class Photo:
    """One RAW of the grass pixel: file, green length (mm), top-quad corners (4, 2) (x, y)."""

    path: Path
    length_mm: float
    corners: tuple[tuple[float, float], ...]


@dataclass(frozen=True)
class Series:
    """The photos of one viewpoint (h cm, d m, theta deg), lengths strictly increasing."""

    viewpoint: tuple[float, float, float]
    photos: tuple[Photo, ...]
    reference: bool = False

    @property
    def lengths_mm(self) -> NDArray[np.float64]:
        """(n,) green lengths, mm."""
        return np.array([p.length_mm for p in self.photos], dtype=np.float64)

    @property
    def label(self) -> str:
        """``(h, d, theta)`` as the paper writes it."""
        h, d, t = self.viewpoint
        return f"({h:g}, {d:g}, {t:g})"


@dataclass(frozen=True)
class CaptureManifest:
    """A parsed ``capture.toml`` (paths resolved against the capture directory)."""

    root: Path
    light: LightInput
    checker_photo: Path
    checker_corners: tuple[tuple[float, float], ...]
    series: tuple[Series, ...]
    chart: str = manifest_fields.DEFAULT_CHART
    pixel: dict[str, PixelValue] = field(default_factory=dict)
    #: the camera's spectral sensitivities: a CSV's path or a name of
    #: :data:`grassd.calib.camera_response.COLOUR_CAMERAS`; None: read through the checker's
    #: correction (:mod:`grassd.daemon.offline.colour_chain`)
    sensitivities: str | None = None

    @property
    def reference(self) -> Series:
        """The series marked ``reference``, else the one at (170, 2, 0), else the first."""
        for s in self.series:
            if s.reference:
                return s
        for s in self.series:
            if s.viewpoint == REFERENCE_VIEWPOINT:
                return s
        return self.series[0]

    def photos(self) -> list[Path]:
        """Every RAW of the capture, checker first."""
        return [self.checker_photo] + [p.path for s in self.series for p in s.photos]


class _PhotoToml(TypedDict):
    """A photo of a ``[[series]]`` as :func:`manifest_to_toml` writes it."""

    file: str
    length_mm: float
    corners: list[list[float]]


class _SeriesToml(TypedDict):
    """A ``[[series]]`` as :func:`manifest_to_toml` writes it."""

    viewpoint: list[float]
    reference: NotRequired[bool]
    photos: list[_PhotoToml]


class _CaptureToml(TypedDict, total=False):
    """``capture.toml`` as :func:`manifest_to_toml` writes it (the sun's keys where given)."""

    hdri: str
    ambient_lux: float
    sun_lux: float
    sun_azimuth_deg: float
    sun_elevation_deg: float
    sun_from_hdri: bool
    rotation_deg: float
    checker_raw: str
    checker_corners: list[list[float]]
    checker_chart: str
    camera_sensitivities: str
    pixel: dict[str, PixelValue]
    series: list[_SeriesToml]


def manifest_to_toml(m: CaptureManifest) -> str:
    """TOML text of a manifest (paths relative to ``m.root`` where they lie inside it), in the
    bundle manifest's vocabulary (:mod:`grassd.daemon.core.config.manifest_fields`)."""

    def rel(p: Path) -> str:
        try:
            return str(Path(p).resolve().relative_to(m.root.resolve()))
        except ValueError:
            return str(Path(p).resolve())

    def series(s: Series) -> _SeriesToml:
        photos = [_PhotoToml(file=rel(p.path), length_mm=p.length_mm,
                             corners=[list(c) for c in p.corners]) for p in s.photos]
        if s.reference:
            return {"viewpoint": list(s.viewpoint), "reference": True, "photos": photos}
        return {"viewpoint": list(s.viewpoint), "photos": photos}

    light = m.light
    head = _CaptureToml(hdri=rel(light.hdri), ambient_lux=light.ambient_lux)
    if light.sun_lux is not None:
        head["sun_lux"] = light.sun_lux
    if light.sun_azimuth_deg is not None:
        head["sun_azimuth_deg"] = light.sun_azimuth_deg
    if light.sun_elevation_deg is not None:
        head["sun_elevation_deg"] = light.sun_elevation_deg
    if light.sun_from_hdri:
        head["sun_from_hdri"] = True
    if light.rotation_deg:
        head["rotation_deg"] = light.rotation_deg
    head["checker_raw"] = rel(m.checker_photo)
    head["checker_corners"] = [list(c) for c in m.checker_corners]
    head["checker_chart"] = rel(Path(m.chart)) if Path(m.chart).is_absolute() else m.chart
    if m.sensitivities is not None:
        head["camera_sensitivities"] = (rel(Path(m.sensitivities))
                                        if Path(m.sensitivities).is_absolute()
                                        else m.sensitivities)
    if m.pixel:
        head["pixel"] = dict(m.pixel)
    if m.series:
        head["series"] = [series(s) for s in m.series]
    return tomli_w.dumps(head)


#: capture.toml's old names, still read (deprecated): where they were written (a table, or the
#: top level) -> {old key: the bundle manifest's name, now written at the top level}.
OLD_NAMES: dict[tuple[str, ...], dict[str, str]] = {
    (): {"chart": "checker_chart"},
    ("light",): {"hdri": "hdri", "lux": "ambient_lux", "sun_lux": "sun_lux",
                 "sun_azimuth_deg": "sun_azimuth_deg", "sun_elevation_deg": "sun_elevation_deg",
                 "sun_from_hdri": "sun_from_hdri", "rotation_deg": "rotation_deg"},
    ("checker",): {"photo": "checker_raw", "corners": "checker_corners"},
}


def _light_fields() -> dict[str, schema.Field]:
    """The schema of capture.toml's light and checker keys: the bundle manifest's
    (:func:`grassd.daemon.core.config.manifest_fields.light_fields`; files as paths, the ambient lux
    and the checker required) and ``sun_from_hdri``, ``rotation_deg`` (degrees; defaults:
    :class:`LightInput`'s)."""
    F = schema.Field
    fields = manifest_fields.light_fields(plain_names=False, ambient_required=True)
    fields["checker_raw"] = replace(fields["checker_raw"], default=schema.MISSING,
                                    hint="the path of the checker's RAW photo")
    fields["checker_corners"] = replace(fields["checker_corners"], default=schema.MISSING,
                                        hint="four [x, y] corners of the chart (pixels)")
    return {**fields, **schema.schema(
        LightInput, sun_from_hdri=F(bool),
        rotation_deg=F(float, check=schema.between(-360.0, 360.0, " degrees")))}


def _rename_old(ctx: schema.Context, data: schema.TomlTable, source: Path
                ) -> tuple[schema.TomlTable, dict[str, tuple]]:
    """``data`` with the old names (:data:`OLD_NAMES`) checked where they are written and moved
    to the new ones, and where each moved key was written (for later errors); logs one
    deprecation warning naming the renames."""
    fields = _light_fields()
    out = dict(data)
    where: dict[str, tuple] = {}
    for prefix, names in OLD_NAMES.items():
        if prefix:
            if prefix[0] not in data:
                continue
            written = out.pop(prefix[0])
        else:
            written = {k: out.pop(k) for k in names if k in data}
            if not written:
                continue
        values = schema.table(ctx, prefix, written, {o: fields[n] for o, n in names.items()})
        for old, new in names.items():
            if old not in written:
                continue
            if new in data:
                raise ctx.error((new,), f"given twice: also as {schema.key_path(prefix + (old,))}"
                                ", its old name; delete that one")
            out[new], where[new] = values[old], prefix + (old,)
    if where:
        renamed = ", ".join(f"{schema.key_path(w)} -> {n}" for n, w in where.items())
        log.warning("%s uses deprecated names (%s): write these keys at the top of the file, "
                    "before [pixel] and [[series]], as a bundle's manifest.toml names them "
                    "(the old names will stop being read)", source, renamed)
    return out, where


#: What a ``[pixel]`` value must be.
_NUMBERS = "a number or a list of numbers"


def _numbers_only(v: schema.TomlValue) -> str | None:
    """Check: a list given for a ``[pixel]`` value holds numbers only."""
    ok = not isinstance(v, list) or all(
        isinstance(x, int | float) and not isinstance(x, bool) for x in v)
    return None if ok else f"must be {_NUMBERS}"


def _at_least_3(v: list) -> str | None:
    return None if len(v) >= 3 else "must list at least 3 photos ({ file = ..., length_mm = ... })"


def _read_toml(path: str | Path) -> tuple[Path, str, schema.TomlTable]:
    """(the manifest's path, its text, its data) of ``capture.toml`` at ``path`` (a file, or a
    directory holding one), read as a bundle's manifest is
    (:func:`grassd.daemon.core.store.manifest.read_manifest_text`: a regular file within the
    manifest byte cap, nested at most MAX_MANIFEST_DEPTH deep); CaptureManifestError when it is
    missing, not TOML or beyond a cap."""
    from grassd.daemon.core.store.manifest import read_manifest_text

    p = Path(path)
    if p.is_dir():
        p = p / MANIFEST_NAME
    if not os.path.lexists(p):
        raise CaptureManifestError(f"{p} does not exist: a capture directory needs a "
                                   f"{MANIFEST_NAME} manifest")
    try:
        text, data = read_manifest_text(p)
    except ManifestError as exc:
        raise CaptureManifestError(f"{p}: {exc}") from None
    return p, text, data


def _light(ctx: schema.Context, top: dict[str, Any], where: Callable[[str], tuple]
           ) -> LightInput:
    """The light of the validated keys ``top``: the HDRI must exist and the sun reading be one
    that can be (:func:`grassd.sim.sun.check_sun_reading`)."""
    from grassd.sim.errors import LightingError
    from grassd.sim.sun import check_sun_reading

    hdri = _path(ctx, top["hdri"])
    if not hdri.is_file():
        raise MissingPhotoError(f"{ctx.source}: {schema.key_path(where('hdri'))} {hdri} does "
                                "not exist; copy the panorama taken with the photos into the "
                                "capture directory")
    try:
        check_sun_reading(top["sun_lux"], top["sun_azimuth_deg"], top["sun_elevation_deg"])
    except LightingError as exc:
        raise ctx.error(where("sun_lux"), f"impossible sun: {exc}") from None
    return LightInput(hdri=hdri, ambient_lux=top["ambient_lux"], sun_lux=top["sun_lux"],
                      sun_azimuth_deg=top["sun_azimuth_deg"],
                      sun_elevation_deg=top["sun_elevation_deg"],
                      sun_from_hdri=top["sun_from_hdri"], rotation_deg=top["rotation_deg"])


def _path(ctx: schema.Context, name: str) -> Path:
    """A file named in the manifest: absolute, or relative to the capture directory."""
    f = Path(name)
    return f if f.is_absolute() else ctx.base_dir / f


def _chart(ctx: schema.Context, name: str, where: Callable[[str], tuple]) -> str:
    """The checker's reference chart as :func:`grassd.calib.charts.get_chart` takes it: a
    built-in chart's name as written, else the path of a chart CSV (a name ending in ``.csv``
    or naming a file), absolute or relative to the capture directory like every other file of
    a capture; :class:`MissingPhotoError` where that file does not exist."""
    if name.lower().replace(" ", "-").replace("_", "-") in CHARTS:
        return name
    path = _path(ctx, name)
    if Path(name).suffix.lower() != ".csv" and not path.exists():
        return name  # neither a built-in name nor a file: get_chart names the choices
    if not path.is_file():
        raise MissingPhotoError(f"{ctx.source}: {schema.key_path(where('checker_chart'))} "
                                f"{path} does not exist; copy the chart's CSV into the capture "
                                "directory or name a built-in chart ("
                                + ", ".join(CHARTS) + ")")
    return str(path)


def _sensitivities(ctx: schema.Context, name: str | None) -> str | None:
    """``camera_sensitivities`` as :func:`grassd.daemon.offline.colour_chain.load_sensitivities`
    takes it: a name of colour-science's cameras as written, else the path of a CSV, absolute
    or relative to the capture directory; :class:`MissingPhotoError` where it does not exist."""
    from grassd.calib.camera_response import COLOUR_CAMERAS

    if name is None or name in COLOUR_CAMERAS:
        return name
    path = _path(ctx, name)
    if not path.is_file():
        raise MissingPhotoError(f"{ctx.source}: camera_sensitivities {path} does not exist; "
                                "copy the camera's CSV of spectral sensitivities into the "
                                "capture directory or name one of " + ", ".join(COLOUR_CAMERAS))
    return str(path)


def _series(ctx: schema.Context, i: int, raw: schema.TomlValue) -> Series:
    """``[[series]]`` number ``i``: its viewpoint and photos (lengths strictly increasing)."""
    F = schema.Field
    where = f"series[{i}]"
    st = schema.table(ctx, ("series", i), raw, schema.schema(
        Series, viewpoint=F(list, check=schema.numbers(3), hint="[h_cm, d_m, theta_deg]"),
        corners=F(list, None, manifest_fields.quad), reference=F(bool),
        photos=F(list, check=_at_least_3)))
    photos = []
    for j, ph_raw in enumerate(st["photos"]):
        pw = ("series", i, "photos", j)
        ph = schema.table(ctx, pw, ph_raw, {
            "file": F(str, check=schema.non_empty),
            "length_mm": F(float, check=schema.non_negative),
            "corners": F(list, st["corners"], manifest_fields.quad)})
        if ph["corners"] is None:
            raise ctx.error(pw, f"has no corners and {where} gives no default corners")
        photos.append(Photo(_path(ctx, ph["file"]), ph["length_mm"],
                            manifest_fields.as_quad(ph["corners"])))
    lengths = [ph.length_mm for ph in photos]
    bad = [k for k in range(1, len(lengths)) if lengths[k] <= lengths[k - 1]]
    if bad:
        k = bad[0]
        raise LengthOrderError(
            f"{ctx.source}: {where} lengths must be strictly increasing (the first photo is the "
            f"OGCD reference); photo {k} ({photos[k].path.name}) has {lengths[k]:g} mm after "
            f"{lengths[k - 1]:g} mm")
    return Series(tuple(float(v) for v in st["viewpoint"]),  # type: ignore[arg-type]
                  tuple(photos), st["reference"])


def load_manifest(path: str | Path) -> CaptureManifest:
    """Parse and check ``capture.toml`` (a file, or a directory holding one).

    Its light and checker keys are a bundle manifest's, checked the same way
    (:mod:`grassd.daemon.core.config.manifest_fields`); the old names (:data:`OLD_NAMES`) are still
    read, with a deprecation warning. Raises :class:`CaptureManifestError` (syntax,
    missing/unknown keys, bad values; the message names the key and its line,
    :mod:`grassd.daemon.core.config.schema`), :class:`MissingPhotoError` (a listed RAW or the HDRI
    does not exist) and :class:`LengthOrderError` (lengths of a series not strictly increasing).
    """
    from grassd.sim.scene import PixelSpec

    p, text, data = _read_toml(path)
    ctx = schema.Context(text, str(p), p.parent, error=CaptureManifestError)
    F = schema.Field
    data, moved = _rename_old(ctx, data, p)

    def where(key: str) -> tuple:
        return moved.get(key, (key,))

    top = schema.table(ctx, (), data, {
        **_light_fields(), "pixel": F(dict, {}), "series": F(list),
        "camera_sensitivities": F(str, None, schema.non_empty,
                                  hint="a CSV of the camera's spectral sensitivities")})
    manifest_fields.check_together(ctx, top, where)
    light = _light(ctx, top, where)
    schema.table(ctx, ("pixel",), top["pixel"],  # PixelSpec checks the values when it is built
                 {k: F(int | float | list, None, _numbers_only, hint=_NUMBERS)
                  for k in PixelSpec.__dataclass_fields__})
    pixel = {k: tuple(v) if isinstance(v, list) else v for k, v in top["pixel"].items()}
    if not top["series"]:
        raise ctx.error(("series",), "give at least one [[series]] of photos")
    series = tuple(_series(ctx, i, raw) for i, raw in enumerate(top["series"]))
    if sum(s.reference for s in series) > 1:
        raise ctx.error(("series",), "more than one series is marked reference = true")
    m = CaptureManifest(root=p.parent, light=light, checker_photo=_path(ctx, top["checker_raw"]),
                        checker_corners=manifest_fields.as_quad(top["checker_corners"]),
                        series=series, chart=_chart(ctx, top["checker_chart"], where),
                        pixel=pixel,
                        sensitivities=_sensitivities(ctx, top["camera_sensitivities"]))
    for photo in m.photos():
        if not photo.is_file():
            raise MissingPhotoError(f"{p}: photo {photo} does not exist; copy it into the "
                                    "capture directory or fix its name in the manifest")
    return m


# ----------------------------------------------------------------------------- real side
class CameraSignature(TypedDict):
    """What identifies the camera of a RAW: ``make``/``model`` (TIFF-based RAWs; empty in
    others), the colour filter layout ``cfa``, the ``white_level`` and LibRaw's colour
    ``matrix`` (to 3 decimals)."""

    make: str
    model: str
    cfa: str
    white_level: int
    matrix: tuple[float, ...]


def camera_signature(path: Path) -> CameraSignature:
    """What identifies the camera of a RAW (:class:`CameraSignature`)."""
    tagged = {271: "", 272: ""}  # make, model
    try:
        import tifffile

        with tifffile.TiffFile(path) as tf:
            tags = tf.pages[0].tags
            for code in tagged:
                if code in tags:
                    tagged[code] = str(tags[code].value).strip()
    except Exception:  # non-TIFF RAW formats (CR3, RAF...) carry no such tags
        pass
    try:
        with open_raw(path) as raw:
            return CameraSignature(
                make=tagged[271], model=tagged[272],
                cfa=raw.color_desc.decode(errors="replace") + ":" + "".join(
                    map(str, np.asarray(raw.raw_pattern).ravel())),
                white_level=int(raw.white_level),
                matrix=tuple(np.round(np.asarray(raw.color_matrix, float), 3).ravel()))
    except Exception as exc:  # rawpy raises several unrelated types
        raise ValidateError(f"{path} is not a RAW file LibRaw can open ({exc}); give the camera's "
                            "unmodified RAW or DNG") from None


def _describe(sig: CameraSignature) -> str:
    name = f"{sig['make']} {sig['model']}".strip() or "an unnamed camera"
    return f"{name} (CFA {sig['cfa']}, white level {sig['white_level']})"


def check_same_camera(paths: Sequence[Path]) -> CameraSignature:
    """The common camera signature of ``paths``; :class:`MixedCamerasError` if they differ."""
    first = camera_signature(paths[0])
    for p in paths[1:]:
        sig = camera_signature(p)
        if sig != first:
            what = [k for k, v in first.items() if v != sig.get(k)]
            raise MixedCamerasError(
                f"{Path(p).name} was taken with {_describe(sig)} but {Path(paths[0]).name} with "
                f"{_describe(first)} (differs in {', '.join(what)}); take every photo of a "
                "capture, the checker included, with the same camera and settings")
    return first


@dataclass(frozen=True)
class RealCapture:
    """The measured (real) side of a capture.

    ``white_balance``: LibRaw multipliers from the checker; ``exposure``: factor that puts the
    checker's grey at Y = 0.18; ``checker_rgb`` (24, 3) normalised ProPhoto linear patches;
    ``rgb`` / ``lab`` / ``ogcd`` per series (n, 3) / (n, 3) / (n,); ``camera``: its signature.
    """

    white_balance: tuple[float, float, float, float]
    exposure: float
    checker_rgb: NDArray[np.float64]
    rgb: tuple[NDArray[np.float64], ...]
    lab: tuple[NDArray[np.float64], ...]
    ogcd: tuple[NDArray[np.float64], ...]
    camera: CameraSignature
    seconds: float


def measure_real(m: CaptureManifest, chart: ReferenceChart | None = None,
                 progress: Callable[[str], None] | None = None) -> RealCapture:
    """Develop and measure every RAW of a capture (see the module docstring)."""
    t0 = time.perf_counter()
    chart = chart or get_chart(m.chart)
    camera = check_same_camera(m.photos())
    wb = checker_white_balance(m.checker_photo, m.checker_corners, chart)
    dev = develop_raw(m.checker_photo, white_balance=wb)
    check_inside(m.checker_corners, dev.rgb.shape, m.checker_photo, "checker")
    patches = dev.checker_patches(m.checker_corners)
    grey_y = float(luminance(patches[chart.grey_index()], "prophoto"))
    if grey_y <= 0:
        raise ValidateError(f"{m.checker_photo.name}: the grey patch is black; check the corners")
    k = GREY_CARD_Y / grey_y
    rgbs, labs, ogcds = [], [], []
    for s in m.series:
        rows = []
        for ph in s.photos:
            if progress:
                progress(f"developing {ph.path.name}")
            img = develop_raw(ph.path, white_balance=wb)
            check_inside(ph.corners, img.rgb.shape, ph.path, "pixel quad")
            rows.append(img.quad_mean(ph.corners) * k)
        rgb = np.array(rows)
        lab = prophoto_to_lab(rgb)
        rgbs.append(rgb)
        labs.append(lab)
        ogcds.append(ogcd_from_lab(lab))
    return RealCapture(white_balance=wb, exposure=k, checker_rgb=patches * k, rgb=tuple(rgbs),
                       lab=tuple(labs), ogcd=tuple(ogcds), camera=camera,
                       seconds=time.perf_counter() - t0)


# ----------------------------------------------------------------------------- comparison
def max_error_at(real: Characteristic, sim: Characteristic) -> tuple[float, float]:
    """Largest |OGCD_real - OGCD_sim| (dE00) and the length (mm) where it occurs, on the union
    of both samplings within their common range (as :func:`grassd.calib.compare.max_ogcd_error`)."""
    lo = max(real.lengths_mm[0], sim.lengths_mm[0])
    hi = min(real.lengths_mm[-1], sim.lengths_mm[-1])
    grid = np.union1d(real.lengths_mm, sim.lengths_mm)
    grid = grid[(grid >= lo) & (grid <= hi)]
    diff = np.abs(np.interp(grid, real.lengths_mm, real.ogcd)
                  - np.interp(grid, sim.lengths_mm, sim.ogcd))
    i = int(np.argmax(diff))
    return float(diff[i]), float(grid[i])


class CalibrationReport(TypedDict):
    """The JSON of a :class:`CalibrationCheck`: its R^2 values."""

    r2_before: float
    r2_after_real: float
    r2_after_sim: float


class ViewpointReport(TypedDict):
    """The JSON of a :class:`ViewpointComparison` (lengths mm, OGCD and CIELAB per length)."""

    viewpoint: list[float]
    reference: bool
    lengths_mm: list[float]
    real_ogcd: list[float]
    sim_ogcd: list[float]
    sim_ogcd_stderr: list[float] | None
    real_lab: list[list[float]]
    sim_lab: list[list[float]]
    frechet: float
    max_ogcd_error: float
    max_ogcd_error_length_mm: float
    real_ogcd_range: float
    sim_ogcd_range: float
    calibration: CalibrationReport | None
    sim_seconds: float


@dataclass(frozen=True)
class CalibrationCheck:
    """The paper's Figure 11 for one viewpoint: OGCD of the REAL pixel vs 8-bit level.

    ``before``: length linear in level; ``after_real`` / ``after_sim``: lengths from the table
    built on the real / simulated characteristic. Each (256,) array with its R^2 and line.
    """

    levels: NDArray[np.float64]
    before: NDArray[np.float64]
    after_real: NDArray[np.float64]
    after_sim: NDArray[np.float64]
    r2_before: float
    r2_after_real: float
    r2_after_sim: float

    def to_json(self) -> CalibrationReport:
        """R^2 values only (the arrays are plotted)."""
        return {"r2_before": self.r2_before, "r2_after_real": self.r2_after_real,
                "r2_after_sim": self.r2_after_sim}


def calibration_check(real: Characteristic, sim: Characteristic) -> CalibrationCheck:
    """8-bit calibration R^2 before and after, with the real and with the simulated table,
    always evaluated on the real pixel's fitted characteristic (paper: 0.956 -> 0.999 real,
    0.956 -> 0.965 simulated)."""
    fit_real = fit_characteristic(real)
    levels = np.arange(LEVELS, dtype=np.float64)
    table_real = build_length_table(fit_real)
    table_sim = build_length_table(sim)
    after_sim = fit_real(np.clip(table_sim.lengths_mm, fit_real.min_length_mm,
                                 fit_real.max_length_mm))
    return CalibrationCheck(levels=levels, before=table_real.uncalibrated_ogcd,
                            after_real=table_real.achieved_ogcd, after_sim=after_sim,
                            r2_before=table_real.r2_before, r2_after_real=table_real.r2_after,
                            r2_after_sim=r_squared(levels, after_sim))


@dataclass(frozen=True)
class ViewpointComparison:
    """Real vs simulated characteristic of one viewpoint, with the paper's metrics."""

    viewpoint: tuple[float, float, float]
    reference: bool
    real: Characteristic
    sim: Characteristic
    real_lab: NDArray[np.float64]
    sim_lab: NDArray[np.float64]
    frechet: float
    max_error: float
    max_error_length_mm: float
    calibration: CalibrationCheck | None
    sim_seconds: float  # simulation wall time of this viewpoint, kernel compilation excluded

    @property
    def label(self) -> str:
        """``(h, d, theta)``."""
        h, d, t = self.viewpoint
        return f"({h:g}, {d:g}, {t:g})"

    @property
    def real_range(self) -> float:
        """OGCD range of the real characteristic (max - min, dE00)."""
        return float(self.real.ogcd.max() - self.real.ogcd.min())

    @property
    def sim_range(self) -> float:
        """OGCD range of the simulated characteristic (dE00)."""
        return float(self.sim.ogcd.max() - self.sim.ogcd.min())

    def to_json(self) -> ViewpointReport:
        """JSON object of this viewpoint."""
        return {
            "viewpoint": list(self.viewpoint), "reference": self.reference,
            "lengths_mm": self.real.lengths_mm.tolist(),
            "real_ogcd": self.real.ogcd.tolist(), "sim_ogcd": self.sim.ogcd.tolist(),
            "sim_ogcd_stderr": (None if self.sim.ogcd_stderr is None
                                else self.sim.ogcd_stderr.tolist()),
            "real_lab": self.real_lab.tolist(), "sim_lab": self.sim_lab.tolist(),
            "frechet": self.frechet, "max_ogcd_error": self.max_error,
            "max_ogcd_error_length_mm": self.max_error_length_mm,
            "real_ogcd_range": self.real_range, "sim_ogcd_range": self.sim_range,
            "calibration": None if self.calibration is None else self.calibration.to_json(),
            "sim_seconds": self.sim_seconds,
        }


def compare_viewpoint(viewpoint: tuple[float, float, float], lengths_mm: NDArray,
                      real_ogcd: NDArray, sim_ogcd: NDArray, *, sim_stderr: NDArray | None = None,
                      real_lab: NDArray | None = None, sim_lab: NDArray | None = None,
                      reference: bool = False, sim_seconds: float = 0.0) -> ViewpointComparison:
    """The paper's metrics between a real and a simulated characteristic at common lengths."""
    real = Characteristic(lengths_mm, np.clip(real_ogcd, 0.0, None))
    sim = Characteristic(lengths_mm, np.clip(sim_ogcd, 0.0, None),
                         None if sim_stderr is None else floor_stderr(sim_stderr))
    err, at = max_error_at(real, sim)
    try:
        cal = calibration_check(real, sim)
    except CalibError:
        cal = None  # a flat characteristic has no table; the comparison still stands
    nan3 = np.full((len(lengths_mm), 3), np.nan)
    return ViewpointComparison(
        viewpoint=viewpoint, reference=reference, real=real, sim=sim,
        real_lab=nan3 if real_lab is None else np.asarray(real_lab),
        sim_lab=nan3 if sim_lab is None else np.asarray(sim_lab),
        frechet=frechet_characteristics(real, sim), max_error=err, max_error_length_mm=at,
        calibration=cal, sim_seconds=sim_seconds)


class Repeatability(TypedDict):
    """The repeatability test at one viewpoint (:func:`repeatability`)."""

    trials: int
    mean_std_ogcd: float
    std_ogcd: list[float]


class SimulationSettings(TypedDict):
    """How ``grassd validate`` simulated (the render settings, layouts, target error)."""

    samples: int
    replicates: int
    layouts: int
    max_bounces: int
    seed: int
    light_samples: int
    target_stderr: float | None


class CameraReport(TypedDict):
    """A :class:`CameraSignature` in JSON."""

    make: str
    model: str
    cfa: str
    white_level: int
    matrix: list[float]


class CorrectionReport(TypedDict):
    """The colour correction M in JSON: its matrix (3 x 3, or 3 x terms of a root-polynomial),
    its form, the checker's error with each patch predicted from the others (``mean_de00``,
    ``max_de00``) and the fitting residual (``fit_*``), dE00."""

    matrix: list[list[float]]
    form: str
    mean_de00: float
    max_de00: float
    fit_mean_de00: float
    fit_max_de00: float


class ValidationReport(TypedDict):
    """The JSON report of ``grassd validate`` (:meth:`ValidationResult.to_json`)."""

    capture: str
    chart: str
    camera: CameraReport
    white_balance: list[float]
    exposure: float
    ccm: CorrectionReport
    colour_chain: str
    reference_viewpoint: list[float]
    viewpoints: list[ViewpointReport]
    repeatability: dict[str, Repeatability]
    settings: SimulationSettings
    seconds: dict[str, float]


@dataclass(frozen=True)
class ValidationResult:
    """Everything ``grassd validate`` reports."""

    manifest: CaptureManifest
    ccm: ColourCorrection
    #: how the simulation was read (:mod:`grassd.daemon.offline.colour_chain`): the
    #: correction's form, or "camera" (the camera's sensitivities, no correction)
    chain: str
    real: RealCapture
    viewpoints: tuple[ViewpointComparison, ...]
    settings: SimulationSettings
    seconds: dict[str, float]
    repeatability: dict[str, Repeatability] = field(default_factory=dict)

    @property
    def reference(self) -> ViewpointComparison:
        """The reference viewpoint's comparison."""
        return next(v for v in self.viewpoints if v.reference)

    def to_json(self) -> ValidationReport:
        """The JSON report."""
        cam = self.real.camera
        loo_mean, loo_max = self.ccm.reported_de00
        return {
            "capture": str(self.manifest.root), "chart": self.manifest.chart,
            "camera": {"make": cam["make"], "model": cam["model"], "cfa": cam["cfa"],
                       "white_level": cam["white_level"], "matrix": list(cam["matrix"])},
            "white_balance": list(self.real.white_balance), "exposure": self.real.exposure,
            "ccm": {"matrix": self.ccm.matrix.tolist(), "form": self.ccm.form,
                    "mean_de00": loo_mean, "max_de00": loo_max,
                    "fit_mean_de00": self.ccm.mean_de00, "fit_max_de00": self.ccm.max_de00},
            "colour_chain": self.chain,
            "reference_viewpoint": list(self.reference.viewpoint),
            "viewpoints": [v.to_json() for v in self.viewpoints],
            "repeatability": self.repeatability,
            "settings": self.settings, "seconds": self.seconds,
        }


def repeatability(m: CaptureManifest, real: RealCapture) -> dict[str, Repeatability]:
    """The paper's repeatability test (section 4.1.1) wherever a viewpoint was measured in
    several trials at the same lengths: ``{label: {"trials": n, "mean_std_ogcd": x,
    "std_ogcd": [...]}}`` with x the mean over lengths of the sample standard deviation
    (ddof = 1) of the real OGCD across trials (paper: about 0.42 for its real pixel)."""
    groups: dict[tuple, list[int]] = {}
    for i, sr in enumerate(m.series):
        groups.setdefault((sr.viewpoint, tuple(sr.lengths_mm)), []).append(i)
    out: dict[str, Repeatability] = {}
    for idx in groups.values():
        if len(idx) < 2:
            continue
        std = np.stack([real.ogcd[i] for i in idx]).std(axis=0, ddof=1)
        out[m.series[idx[0]].label] = Repeatability(
            trials=len(idx), mean_std_ogcd=float(std.mean()), std_ogcd=std.tolist())
    return out


def measure_and_correct(m: CaptureManifest, chart: ReferenceChart,
                        progress: Callable[[str], None] | None = None
                        ) -> tuple[RealCapture, ColourCorrection, float]:
    """The real side of a capture (:func:`measure_real`), the colour correction M from the
    virtual to the real checker (the form of :data:`grassd.calib.ccm.CCM_FORMS` of least
    leave-one-out error, :func:`grassd.calib.ccm.select_ccm`), and the factor ``s`` that scales
    the white-card-normalised simulation before M (:func:`virtual_checker`)."""
    real = measure_real(m, chart, progress)
    virtual, s = virtual_checker(chart)
    return real, select_ccm(virtual, real.checker_rgb), s


def validate_capture(m: CaptureManifest, *, renderer: Renderer | None = None,
                     settings: RenderSettings | None = None,
                     target_stderr: float | None = None, lighting: Lighting | None = None,
                     arch: str = "cpu", layouts: int = 1,
                     progress: Callable[[str], None] | None = None) -> ValidationResult:
    """Measure the real characteristic of a capture, simulate the same scene, compare.

    ``renderer``: a :class:`grassd.sim.renderer.Renderer` (if None, one is created on backend
    ``arch`` after the photos were measured, so bad captures fail fast);
    ``settings``: :class:`grassd.sim.scene.RenderSettings`, its ``replicates`` per layout;
    ``layouts``: random tuft layouts the simulation averages, the pixel's ``layout_seed`` and
    the next ones, each with its own paths, as ``grassd fit`` averages and judges them
    (:func:`grassd.daemon.core.calibration.simulation.simulate_curve`; 1: the pixel's layout
    alone); ``lighting``: a prebuilt Lighting of ``m.light`` (built here if None). Raises
    :class:`ValidateError` where ``replicates x layouts`` exceeds what one render traces.
    """
    from grassd.daemon.core.calibration.simulation import simulate_curve
    from grassd.sim.scene import (
        MAX_REPLICATES,
        DisplaySpec,
        PixelSpec,
        RenderSettings,
        Viewpoint,
    )

    settings = settings or RenderSettings(samples=4096, replicates=8)
    if layouts < 1 or settings.replicates * layouts > MAX_REPLICATES:
        raise ValidateError(f"{settings.replicates} replicates x {layouts} layouts: give at "
                            f"least 1 layout and at most {MAX_REPLICATES} replicates in all")
    if m.sensitivities is not None and target_stderr is not None:
        raise ValidateError("a capture read through the camera's sensitivities is simulated "
                            "with fixed replicates: leave out the target standard error")
    t0 = time.perf_counter()
    chart = get_chart(m.chart)
    real, ccm, s = measure_and_correct(m, chart, progress)
    t1 = time.perf_counter()
    traced = replace(settings, replicates=settings.replicates * layouts)
    if progress:
        progress("building the lighting")
    lighting = lighting if lighting is not None else m.light.lighting()
    chain = simulation_chain(m.sensitivities, ccm, s, lighting, real.white_balance,
                             m.checker_photo, chart)
    if renderer is None:
        renderer = default_renderer(arch)
    pixel = PixelSpec(**m.pixel)
    ref = m.reference
    out = []
    curves: dict[tuple, tuple[NDArray, NDArray, NDArray, float]] = {}  # trials share one
    for i, series in enumerate(m.series):
        ts = time.perf_counter()
        key = (series.viewpoint, tuple(series.lengths_mm))
        if key not in curves:
            if progress:
                progress(f"simulating viewpoint {series.label}")
            vp = Viewpoint(*series.viewpoint)
            if isinstance(chain, CorrectedChain):
                c = simulate_curve(renderer, DisplaySpec(pixel), lighting, vp,
                                   series.lengths_mm, traced, ccm=chain.ccm,
                                   target_stderr=target_stderr, layouts=layouts)
                curves[key] = (c.ogcd, c.ogcd_stderr, c.lab, c.seconds.get("compile", 0.0))
            else:
                r = _chain_curve(renderer, pixel, lighting, vp, series.lengths_mm, settings,
                                 layouts, chain)
                curves[key] = (r.ogcd, r.ogcd_stderr, r.lab, 0.0)
        ogcd, stderr, lab, compile_s = curves[key]
        out.append(compare_viewpoint(series.viewpoint, series.lengths_mm, real.ogcd[i],
                                     ogcd, sim_stderr=stderr, real_lab=real.lab[i],
                                     sim_lab=lab, reference=series is ref,
                                     sim_seconds=time.perf_counter() - ts - compile_s))
    t2 = time.perf_counter()
    return ValidationResult(
        manifest=m, ccm=ccm, chain=chain.form, real=real, viewpoints=tuple(out),
        repeatability=repeatability(m, real),
        settings={"samples": settings.samples, "replicates": settings.replicates,
                  "layouts": layouts,
                  "max_bounces": settings.max_bounces, "seed": settings.seed,
                  "light_samples": settings.light_samples, "target_stderr": target_stderr},
        seconds={"measure": t1 - t0, "simulate": t2 - t1, "total": t2 - t0})


def _chain_curve(renderer: Renderer, pixel: PixelSpec, lighting: Lighting, viewpoint: Viewpoint,
                 lengths_mm: NDArray[np.float64], settings: RenderSettings, layouts: int,
                 chain: ColourChain) -> OGCDResult:
    """One viewpoint's simulated characteristic read through ``chain``: the albedo polynomial
    recorded for each of ``layouts`` tuft layouts (the pixel's ``layout_seed`` and the next
    ones, each with its own paths, as ``grassd fit`` records them), evaluated at the pixel's
    own materials; every layout's replicates are independent samples of the mean."""
    from grassd.daemon.core.calibration.simulation import layout_display, layout_seed
    from grassd.sim.scene import DisplaySpec

    samples = []
    for k in range(layouts):
        terms = renderer.albedo_terms(
            layout_display(DisplaySpec(pixel), k), lighting, viewpoint, lengths_mm,
            replace(settings, seed=layout_seed(settings.seed, k)), glossy=pixel.specular > 0)
        samples.append(chain.signal(terms.coefficients, pixel.albedo_linear, pixel.specular,
                                    terms.degree))
    return chain.ogcd(np.concatenate(samples))
