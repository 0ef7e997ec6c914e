"""The ``[capture]`` config section: the capture station's camera, bracket and schedule.

::

    [capture]
    camera = "http://192.168.1.1"   # the OSC camera's base URL
    username = ""                   # digest auth (THETA in Wi-Fi client mode: THETAYN..., and
    password = ""                   #   the serial digits); empty: no authentication
    interval_s = 1800.0             # one capture every this many seconds (daemon's own loop)
    shots = 9                       # exposures in the bracket
    ev_step = 2.0                   # EV between neighbouring exposures
    iso = 100                       # fixed ISO
    aperture = 0.0                  # f-number to set (THETA Z1: 2.1, 3.5, 5.6); 0 = leave it
    white_balance = "daylight"      # fixed OSC whiteBalance
    shutter_s = 0.0                 # centre shutter (s); 0 = meter it with one shot
    file_format = "jpeg"            # or "raw+" (THETA Z1: JPEG + DNG, merged linearly)
    max_shutter_s = 1.0             # longest shutter used (s)
    timeout_s = 10.0                # per HTTP read (s): connect, and each wait for data
    request_deadline_s = 30.0       # whole JSON request, start to last byte (s)
    download_deadline_s = 300.0     # whole shot download, start to last byte (s)
    min_download_rate = 16384       # a download slower than this (bytes/s, 0..1e8; 0 = no
    min_download_window_s = 10.0    #   limit) over this window (s, 1..300) is cut (curl's
                                    #   --speed-limit / --speed-time)
    max_json_bytes = 1048576        # largest JSON answer accepted (bytes)
    max_download_bytes = 134217728  # largest shot file accepted (bytes)
    command_timeout_s = 120.0       # per camera command until done (s)
    retries = 3                     # attempts after a failed capture, with backoff
    retry_s = 10.0                  # first backoff (s), doubling
    response_max_age_days = 30.0    # the cached camera response is recovered again when older
    shaded_unit = 0                 # Modbus unit of a second, shaded lux sensor (0 = none) on
    shaded_port = 0                 #   [light.modbus]'s link (TCP port 0 = the same port)

Lux comes from ``[light.modbus]`` (read right after the bracket); with ``shaded_unit`` the
reading of that shaded sensor is the ambient lux and the difference is the sun's.

The camera and anyone on its network are not trusted: the client follows no redirect, reads no
answer past its byte cap, and ends every request at its deadline however slowly the bytes come
(:mod:`grassd.daemon.camera.client`). OSC answers are a few kB (a THETA's ``_getMetadata``
EXIF, the largest, about 5 kB); a THETA Z1 DNG is about 50 MB and its JPEG about 10 MB, which a
weak 2 Mbit/s link brings in about 200 s.
"""

from __future__ import annotations

from dataclasses import dataclass

from grassd.daemon.core.config import schema


@dataclass(frozen=True)
class CaptureConfig:
    """Validated ``[capture]`` section (see the module docstring; seconds, EV, ISO)."""

    camera: str
    username: str = ""
    password: str = ""
    interval_s: float = 1800.0
    shots: int = 9
    ev_step: float = 2.0
    iso: int = 100
    aperture: float = 0.0
    white_balance: str = "daylight"
    shutter_s: float = 0.0
    max_shutter_s: float = 1.0
    file_format: str = "jpeg"
    timeout_s: float = 10.0
    request_deadline_s: float = 30.0
    download_deadline_s: float = 300.0
    min_download_rate: int = 16384
    min_download_window_s: float = 10.0
    max_json_bytes: int = 1 << 20
    max_download_bytes: int = 128 << 20
    command_timeout_s: float = 120.0
    retries: int = 3
    retry_s: float = 10.0
    response_max_age_days: float = 30.0
    shaded_unit: int = 0
    shaded_port: int = 0


def parse_capture(top: schema.Section) -> CaptureConfig | None:
    """Validate the ``[capture]`` table (None when absent) of the configuration ``top`` being
    read (errors name the key and line); defaults are :class:`CaptureConfig`'s."""
    F = schema.Field
    c = top.opt_section("capture", schema.schema(
        CaptureConfig,
        camera=F(str, check=schema.non_empty), username=F(str), password=F(str),
        interval_s=F(float, check=schema.between(10.0, 7 * 86400.0, " s")),
        shots=F(int, check=schema.between(3, 15)),
        ev_step=F(float, check=schema.between(0.5, 4.0, " EV")),
        iso=F(int, check=schema.between(50, 12800)),
        aperture=F(float, check=schema.between(0.0, 32.0)),
        white_balance=F(str, check=schema.one_of(
            "daylight", "shade", "cloudy-daylight", "incandescent", "fluorescent", "auto")),
        shutter_s=F(float, check=schema.between(0.0, 60.0, " s")),
        max_shutter_s=F(float, check=schema.between(1e-4, 60.0, " s")),
        file_format=F(str, check=schema.one_of("jpeg", "raw+")),
        timeout_s=F(float, check=schema.positive),
        request_deadline_s=F(float, check=schema.positive),
        download_deadline_s=F(float, check=schema.positive),
        min_download_rate=F(int, check=schema.between(0, 100_000_000, " bytes/s")),
        min_download_window_s=F(float, check=schema.between(1.0, 300.0, " s")),
        max_json_bytes=F(int, check=schema.between(4096, 1 << 30, " bytes")),
        max_download_bytes=F(int, check=schema.between(1 << 20, 1 << 34, " bytes")),
        command_timeout_s=F(float, check=schema.positive),
        retries=F(int, check=schema.between(0, 20)),
        retry_s=F(float, check=schema.between(0.0, 3600.0, " s")),
        response_max_age_days=F(float, check=schema.positive),
        shaded_unit=F(int, check=schema.between(0, 247)),
        shaded_port=F(int, check=schema.between(0, 65535)),
    ))
    if c is None:
        return None
    if not c.get_str("camera").startswith(("http://", "https://")):
        raise c.error("camera", "must be an http:// URL of the OSC camera "
                      "(e.g. http://192.168.1.1)")
    return c.fill(CaptureConfig)
