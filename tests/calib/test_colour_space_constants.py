"""The matrices that grassd.calib.colour_spaces writes out (so that importing it needs no
colour-science) are colour-science's, to the last bit, and it imports colour only
when a CIELAB conversion or a colour difference is asked for."""

from __future__ import annotations

import subprocess
import sys

import colour
import numpy as np

from grassd.calib import colour_spaces as cs


def test_the_written_matrices_are_colour_sciences_exactly():
    rec709 = colour.RGB_COLOURSPACES["ITU-R BT.709"].matrix_RGB_to_XYZ
    prophoto = colour.RGB_COLOURSPACES["ProPhoto RGB"].matrix_RGB_to_XYZ
    assert np.array_equal(cs.M_REC709_TO_XYZ, rec709)
    assert np.array_equal(cs.M_PROPHOTO_TO_XYZ, prophoto)
    assert np.array_equal(cs.WHITE_D65_XYZ, np.asarray(rec709).sum(axis=1))
    assert np.array_equal(cs.WHITE_D50_XYZ, np.asarray(prophoto).sum(axis=1))
    bradford = colour.adaptation.matrix_chromatic_adaptation_VonKries(
        cs.WHITE_D65_XYZ, cs.WHITE_D50_XYZ, transform=cs.ADAPTATION)
    assert np.array_equal(cs.M_CAT_D65_TO_D50, bradford)
    assert np.array_equal(cs.M_CAT_D50_TO_D65, np.linalg.inv(bradford))


def test_colour_science_loads_only_for_a_colour_difference():
    """Importing the calibration modules and converting between RGB spaces load no colour;
    the first CIEDE2000 does."""
    code = """
import sys
import grassd.calib.ccm, grassd.calib.charts, grassd.calib.ogcd
from grassd.calib.colour_spaces import rec709_to_prophoto
rec709_to_prophoto([0.2, 0.3, 0.4])
before = "colour" in sys.modules
d = grassd.calib.ogcd.ogcd_from_lab([[50, 0, 0], [60, 0, 0]])
print(before, "colour" in sys.modules, round(float(d[1]), 4))
"""
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert proc.stdout.split() == ["False", "True", "9.4706"], proc.stdout
