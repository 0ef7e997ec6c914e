"""``grassd measure`` in a world it did not render (:mod:`grassd.rigs.spectral_display`): the
embedded default config's 4 x 8 display, its pixels varied as the secret file says and each
with a tuft layout of its own, rendered by Mitsuba's spectral path tracer and photographed
through the Nikon D5100's spectral sensitivities; the checker of the set-up shot is the
ColorChecker's measured spectra under the same light.

The measurement recovers the hidden offsets and gains from the photos, and its correction
leaves the display, as the CIE observer sees it from the camera, within 0.5 dE00 (worst pixel
pair at mid level) of what the true variation, corrected the same way, would give.
docs/measure.md ("In a world grassd did not render") has the figures: the green gains'
correlation is about 0.93 since the fit knows how much of each quad is its neighbours' grass
(0.81 without)."""

from __future__ import annotations

from pathlib import Path

import pytest

from grassd.daemon.core.calibration.variation import load_variation

pytest.importorskip("mitsuba")
pytestmark = [pytest.mark.long, pytest.mark.slow, pytest.mark.timeout(1800)]

SECRET = Path(__file__).resolve().parents[2] / "data" / "measure" / "secret_variation.toml"


def test_measure_corrects_a_display_it_did_not_render_as_well_as_the_truth_would(tmp_path):
    from grassd.rigs.spectral_display import measure_spectral_world

    m = measure_spectral_world(tmp_path, load_variation(SECRET, 32))
    r, seen = m.correlation, m.worst_pair
    print(f"correlation with the truth {r}; the observer's worst pair {seen}; the camera's "
          f"{m.report['uniformity']['before']:.2f} -> {m.report['uniformity']['after']:.2f}; "
          f"checker leave-one-out {m.checker_de00}")  # -s shows the figures
    assert r["length_offset_mm"] >= 0.9 and r["yellow_gain"] >= 0.8, r
    assert r["green_gain"] >= 0.88, r
    assert seen["measured"] <= seen["truth"] + 0.5, seen
    assert seen["measured"] * 3.0 <= seen["before"], seen
    assert m.report["tables"]["status"] == "ok" and all(m.report["tables"]["pushed"])
