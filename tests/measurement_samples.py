"""Measurement reports as ``grassd measure`` writes them (a successful and a failed one), for
the report and status-page tests."""

from __future__ import annotations


def ok_report(mid: str = "20261127T235000Z", *, green: float = 1.0, yellow: float = 1.0,
              offset: float = 0.0, after: float = 0.8, n: int = 6,
              shape: list[int] | None = None) -> dict:
    """A successful report shaped as run._report and job.measure_with make it: ``n`` pixels
    with gains spread about ``green`` / ``yellow`` and offsets about ``offset``."""
    lengths = [1.0, 7.0, 13.0, 19.0]
    pixels = [{"index": i, "length_offset_mm": offset + 0.1 * (i - n / 2),
               "green_gain": green + 0.01 * (i % 3 - 1), "yellow_gain": yellow - 0.01 * (i % 2),
               "rms_lab": 0.4 + 0.01 * i, "rms_lab_model": 1.5 + 0.1 * i} for i in range(n)]
    measured = [[0.0, 3.0 + 0.1 * i, 6.0 + 0.2 * i, 9.0] for i in range(n)]
    predicted = [[0.0, 3.0, 6.0, 9.0] for _ in range(n)]
    fitted = [[0.0, 3.0 + 0.09 * i, 6.0 + 0.19 * i, 9.0] for i in range(n)]
    detail = {"worst_pair_de00": 3.1, "worst_pair": [0, n - 1],
              "ogcd_spread_de00": [0.0, 0.5, 0.7, 0.6, 0.4],
              "mean_ogcd_de00": [0.0, 4.0, 8.0, 12.0, 16.0]}
    rep = {
        "measurement": mid, "trigger": "request", "started_at": f"{mid[:4]}-{mid[4:6]}-"
        f"{mid[6:8]}T{mid[9:11]}:{mid[11:13]}:{mid[13:15]}+00:00",
        "finished_at": "2026-11-28T00:20:00+00:00", "status": "ok",
        "camera": {"url": "http://192.168.1.1", "position_m": [0.1, -2.5, 1.6],
                   "rms_deg": 0.012, "viewpoint": {"h_cm": 160.0, "d_m": 2.5,
                                                   "theta_deg": 2.3}},
        "light": {"hdri": "/srv/inbox/b1/sky.exr", "lux": [2500.0, 2510.0, 2490.0]},
        "patterns_mm": lengths,
        "pixels": pixels,
        "characteristic": {"lengths_mm": lengths, "measured_ogcd": measured,
                           "predicted_ogcd": predicted, "fitted_ogcd": fitted,
                           "max_error_predicted_de00": 1.0, "max_error_fitted_de00": 0.05},
        "uniformity": {"level": 128, "levels": [0, 64, 128, 192, 255], "before": 3.1,
                       "after": after, "improvement": 3.1 / after,
                       "before_detail": detail, "after_detail": {**detail,
                                                                 "worst_pair_de00": after}},
        "verdict": {"state": "within tolerance" if after <= 1.0 else "recalibrate",
                    "tolerance_de00": 1.0,
                    "reason": f"worst pixel pair {after:.2f} dE00 after correction (before "
                              "3.10), tolerance 1"},
        "tables": {"granularity": "pixel", "nominal_source": "renderer", "run_id": 7,
                   "status": "ok", "pushed": [True, True]},
        "seconds": {"calibrate": 30.0, "photos_before": 120.0, "analyse_and_after": 200.0,
                    "total": 350.0},
    }
    if shape is not None:
        rep["shape"] = shape
    return rep


def failed_report(mid: str = "20261128T010000Z", error: str = "camera unreachable") -> dict:
    return {"measurement": mid, "trigger": "request", "started_at": "2026-11-28T01:00:00+00:00",
            "finished_at": "2026-11-28T01:00:05+00:00", "status": "failed", "error": error}
