"""A calibration run's report and metrics as JSON: what
:meth:`~grassd.daemon.core.calibration.result.CalibrationResult.report` and
:meth:`~grassd.daemon.core.calibration.result.CalibrationResult.metrics` give, written into the
run's report file and history and shown by ``grassd status``.

A centre-pixel run's report and metrics keep the form operators' scripts read since the first
release (:class:`CentreReport`, :class:`RunMetrics`); a display run's (from [[viewpoints]] or
[audience]) have their own (:class:`DisplayReport`, :class:`DisplayMetrics`). A run whose tables
include the display's measured correction also names that measurement (``display_correction``).

Units: lengths mm (tables um), OGCD and colour differences dE00 (CIEDE2000), seconds.
"""

from __future__ import annotations

from typing import Literal, NotRequired, Required, TypedDict


class GroupingSummary(TypedDict, total=False):
    """What grouping pixels by viewing geometry costs, on the groups checked (none checked:
    ``groups_checked`` alone): the largest angle from the representative (deg), OGCD
    difference (largest and mean), table error with the representative's table, with a table
    of its own and their difference, and (when decomposed) the geometry and pixel parts of
    the difference (dE00). A run's merges its viewers' (the largest of each ``max_``)."""

    groups_checked: Required[int]
    max_angle_deg: float
    max_ogcd_diff: float
    mean_ogcd_diff: float
    max_table_error: float
    max_own_table_error: float
    max_added_table_error: float
    max_geometry_diff: float
    max_pixel_diff: float


#: The keys of a :class:`GroupingSummary` that a run's merged summary keeps (the largest
#: over its viewers).
GROUPING_MAXIMA: tuple[Literal["max_angle_deg", "max_ogcd_diff", "max_table_error",
                               "max_own_table_error", "max_added_table_error",
                               "max_geometry_diff", "max_pixel_diff"], ...] = (
    "max_angle_deg", "max_ogcd_diff", "max_table_error", "max_own_table_error",
    "max_added_table_error", "max_geometry_diff", "max_pixel_diff")


class RegionSummary(TypedDict):
    """An [audience] run's region: its sampled ``eyes``, ground area (m^2), eye heights (cm,
    low and high) and the table's objective."""

    eyes: int
    area_m2: float
    h_cm: list[float]
    objective: str


class CcmMetrics(TypedDict):
    """The colour correction in the metrics: its source, its form (only with a correction)
    and the mean and largest error a report prints (dE00)."""

    ccm_source: str
    ccm_form: NotRequired[str]
    ccm_mean_de00: float | None
    ccm_max_de00: float | None


class RunMetrics(CcmMetrics):
    """Summary numbers every run's metrics hold (a centre-pixel run's all of them): R^2 and
    the largest deviation from linear OGCD (dE00) with linear lengths, the fit and the closed
    loop, their goals and whether they were met, the closed-loop rounds, the OGCD range and
    mean standard error, the largest step from the active tables (um) and wall times."""

    r2_before: float
    r2_after_fit: float
    r2_closed_loop: float | None
    r2_goal: float
    r2_goal_met: bool
    max_dev_de00: float | None
    max_dev_goal_de00: float
    max_dev_goal_met: bool
    rounds: int
    ogcd_range_de00: float
    mean_ogcd_stderr_de00: float | None
    max_step_from_last_um: int | None
    seconds: dict[str, float]
    display_correction: NotRequired[str]


class DisplayMetrics(RunMetrics):
    """A display run's metrics: its granularity and source, which check gave ``max_dev_de00``
    (the closed loop, or the fit without one), its table and controller counts, the fits'
    worst and mean deviation (dE00), the tables refined, and its grouping error (dE00, deg)
    and region summaries."""

    granularity: str
    table_source: str
    check: Literal["closed loop", "fit"]
    tables: int
    controllers: int
    max_fit_dev_de00: float
    mean_fit_dev_de00: float
    refined_tables: int
    grouping: GroupingSummary | None
    region: RegionSummary | None


class CcmReport(TypedDict):
    """The colour correction in the report: its source and form, how to apply it again
    (``method``, ``degree``, ``matrix``), its errors (dE00: reported, leave-one-out, fitting)
    and every candidate form's scores when the form was chosen."""

    source: str
    form: str
    method: str
    degree: int
    matrix: list[list[float]]
    mean_de00: float | None
    max_de00: float | None
    loo_mean_de00: float | None
    loo_max_de00: float | None
    fit_mean_de00: float | None
    fit_max_de00: float | None
    candidates: list[dict[str, str | float]]


class LoopReport(TypedDict):
    """One closed-loop round of a display run (per pixel group, at the checked levels)."""

    round: int
    levels: list[int]
    pixels: list[int]
    lengths_mm: list[list[float]]
    ogcd_de00: list[list[float]]
    ogcd_stderr_de00: list[list[float]]
    target_de00: list[list[float]]
    max_dev_de00: list[float]
    r2: list[float]


class LoopRoundSummary(TypedDict):
    """A display run's closed-loop round in brief: its worst deviation (dE00) and R^2."""

    round: int
    max_dev_de00: float
    r2_min: float


class ControllerTableReport(TypedDict):
    """One controller's table: its CRC as the controller reports it, shape and lengths (um;
    (256,) or (pixels, 256))."""

    table_crc: int
    shape: list[int]
    lengths_um: list[int] | list[list[int]]


class UnitReport(TypedDict):
    """One unit of a display run: its table (um), characteristic (mm, dE00) and errors."""

    name: str
    pixels: list[int]
    lengths_um: list[int]
    lengths_mm: list[float]
    ogcd_de00: list[float]
    ogcd_stderr_de00: list[float] | None
    max_error_de00: float
    mean_error_de00: float
    r2_before: float
    r2_after_fit: float
    ogcd_range_de00: float
    closed_loop_max_dev_de00: float | None
    refined_rounds: int
    closed_loop_r2: float | None


class DisplayReport(TypedDict):
    """A display run's report: the display-wide table, every controller's, the units behind
    them, the last closed-loop round and every round in brief, grouping and region
    summaries, the colour correction, the light's transport (``[simulation] transport``) and
    the lighting's notes."""

    granularity: str
    table_source: str
    display_shape: list[int]
    table_um: list[int]
    controller_tables: dict[str, ControllerTableReport]
    unit_of_pixel: list[int]
    units: list[UnitReport]
    closed_loop: LoopReport | None
    closed_loop_rounds: list[LoopRoundSummary]
    grouping: GroupingSummary | None
    region: RegionSummary | None
    ccm: CcmReport | None
    transport: str
    lighting_notes: list[str]
    display_correction: NotRequired[str]


class CharacteristicReport(TypedDict):
    """OGCD (dE00) against length (mm), with its standard errors when known."""

    lengths_mm: list[float]
    ogcd_de00: list[float]
    ogcd_stderr_de00: list[float] | None


class ViewpointCurveReport(TypedDict):
    """A centre-pixel run's curve from one viewpoint (cm, m, deg; its weight), the D50
    CIELAB at each length when known."""

    h_cm: float
    d_m: float
    theta_deg: float
    weight: float
    lengths_mm: list[float]
    ogcd_de00: list[float]
    ogcd_stderr_de00: list[float]
    seconds: float
    lab_d50: NotRequired[list[list[float]]]


class CentreLoopRound(TypedDict):
    """A centre-pixel run's closed-loop round: lengths (mm) and OGCD (dE00) at the checked
    levels against the target, the worst deviation and R^2."""

    round: int
    levels: list[int]
    lengths_mm: list[float]
    ogcd_de00: list[float]
    target_de00: list[float]
    max_dev_de00: float
    r2: float


class CentreReport(TypedDict):
    """A centre-pixel run's report: its table, pooled characteristic, per-viewpoint curves,
    closed-loop rounds, the colour correction, the light's transport and the lighting's
    notes."""

    table_um: list[int]
    characteristic: CharacteristicReport
    viewpoints: list[ViewpointCurveReport]
    closed_loop: list[CentreLoopRound]
    ccm: CcmReport | None
    transport: str
    lighting_notes: list[str]
    display_correction: NotRequired[str]
