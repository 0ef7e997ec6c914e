"""The checker photo's white balance refuses a photo whose patches are clipped: a clipped patch
(the grey unclipped) bends the colour correction fitted to the patches."""

from __future__ import annotations

import numpy as np
import pytest

from grassd.calib.ccm import fit_ccm
from grassd.calib.charts import get_chart
from grassd.calib.checker_photo import checker_scene, checker_white_balance, virtual_checker
from grassd.calib.colour_spaces import luminance
from grassd.calib.errors import CheckerPhotoError
from grassd.calib.exposure import GREY_CARD_Y
from grassd.calib.raw import develop_raw
from grassd.calib.virtual_camera import VirtualCamera

CHART = get_chart("spydercheckr-24")


def _correction(path, corners):
    wb = checker_white_balance(path, corners, CHART)
    patches = develop_raw(path, white_balance=wb).checker_patches(corners)
    k = GREY_CARD_Y / float(luminance(patches[CHART.grey_index()], "prophoto"))
    virtual, _ = virtual_checker(CHART)
    return fit_ccm(virtual, patches * k, "3x3")


def test_a_checker_with_clipped_bright_patches_is_refused(tmp_path):
    white = np.array([1.0, 0.85, 0.65]) * 80.0  # a warm light: white card nits
    img, corners = checker_scene(CHART, white)
    cam = VirtualCamera(read_noise_e=0.0, full_well_e=1e9)
    k = cam.exposure_for(white)
    good = _correction(cam.photograph(tmp_path / "good.dng", img, white), corners)
    assert good.mean_de00 < 0.2
    # 2.5x over: the white and light patches clip, the grey (L* 49.5) does not
    over = cam.photograph(tmp_path / "over.dng", img, white, electrons_per_unit=2.5 * k)
    with pytest.raises(CheckerPhotoError, match="clipped") as err:
        checker_white_balance(over, corners, CHART)
    brightest = int(np.argmax(CHART.lab[:, 0]))
    assert f"{brightest + 1} ({CHART.patch_names[brightest]})" in str(err.value)
    assert "grey" not in str(err.value) and "lower the exposure" in str(err.value)
