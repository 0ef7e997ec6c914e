"""The ``[measure]`` config section: the camera that photographs the display, and when.

::

    [measure]
    camera = "capture"              # "capture": the capture station's camera ([capture]);
                                    #   or the http:// URL of a second OSC camera
    username = ""                   # digest auth of a second camera (as [capture])
    password = ""
    interval_s = 0.0                # a measurement every this many seconds (604800 = weekly);
                                    #   0: only on request (grassd measure --now)
    start_hour = 10                 # scheduled measurements only between these local hours
    end_hour = 14                   #   (a time of steady light)
    steady_lux = 0.15               # largest relative lux change during a measurement
    patterns = 8                    # test-pattern lengths photographed, spread over the range
    settle_s = 30.0                 # longest wait for the motors to reach a pattern (s)
    pattern_timeout_s = 120.0       # the controllers' watchdog: back to content after this (s)
    tolerance_de00 = 2.0            # worst pixel pair at mid level (dE00) within tolerance
    iso = 100                       # fixed ISO of the shots
    samples = 1024                  # render samples per length for the pixel models
    layouts = 4                     # tuft layouts the pixel model averages (their spread
                                    #   weighs the fit: a real pixel is one layout)
    deadline_s = 3600.0             # the whole measurement, start to verdict (s, 10..86400):
                                    #   past it the display shows content and the run ends
    keep_photos = 4                 # the photos of the newest this many measurements are
                                    #   kept (1..1000); older ones are pruned

The colour checker, photographed once at set-up with this camera (``grassd measure setup``),
gives the camera's white balance, colour correction and exposure scale
(:mod:`grassd.daemon.measure.camera_chain`); a simulated site makes its own.
"""

from __future__ import annotations

from dataclasses import dataclass

from grassd.daemon.core.config import schema


@dataclass(frozen=True)
class MeasureConfig:
    """Validated ``[measure]`` section (see the module docstring; s, hours, lux, dE00)."""

    camera: str = "capture"
    username: str = ""
    password: str = ""
    interval_s: float = 0.0
    start_hour: int = 10
    end_hour: int = 14
    steady_lux: float = 0.15
    patterns: int = 8
    settle_s: float = 30.0
    pattern_timeout_s: float = 120.0
    tolerance_de00: float = 2.0
    iso: int = 100
    samples: int = 1024
    layouts: int = 4
    deadline_s: float = 3600.0
    keep_photos: int = 4

    def in_window(self, hour: int) -> bool:
        """Whether a scheduled measurement may start at local ``hour`` (0..23)."""
        if self.start_hour <= self.end_hour:
            return self.start_hour <= hour < self.end_hour
        return hour >= self.start_hour or hour < self.end_hour  # a window over midnight


def parse_measure(top: schema.Section, has_capture: bool) -> MeasureConfig | None:
    """Validate the ``[measure]`` table of the configuration ``top`` (None when absent);
    ``has_capture``: the configuration has a ``[capture]`` camera to borrow. Defaults are
    :class:`MeasureConfig`'s."""
    F = schema.Field
    m = top.opt_section("measure", schema.schema(
        MeasureConfig,
        camera=F(str, check=schema.non_empty), username=F(str), password=F(str),
        interval_s=F(float, check=lambda v: None if v == 0 or 3600 <= v <= 366 * 86400 else
                     "must be 0 (only on request) or 3600..31622400 s"),
        start_hour=F(int, check=schema.between(0, 23)),
        end_hour=F(int, check=schema.between(0, 24)),
        steady_lux=F(float, check=schema.between(0.01, 1.0)),
        patterns=F(int, check=schema.between(4, 32)),
        settle_s=F(float, check=schema.between(0.5, 600.0, " s")),
        pattern_timeout_s=F(float, check=schema.between(5.0, 6000.0, " s")),
        tolerance_de00=F(float, check=schema.positive),
        iso=F(int, check=schema.between(50, 12800)),
        samples=F(int, check=schema.between(64, 65536)),
        layouts=F(int, check=schema.between(1, 16)),
        deadline_s=F(float, check=schema.between(10.0, 86400.0, " s")),
        keep_photos=F(int, check=schema.between(1, 1000)),
    ))
    if m is None:
        return None
    camera = m.get_str("camera")
    if camera == "capture":
        if not has_capture:
            raise m.error("camera", '"capture" borrows the [capture] camera, '
                          "but there is no [capture] section; give the measuring camera's "
                          "http:// URL instead")
    elif not camera.startswith(("http://", "https://")):
        raise m.error("camera", 'must be "capture" or an http:// URL of an OSC '
                      "camera")
    return m.fill(MeasureConfig)
