"""The studio's wire format towards the page: what ``GET /api/state`` and the uploads answer,
and the messages the WebSocket streams while a condition's views refine (lengths in mm, OGCD
and its standard errors in CIEDE2000, colours as 8-bit sRGB, images as PNG data URLs).

Every streamed message has a ``type``; the server adds the ``id`` of the page's input it
answers, the session ``ms``, the milliseconds since the job began. The order they come in is
:mod:`grassd.daemon.studio.session`'s.
"""

from __future__ import annotations

from typing import Literal, NotRequired, TypedDict


class _Stamped(TypedDict, total=False):
    """What every streamed message carries besides its own fields: the page's input ``id``
    (the server's) and ``ms`` since the job began (the session's)."""

    id: int
    ms: float


class SunPosition(TypedDict):
    """Where the lighting put the sun: compass azimuth and elevation, deg."""

    azimuth_deg: float
    elevation_deg: float


class LightMessage(_Stamped):
    """The condition's light: the lighting's notes, its sun (None: no sun) and the radiance
    of a white lying flat under it (linear Rec.709, nits)."""

    type: Literal["light"]
    notes: list[str]
    sun: SunPosition | None
    white_nits: list[float]


class ImageMessage(_Stamped):
    """An image of the pixel (``type`` "pixel", or "pinned" for B's): ``width`` pixels wide,
    ``spp`` paths per pixel; ``final`` once refined to its passes (the first image has
    none)."""

    type: Literal["pixel", "pinned"]
    image: str
    width: int
    spp: int
    final: NotRequired[bool]


class CurveMessage(_Stamped):
    """A characteristic: per length, its OGCD and standard error, the simulated pixel's colour
    (``srgb``, and ``lab_d50`` unrounded), with the replicates so far, the largest standard
    error, whether that is within the target, and whether it was ``kept`` from an earlier
    input."""

    type: Literal["curve"]
    lengths_mm: list[float]
    ogcd: list[float]
    ogcd_stderr: list[float]
    srgb: list[list[int]]
    lab_d50: list[list[float]]
    replicates: int
    max_stderr: float
    converged: bool
    kept: bool


class TableView(TypedDict):
    """An 8-bit table (``source`` "live" or "active") of 256 lengths and the OGCD it reaches
    per level, with the OGCD of a table linear in level, R^2 before and after, and the largest
    level error."""

    source: str
    lengths_mm: list[float]
    achieved_ogcd: list[float]
    uncalibrated_ogcd: list[float]
    r2_before: float
    r2_after: float
    max_level_error: float


class TableMessage(TableView, _Stamped):
    """The condition's table."""

    type: Literal["table"]


class NoTableMessage(_Stamped):
    """Why the condition has no table (its characteristic has no monotone fit)."""

    type: Literal["table"]
    error: str | None


class ContrastView(TypedDict):
    """What a content designer has to work with from one eye
    (:func:`~grassd.daemon.studio.views.contrast_view`)."""

    ogcd_range: float
    jnd_de00: float
    step_de00: float
    distinct_levels: int
    min_visible_step_levels: int


class ContrastMessage(ContrastView, _Stamped):
    """The condition's contrast."""

    type: Literal["contrast"]


class DisplayMessage(_Stamped):
    """The display showing the uploaded picture: its image, the levels (rows x cols), the
    ``[content] map`` used and the colours mapped onto (None unless "nearest_de00")."""

    type: Literal["display"]
    image: str
    levels: list[list[int]]
    map: str
    colours: str | None


class AudiencePlace(TypedDict):
    """A place of the audience map (m from the display's centre): its OGCD range, that range's
    standard error, and whether it keeps too little of the eye's."""

    x: float
    y: float
    range: float
    stderr: float
    warn: bool


class AudienceMessage(_Stamped):
    """The audience map: places ``step_m`` apart at the eye's height ``h_cm``, the eye's own
    OGCD range, how many places are warned of, and the contrast loss that warns."""

    type: Literal["audience"]
    step_m: float
    eye_range: float
    h_cm: float
    places: list[AudiencePlace]
    warned: int
    loss: float


class PinnedMessage(_Stamped):
    """The condition pinned as B: its characteristic and OGCD range (none without a monotone
    fit)."""

    type: Literal["pinned"]
    curve: CurveMessage
    ogcd_range: NotRequired[float]


class PinnedErrorMessage(_Stamped):
    """Why B cannot be computed (A goes on)."""

    type: Literal["pinned"]
    error: str
    final: bool


class DoneMessage(_Stamped):
    """Every view of the condition is sent."""

    type: Literal["done"]


class ErrorMessage(_Stamped):
    """Why the page's input (or the studio) failed."""

    type: Literal["error"]
    message: str


#: A message the WebSocket streams to the page.
PageMessage = (LightMessage | ImageMessage | CurveMessage | TableMessage | NoTableMessage
               | ContrastMessage | DisplayMessage | AudienceMessage | PinnedMessage
               | PinnedErrorMessage | DoneMessage | ErrorMessage)


class LightDescription(TypedDict):
    """A light source as the page lists it (lux, compass deg; ``taken``: ISO 8601)."""

    name: str
    label: str
    ambient_lux: float | None
    sun_lux: float | None
    sun_azimuth_deg: float | None
    sun_elevation_deg: float | None
    taken: str | None


class Materials(TypedDict):
    """A pixel's materials as the page shows them: where they come from, splay (deg), gloss
    and the 8-bit sRGB albedos."""

    source: str
    splay_deg: float
    specular: float
    smoothness: float
    green_srgb: list[float]
    yellow_srgb: list[float]
    base_srgb: list[float]


class PixelState(Materials):
    """The pixel the conditions default to (its materials), and every pixel they may choose."""

    default: str
    choices: dict[str, Materials]


class DisplayState(TypedDict):
    """The display: rows x cols pixels at ``pitch_mm``, the longest green length (mm)."""

    rows: int
    cols: int
    pitch_mm: float
    green_max_mm: float


class SiteState(TypedDict):
    """Where the display stands (deg) and its time zone."""

    latitude: float
    longitude: float
    timezone: str


class TablesState(TypedDict):
    """Whether the studio has the daemon's active table."""

    active: bool


class StudioState(TypedDict):
    """What the page draws its inputs from (``GET /api/state``, the server adds its
    simulator's)."""

    ready: bool
    arch: str
    display: DisplayState
    site: SiteState
    viewpoints: list[list[float]]
    region: list[list[float]]
    region_is_default: bool
    lights: list[LightDescription]
    light: str
    pixel: PixelState
    tables: TablesState
    lengths_mm: list[float]
    target_stderr: float
    jnd_de00: float
    contrast_loss: float


class CharacteristicAnswer(TypedDict):
    """What ``POST /api/characteristic`` answers: per length (mm) the OGCD and its standard
    error, the replicates and the seconds the request took."""

    lengths_mm: list[float]
    ogcd: list[float]
    ogcd_stderr: list[float]
    replicates: int
    seconds: float


class PictureUpload(TypedDict):
    """An uploaded picture: its id for the conditions and its colours, one 8-bit sRGB colour per
    display pixel (rows x cols x 3)."""

    image: str
    rows: int
    cols: int
    rgb: list[list[list[int]]]
