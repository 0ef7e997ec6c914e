"""grassd fit against virtual captures of pixels whose materials are known: the real renderer
draws the "real" pixel (its own tuft layout), the virtual camera photographs it into DNGs, and
the fit must find its materials from the photos alone, starting from the defaults."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
from click.testing import CliRunner

from grassd.daemon.cli.main import main
from grassd.daemon.offline.fit import (
    FIT_PARAMS,
    PRIOR_STDERR,
    ContradictoryPhotosError,
    FitError,
    NotIdentifiableError,
    fit_capture,
    load_pixel_fields,
    parse_params,
    unseen_parameters,
)
from grassd.daemon.offline.validate import Series
from grassd.daemon.offline.virtual_capture import capture_world
from grassd.rigs.fit_worlds import (
    ALBEDOS,
    HELD_OUT,
    LENGTHS,
    PHOTO,
    VIEWS,
    WORLDS,
    albedo_de00,
    capture_known_pixel,
    true_fields,
)
from grassd.sim.light_input import LightInput
from grassd.sim.scene import PixelSpec


@pytest.fixture(scope="module")
def captures(tmp_path_factory, renderer, shared_hdri):
    """Photograph a world once per module: name -> (manifest, lighting)."""
    done: dict = {}

    def get(name: str):
        if name not in done:
            done[name] = capture_known_pixel(tmp_path_factory.mktemp(name), name,
                                             shared_hdri("forest").parent, renderer)
        return done[name]

    return get


@pytest.fixture(scope="module", params=list(WORLDS))
def world(request, captures, renderer):
    """A world photographed, fitted from the defaults, and judged with its true materials."""
    name = request.param
    manifest, lighting = captures(name)
    fitted = fit_capture(manifest, holdout=[HELD_OUT], renderer=renderer, lighting=lighting)
    known = fit_capture(replace(manifest, pixel=true_fields(name)), holdout=[HELD_OUT],
                        params=(), renderer=renderer, lighting=lighting)
    return {"name": name, "truth": WORLDS[name][0], "manifest": manifest,
            "lighting": lighting, "fit": fitted, "known": known}


@pytest.fixture(scope="module")
def pink(captures):
    """The pink world's capture (no fit): for the command line and bad input."""
    manifest, lighting = captures("pink")
    return {"manifest": manifest, "lighting": lighting}


#: Largest CIEDE2000 between a fitted and the true albedo, every albedo of both pixels. (The
#: olive pixel's base, hidden under the blades and seen next to a glossy lobe, follows the
#: fitted smoothness closely: its blue moves about 3 levels per 0.01 of smoothness, so the fit
#: refines the lobe's shape to 0.01 at the fitted splay; read off the coarse grid's 0.5 it was
#: 3.4 dE00 off.)
ALBEDO_DE00 = {(w, a): 2.0 for w in WORLDS for a in ALBEDOS}


def _held_out(result):
    return next(v for v in result.viewpoints if v.held_out)


@pytest.mark.long
def test_fit_recovers_the_albedos_and_the_splay(world):
    res, truth = world["fit"], world["truth"]
    assert set(res.pixel) == {"yellow_srgb", "green_srgb", "base_srgb", "specular",
                              "smoothness", "splay_deg"}
    assert set(res.stderr) == set(res.pixel)
    for name in ALBEDOS:
        de = albedo_de00(res.pixel[name], getattr(truth, name))
        assert de <= ALBEDO_DE00[world["name"], name], (name, res.pixel[name],
                                                         getattr(truth, name), de)
        # the defaults are far from the truth: a fit that did not run cannot pass
        assert albedo_de00(getattr(PixelSpec(), name), getattr(truth, name)) > 5.0
    assert abs(res.pixel["splay_deg"] - truth.splay_deg) <= 2.0, res.profile["splay_deg"]
    assert {0.0, 4.0, 8.0, 12.0, 16.0} <= {v for v, _ in res.profile["splay_deg"]}


@pytest.mark.long
def test_held_out_viewpoint_is_predicted_as_the_true_materials_predict_it(world):
    held, truth = _held_out(world["fit"]), _held_out(world["known"])
    assert held.viewpoint == HELD_OUT
    assert held.start.frechet >= 3.0 * held.fitted.frechet, (held.start.frechet,
                                                             held.fitted.frechet)
    assert held.fitted.frechet <= truth.fitted.frechet + 0.25, (held.fitted.frechet,
                                                                truth.fitted.frechet)


@pytest.mark.long
def test_the_glossy_lobe_is_found_where_there_is_one(world):
    res, truth = world["fit"], world["truth"]
    if truth.specular:
        assert abs(res.pixel["specular"] - truth.specular) <= 0.03, res.pixel
        assert res.stderr["specular"] > 0 and res.stderr["smoothness"] is not None
    else:
        assert res.pixel["specular"] <= 0.04, res.pixel


@pytest.mark.long
def test_standard_errors_cover_the_truth(world):
    """The photographed layout's accident is shared by every photo: the standard errors count
    it, so the truth lies within 3 of them."""
    res, truth = world["fit"], world["truth"]
    for name in ALBEDOS:
        err = np.abs(np.subtract(res.pixel[name], getattr(truth, name)))
        se = np.array(res.stderr[name])
        assert (se > 0).all() and (err <= 3 * se).all(), (name, err, se)
    assert abs(res.pixel["splay_deg"] - truth.splay_deg) <= 3 * res.stderr["splay_deg"]
    assert abs(res.pixel["specular"] - truth.specular) <= 3 * res.stderr["specular"]
    if truth.specular:  # the lobe's shape, refined: the hidden base's colour follows it
        assert abs(res.pixel["smoothness"] - truth.smoothness) <= 3 * res.stderr["smoothness"]
    assert res.dof > 0 and np.isfinite(res.chi2)


@pytest.mark.long
@pytest.mark.parametrize("name", list(WORLDS))
def test_two_fitted_views_give_what_they_determine_and_hold_the_rest(captures, renderer, name):
    """Two fitted views (a site with two benches) do not determine the hidden base or the
    splay: those are held at their prior (the [pixel] value, PRIOR_STDERR) and named in a
    note, while the rest is fitted and its standard errors still cover the truth (the fit
    refused the whole pixel before, naming the one parameter it could not see)."""
    manifest, lighting = captures(name)
    two = (VIEWS[0], VIEWS[2])
    res = fit_capture(manifest, holdout=[HELD_OUT, *(v for v in VIEWS if v not in two)],
                      renderer=renderer, lighting=lighting)
    truth = WORLDS[name][0]
    assert set(res.pixel) == set(FIT_PARAMS)
    held = [p for p in FIT_PARAMS if any(n.startswith(f"{p} held at its prior") for n in res.notes)]
    assert held, res.notes  # these views leave something to the prior
    for p in held:
        se = np.atleast_1d(res.stderr[p])
        # the prior's error, with what the splay's and the lobe's uncertainty add to it
        assert (se > 0).all() and np.isfinite(se).all(), (p, se)
        assert f"+- {PRIOR_STDERR[p]:g}" in next(n for n in res.notes if n.startswith(p))
    for p in ("yellow_srgb", "green_srgb"):  # the blades' colours, which both views see
        if p in held:
            continue
        err = np.abs(np.subtract(res.pixel[p], getattr(truth, p)))
        assert (err <= 3 * np.array(res.stderr[p])).all(), (p, err, res.stderr[p])
        print(f"{name} {p}: {albedo_de00(res.pixel[p], getattr(truth, p)):.2f} dE00 from the truth")


@pytest.mark.long
def test_cli_writes_reports_that_check_config_and_validate_accept(pink, tmp_path):
    root = pink["manifest"].root
    out = {k: tmp_path / f"fit.{k}" for k in ("json", "toml", "html")}
    r = CliRunner().invoke(main, ["fit", str(root), "--holdout", "150,1.2,60", "--params",
                                  ",".join(ALBEDOS), "--samples", "256", "-q",
                                  "--json", str(out["json"]), "--toml", str(out["toml"]),
                                  "--html", str(out["html"])])
    assert r.exit_code == 0, r.output
    report = json.loads(out["json"].read_text())
    assert set(report) >= {"pixel", "stderr", "viewpoints", "seconds"}
    assert list(report["pixel"]) == list(ALBEDOS) and len(report["stderr"]["green_srgb"]) == 3
    assert albedo_de00(report["pixel"]["green_srgb"], WORLDS["pink"][0].green_srgb) < 5.0
    held = [v for v in report["viewpoints"] if v["held_out"]]
    assert [v["viewpoint"] for v in held] == [list(HELD_OUT)]
    assert set(held[0]["frechet"]) == {"start", "fitted"} and "max_error" in held[0]
    assert "<img" in out["html"].read_text() and "held out" in out["html"].read_text()
    table = out["toml"].read_text()
    assert table.splitlines()[1] == "[display.pixel]" and "green_srgb = [" in table
    # pasted into the default config in place of its empty [display.pixel] table
    from importlib.resources import files

    default = files("grassd.daemon.core.config").joinpath("default.toml").read_text()
    head, _, tail = default.partition("[display.pixel]")
    config = tmp_path / "grassd.toml"
    config.write_text(head + table + tail.split("\n", 1)[1])
    r = CliRunner().invoke(main, ["check-config", "--config", str(config)])
    assert r.exit_code == 0, r.output
    assert load_pixel_fields(out["toml"])["green_srgb"] == tuple(report["pixel"]["green_srgb"])
    assert load_pixel_fields(out["json"])["green_srgb"] == tuple(report["pixel"]["green_srgb"])
    r = CliRunner().invoke(main, ["validate", str(root), "--pixel", str(out["json"]),
                                  "--samples", "256", "--replicates", "2", "-q"])
    assert r.exit_code == 0, r.output


def test_params_names_are_checked():
    assert parse_params("splay_deg,green_srgb") == ("green_srgb", "splay_deg")
    with pytest.raises(FitError, match="unknown metallic"):
        parse_params("green_srgb,metallic")


def _manifest_of(series, tmp_path):
    """A manifest whose photos exist nowhere: the checks below run before any photo is read."""
    from grassd.daemon.offline.validate import CaptureManifest

    return CaptureManifest(root=tmp_path, light=LightInput(tmp_path / "env.exr", 500.0),
                           checker_photo=tmp_path / "checker.dng",
                           checker_corners=((0, 0), (1, 0), (1, 1), (0, 1)),
                           series=tuple(series))


def _series(viewpoint, lengths):
    from grassd.daemon.offline.validate import Photo

    quad = ((0, 0), (1, 0), (1, 1), (0, 1))
    return Series(viewpoint, tuple(Photo(f"{x}.dng", x, quad) for x in lengths))


def test_what_the_views_or_lengths_cannot_show_is_named_and_held(tmp_path):
    """One viewpoint cannot show gloss, short grass cannot show splay: those are held at their
    prior (with what to photograph to fit them); a fit left with nothing to determine, or
    with no viewpoint to fit, is refused."""
    start = PixelSpec()
    one_view = _manifest_of([_series(VIEWS[0], list(LENGTHS))], tmp_path)
    unseen = unseen_parameters(one_view, [0], FIT_PARAMS, start)
    assert sorted(unseen) == ["smoothness", "specular"]
    assert "photograph at least 2 viewpoints" in unseen["specular"]
    short = _manifest_of([_series(v, [0.0, 2.0, 4.0]) for v in VIEWS[:2]], tmp_path)
    unseen = unseen_parameters(short, [0, 1], FIT_PARAMS, start)
    assert list(unseen) == ["splay_deg"] and "4 mm" in unseen["splay_deg"]
    with pytest.raises(NotIdentifiableError, match="determine none of specular, smoothness"):
        fit_capture(one_view, params=["specular", "smoothness"])
    with pytest.raises(NotIdentifiableError, match="every viewpoint is held out"):
        fit_capture(one_view, holdout=[VIEWS[0]])
    with pytest.raises(FitError, match="not a viewpoint of the capture"):
        fit_capture(one_view, holdout=[(1.0, 1.0, 1.0)])


@pytest.mark.long
def test_one_view_fits_the_albedos_and_holds_the_gloss(captures, renderer):
    """From one viewpoint the albedos are fitted and the glossy lobe held at its prior, with a
    note saying what to photograph (it was refused before)."""
    manifest, lighting = captures("pink")
    res = fit_capture(manifest, holdout=[HELD_OUT, *VIEWS[1:]], renderer=renderer,
                      lighting=lighting)
    assert set(res.pixel) == set(FIT_PARAMS)
    assert any(n.startswith("specular held at its prior") and "2 viewpoints" in n
               for n in res.notes), res.notes
    truth = WORLDS["pink"][0]
    print(f"pink from one view: green {albedo_de00(res.pixel['green_srgb'], truth.green_srgb):.2f}"
          f" dE00 from the truth")
    assert albedo_de00(res.pixel["green_srgb"], truth.green_srgb) < 5.0


@pytest.mark.long
def test_photos_of_two_different_pixels_contradict_each_other(pink, renderer, tmp_path):
    """One viewpoint photographed on the pink pixel, another on a default one: no materials
    make both agree."""
    other = capture_world(tmp_path, pink["manifest"].light, [VIEWS[1]], list(LENGTHS),
                          real_pixel=PixelSpec(layout_seed=101), renderer=renderer,
                          lighting=pink["lighting"], **PHOTO)
    mixed = replace(pink["manifest"], series=(pink["manifest"].series[0], other.series[0]))
    with pytest.raises(ContradictoryPhotosError, match="median .* dE00"):
        fit_capture(mixed, params=ALBEDOS, renderer=renderer, lighting=pink["lighting"])
