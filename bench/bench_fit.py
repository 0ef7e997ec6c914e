"""``grassd fit`` on virtual captures of two pixels whose materials are known (pink grass
indoors, glossy splayed olive turf outdoors; :mod:`grassd.rigs.fit_worlds`), fitted from the
defaults. Two runs per pixel:

* the speed case: 3 viewpoints x 6 lengths, all fitted (the reference view, a
  steep one across the slits, which sees the base, and one along them, which sees the splay);
* the accuracy case of the tests: 4 viewpoints fitted, 1 held out. (With 2 viewpoints fitted
  the fit refuses: the yellow albedo's standard error exceeds its limit.)

Prints the fit's time, every recovered parameter against the truth (albedos as dE00), and the
held-out viewpoint's Frechet distance from the defaults, from the fit and from the true
materials (target: the fit at most 60 s on 2 cores; held-out Frechet 3x below the defaults'
and within 0.25 of the truth's)."""

from __future__ import annotations

import tempfile
from dataclasses import replace

from bench import ARCH, HDRI_DIR
from grassd.daemon.offline.fit import FitError, fit_capture
from grassd.daemon.offline.validate import default_renderer
from grassd.rigs.fit_worlds import (
    ALBEDOS,
    HELD_OUT,
    VIEWS,
    WORLDS,
    albedo_de00,
    capture_known_pixel,
    true_fields,
)


def _row(name: str, case: str, manifest, lighting, renderer, holdout: list) -> None:
    truth = WORLDS[name][0]
    try:
        fit = fit_capture(manifest, holdout=holdout, renderer=renderer, lighting=lighting)
    except FitError as exc:
        print(f"{name:6s} {case:22s} refused: {exc}")
        return
    known = fit_capture(replace(manifest, pixel=true_fields(name)), holdout=holdout,
                        params=(), renderer=renderer, lighting=lighting)
    fitted = len([v for v in fit.viewpoints if not v.held_out])
    judged = [(v, t) for v, t in zip(fit.viewpoints, known.viewpoints, strict=True)
              if v.held_out or not holdout]
    print(f"{name:6s} {case:22s} fitted {fitted} viewpoints in {fit.seconds:5.1f} s; Frechet "
          f"from the defaults -> fit (true materials) "
          + ("held out " if holdout else "")
          + "; ".join(f"{v.fitted.label} {v.start.frechet:.2f} -> {v.fitted.frechet:.2f} "
                      f"({t.fitted.frechet:.2f})" for v, t in judged))
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
    renderer = default_renderer(ARCH)
    print(f"grassd fit on Taichi's {ARCH} arch")
    for name in WORLDS:
        with tempfile.TemporaryDirectory() as tmp:
            manifest, lighting = capture_known_pixel(tmp, name, HDRI_DIR, renderer)
            three = replace(manifest, series=tuple(
                s for s in manifest.series if s.viewpoint in (VIEWS[0], VIEWS[1], VIEWS[3])))
            _row(name, "3 views x 6 lengths", three, lighting, renderer, [])
            _row(name, "5 views x 6 lengths", manifest, lighting, renderer, [HELD_OUT])


if __name__ == "__main__":
    main()
