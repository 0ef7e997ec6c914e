"""Colour-space conventions: D50 Lab white, Bradford (not CAT02), LibRaw agreement, exposure."""

from __future__ import annotations

import colour
import numpy as np
import pytest

from grassd.calib import colour_spaces as cs
from grassd.calib.charts import colorchecker_classic
from grassd.calib.errors import ExposureError, NegativeValueError, UnknownMethodError
from grassd.calib.exposure import exposure_matrix, normalise_exposure

# LibRaw 0.21 src/utils/... `prophoto_rgb` (sRGB D65 -> ProPhoto D50, Bradford), as printed there.
LIBRAW_PROPHOTO_RGB = np.array(
    [
        [0.529317, 0.330092, 0.140588],
        [0.098368, 0.873465, 0.028169],
        [0.016879, 0.117663, 0.865457],
    ]
)


def test_whites_and_normalisation():
    np.testing.assert_allclose(cs.WHITE_D50_XYZ, [0.9642, 1.0, 0.8249], atol=1e-12)
    np.testing.assert_allclose(cs.WHITE_D65_XY, [0.3127, 0.3290], atol=1e-12)
    np.testing.assert_allclose(cs.WHITE_D50_XY, [0.3457, 0.3585], atol=1e-4)
    # perfect white has Y = 1 and Lab (100, 0, 0) in both spaces
    assert cs.luminance([1, 1, 1], "prophoto") == pytest.approx(1.0)
    assert cs.luminance([1, 1, 1], "rec709") == pytest.approx(1.0)
    np.testing.assert_allclose(cs.prophoto_to_lab([1, 1, 1]), [100, 0, 0], atol=1e-9)
    np.testing.assert_allclose(cs.rec709_to_prophoto([1, 1, 1]), [1, 1, 1], atol=1e-12)


def test_lab_white_is_d50_not_colour_science_default_d65():
    xyz = cs.prophoto_to_xyz([0.4, 0.4, 0.4])
    ours = cs.xyz_to_lab(xyz)
    d65_default = colour.XYZ_to_Lab(xyz)  # colour-science's default illuminant (D65)
    assert abs(ours[1]) < 1e-9 and abs(ours[2]) < 1e-9  # a neutral stays neutral
    assert np.hypot(d65_default[1], d65_default[2]) > 5.0  # the trap we avoid


def test_adaptation_is_bradford_and_differs_from_cat02():
    pp = colour.RGB_COLOURSPACES["ProPhoto RGB"]
    srgb = colour.RGB_COLOURSPACES["ITU-R BT.709"]
    bradford = colour.matrix_RGB_to_RGB(srgb, pp, chromatic_adaptation_transform="Bradford")
    cat02 = colour.matrix_RGB_to_RGB(srgb, pp)  # colour-science's default: CAT02
    # colour-science builds its matrix from the rounded xy (0.3457, 0.3585); ours from the
    # ProPhoto white XYZ (0.9642, 1, 0.8249) exactly, which is what LibRaw does: <= 3e-4 apart.
    np.testing.assert_allclose(cs.M_REC709_TO_PROPHOTO, bradford, atol=3e-4)
    assert np.abs(cs.M_REC709_TO_PROPHOTO - cat02).max() > 3e-3
    # On a ColorChecker, the two adaptations differ by a visible amount (about 0.6 dE00).
    rec = cs.prophoto_to_rec709(colorchecker_classic().prophoto())
    de = colour.delta_E(
        cs.prophoto_to_lab(rec @ cs.M_REC709_TO_PROPHOTO.T), cs.prophoto_to_lab(rec @ cat02.T)
    )
    assert 0.2 < de.max() < 1.5


def test_rec709_to_prophoto_matches_libraw_matrix():
    np.testing.assert_allclose(cs.M_REC709_TO_PROPHOTO, LIBRAW_PROPHOTO_RGB, atol=1e-4)


def test_round_trips():
    rng = np.random.default_rng(3)
    rgb = rng.uniform(0, 1, (100, 3))
    np.testing.assert_allclose(cs.prophoto_to_rec709(cs.rec709_to_prophoto(rgb)), rgb, atol=1e-12)
    np.testing.assert_allclose(cs.xyz_to_rec709(cs.rec709_to_xyz(rgb)), rgb, atol=1e-12)
    np.testing.assert_allclose(cs.lab_to_prophoto(cs.prophoto_to_lab(rgb)), rgb, atol=1e-9)
    np.testing.assert_allclose(cs.xyz_d50_to_d65(cs.xyz_d65_to_d50(rgb)), rgb, atol=1e-12)
    # ColorChecker: Lab -> ProPhoto -> Lab
    lab = colorchecker_classic().lab
    np.testing.assert_allclose(cs.prophoto_to_lab(cs.lab_to_prophoto(lab)), lab, atol=1e-9)


def test_space_names_and_errors():
    assert cs.to_prophoto([0.2, 0.3, 0.4], "scRGB").shape == (3,)
    with pytest.raises(UnknownMethodError, match="prophoto"):
        cs.to_prophoto([0.2, 0.3, 0.4], "adobe")


def test_exposure_normalises_grey_to_018_in_both_spaces():
    grey_pp = np.array([0.05, 0.055, 0.045])
    img = np.array([[0.1, 0.2, 0.3], grey_pp])
    out = normalise_exposure(img, grey_pp, space="prophoto")
    assert cs.luminance(out[1], "prophoto") == pytest.approx(0.18)
    np.testing.assert_allclose(out[0] / img[0], out[1] / img[1])  # one scalar gain
    grey_709 = np.array([0.7, 0.7, 0.7])
    out709 = normalise_exposure(grey_709[None], grey_709, space="rec709")
    assert cs.luminance(out709[0], "rec709") == pytest.approx(0.18)
    np.testing.assert_allclose(out709[0], [0.18, 0.18, 0.18])


def test_exposure_white_balance_makes_grey_neutral():
    grey_pp = np.array([0.30, 0.25, 0.15])  # warm, under-exposed grey card
    out = normalise_exposure(grey_pp, grey_pp, white_balance=True)
    np.testing.assert_allclose(out, [0.18, 0.18, 0.18], atol=1e-12)
    lab = cs.prophoto_to_lab(out)
    assert abs(lab[1]) < 1e-9 and abs(lab[2]) < 1e-9
    # in Rec.709 the same ProPhoto diagonal gain is a full 3x3; the grey ends neutral (D65 there)
    grey_709 = cs.prophoto_to_rec709(grey_pp)
    g = exposure_matrix(grey_709, space="rec709", white_balance=True)
    np.testing.assert_allclose(grey_709 @ g.T, [0.18, 0.18, 0.18], atol=1e-12)


def test_exposure_bad_grey():
    with pytest.raises(ExposureError, match="luminance"):
        normalise_exposure([[0.1, 0.1, 0.1]], [0.0, 0.0, 0.0])
    with pytest.raises(NegativeValueError):
        normalise_exposure([[-0.1, 0.1, 0.1]], [0.2, 0.2, 0.2])
    with pytest.raises(ExposureError, match="white-balanced"):
        normalise_exposure([[0.1, 0.1, 0.1]], [0.5, 0.2, 0.0], white_balance=True)
