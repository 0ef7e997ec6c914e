"""``grassd fit`` on virtual captures of two pixels whose materials are known (pink grass
indoors, glossy splayed olive turf outdoors; :mod:`bench.fit_worlds`), fitted from the
defaults. Two runs per pixel:

* the speed case of issue #28: 3 viewpoints x 6 lengths, 2 fitted (a steep view across the
  slits, which sees the base, and one along them, which sees the splay) and 1 held out;
* the accuracy case of the tests: 4 viewpoints fitted, 1 held out.

Prints the fit's time, every recovered parameter against the truth (albedos as dE00), and the
held-out viewpoint's Frechet distance from the defaults, from the fit and from the true
materials (target: the fit at most 60 s on 2 cores; held-out Frechet 3x below the defaults'
and within 0.25 of the truth's)."""

from __future__ import annotations

import tempfile
from dataclasses import replace
from pathlib import Path

from bench.fit_worlds import (
    ALBEDOS,
    HELD_OUT,
    VIEWS,
    WORLDS,
    albedo_de00,
    capture_known_pixel,
    true_fields,
)
from grassd.daemon.offline.fit import FitError, fit_capture
from grassd.daemon.offline.validate import default_renderer

HDRI_DIR = Path(__file__).resolve().parents[1].parent / "shared" / "hdri"


def _row(name: str, case: str, manifest, lighting, renderer) -> None:
    truth = WORLDS[name][0]
    try:
        fit = fit_capture(manifest, holdout=[HELD_OUT], renderer=renderer, lighting=lighting)
    except FitError as exc:
        print(f"{name:6s} {case:22s} refused: {exc}")
        return
    known = fit_capture(replace(manifest, pixel=true_fields(name)), holdout=[HELD_OUT],
                        params=(), renderer=renderer, lighting=lighting)
    held = next(v for v in fit.viewpoints if v.held_out)
    held_true = next(v for v in known.viewpoints if v.held_out)
    fitted = len([v for v in fit.viewpoints if not v.held_out])
    print(f"{name:6s} {case:22s} fitted {fitted} viewpoints in {fit.seconds:5.1f} s; held out "
          f"{HELD_OUT}: Frechet defaults {held.start.frechet:.2f} -> fit "
          f"{held.fitted.frechet:.2f} (true materials {held_true.fitted.frechet:.2f})")
    for k in ALBEDOS:
        got = fit.pixel[k]
        print(f"    {k:12s} {', '.join(f'{c:5.1f}' for c in got)} +- "
              f"{', '.join(f'{c:.1f}' for c in fit.stderr[k])}  truth "
              f"{', '.join(f'{c:g}' for c in getattr(truth, k))}: dE00 "
              f"{albedo_de00(got, getattr(truth, k)):.2f}")
    for k in ("specular", "smoothness", "splay_deg"):
        se = fit.stderr.get(k)
        print(f"    {k:12s} {fit.pixel[k]:g} +- {'-' if se is None else f'{se:g}'}  truth "
              f"{getattr(truth, k):g}")
    for note in fit.notes:
        print(f"    note: {note}")


def main() -> None:
    if not HDRI_DIR.is_dir():
        print(f"skipped: {HDRI_DIR} not present")
        return
    renderer = default_renderer()
    for name in WORLDS:
        with tempfile.TemporaryDirectory() as tmp:
            manifest, lighting = capture_known_pixel(tmp, name, HDRI_DIR, renderer)
            three = replace(manifest, series=tuple(
                s for s in manifest.series if s.viewpoint in (VIEWS[1], VIEWS[3], HELD_OUT)))
            _row(name, "3 views x 6 lengths", three, lighting, renderer)
            _row(name, "5 views x 6 lengths", manifest, lighting, renderer)


if __name__ == "__main__":
    main()
