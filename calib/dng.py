"""A small, real DNG writer: linear camera RGB -> Bayer-mosaiced 16-bit DNG that LibRaw develops.

Used by the tests (to check RAW development end to end without any mocked reader) and meant for a
virtual camera: render scene-linear colour, express it in the camera's native RGB, mosaic it,
write it. The file is a single-IFD uncompressed CFA DNG (Adobe DNG Specification 1.4.0.0):

* IFD0 holds the raw image (NewSubFileType 0, PhotometricInterpretation 32803 = CFA, 16 bit);
* CFARepeatPatternDim / CFAPattern give the 2x2 Bayer layout (e.g. RGGB);
* BlackLevel / WhiteLevel give the data range;
* ColorMatrix1 maps XYZ to camera native RGB under CalibrationIlluminant1 (21 = D65);
* AsShotNeutral is the camera-native RGB of the scene white (the camera white balance).

Camera model: ``camera = ColorMatrix1 . XYZ`` for scene XYZ relative to D65 (Y of white = 1),
and the raw value of a photosite is ``black + camera_channel * exposure * (white - black)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from fractions import Fraction
from pathlib import Path

import numpy as np
import tifffile
from numpy.typing import ArrayLike, NDArray

from grassd.calib.array_checks import as_float_array
from grassd.calib.colour_spaces import M_REC709_TO_XYZ, WHITE_D65_XYZ
from grassd.calib.errors import DngWriteError

#: Bayer layouts: name -> 2x2 colour indices (0 = R, 1 = G, 2 = B), row-major.
CFA_PATTERNS: dict[str, tuple[int, int, int, int]] = {
    "RGGB": (0, 1, 1, 2),
    "BGGR": (2, 1, 1, 0),
    "GRBG": (1, 0, 2, 1),
    "GBRG": (1, 2, 0, 1),
}
#: EXIF LightSource code of D65, used for CalibrationIlluminant1.
ILLUMINANT_D65: int = 21


def _srational(values: ArrayLike, denominator: int = 10000) -> list[int]:
    out: list[int] = []
    for v in np.asarray(values, dtype=np.float64).ravel():
        f = Fraction(float(v)).limit_denominator(denominator)
        out += [f.numerator, f.denominator]
    return out


@dataclass(frozen=True)
class DngCamera:
    """Colour description of a (virtual) camera written into DNG tags.

    Attributes:
        color_matrix: (3, 3) XYZ (D65-relative) -> camera native RGB (DNG ColorMatrix1).
        cfa_pattern: Bayer layout name, one of :data:`CFA_PATTERNS`.
        black_level: raw value of zero light.
        white_level: raw value of saturation (<= 65535).
        make, model: written to Make/Model/UniqueCameraModel.
    """

    color_matrix: NDArray[np.float64] = field(
        default_factory=lambda: np.linalg.inv(M_REC709_TO_XYZ)
    )
    cfa_pattern: str = "RGGB"
    black_level: int = 512
    white_level: int = 16383
    make: str = "grassd"
    model: str = "Virtual Camera"

    def camera_rgb_from_xyz(self, xyz: ArrayLike) -> NDArray[np.float64]:
        """Scene XYZ relative to D65 (..., 3) -> camera native linear RGB (..., 3)."""
        return as_float_array(xyz, "xyz", last_dim=3) @ np.asarray(self.color_matrix).T

    def neutral(self) -> NDArray[np.float64]:
        """Camera-native RGB of the D65 white, scaled so its maximum is 1 (AsShotNeutral)."""
        n = np.asarray(self.color_matrix) @ WHITE_D65_XYZ
        return n / n.max()


def mosaic(camera_rgb: ArrayLike, camera: DngCamera, exposure: float = 1.0) -> NDArray[np.uint16]:
    """Bayer-sample camera RGB (H, W, 3) into raw 16-bit values (H, W) with black/white levels.

    Values are ``black + rgb * exposure * (white - black)``, rounded and clipped at white.
    """
    rgb = as_float_array(camera_rgb, "camera_rgb", last_dim=3, ndim=3, non_negative=True)
    if camera.cfa_pattern not in CFA_PATTERNS:
        raise DngWriteError(
            f"unknown CFA pattern {camera.cfa_pattern!r}; use one of {', '.join(CFA_PATTERNS)}"
        )
    h, w, _ = rgb.shape
    if h < 2 or w < 2 or h % 2 or w % 2:
        raise DngWriteError(f"a Bayer image needs an even height and width >= 2; got {h}x{w}")
    if not 0 <= camera.black_level < camera.white_level <= 65535:
        raise DngWriteError(
            f"need 0 <= black_level < white_level <= 65535; got {camera.black_level}, "
            f"{camera.white_level}"
        )
    pattern = np.array(CFA_PATTERNS[camera.cfa_pattern]).reshape(2, 2)
    channel = np.tile(pattern, (h // 2, w // 2))
    plane = np.take_along_axis(rgb, channel[..., None], axis=2)[..., 0]
    span = camera.white_level - camera.black_level
    raw = np.rint(camera.black_level + plane * exposure * span)
    return np.clip(raw, 0, camera.white_level).astype(np.uint16)


def write_dng(
    path: str | Path,
    raw: ArrayLike,
    camera: DngCamera,
    *,
    as_shot_neutral: ArrayLike | None = None,
) -> Path:
    """Write a Bayer raw image (H, W) uint16 as a DNG file that LibRaw/rawpy can develop.

    Args:
        path: destination file (``.dng``).
        raw: (H, W) raw values laid out in ``camera.cfa_pattern`` (see :func:`mosaic`).
        camera: colour matrix, CFA layout, black and white levels.
        as_shot_neutral: camera-native RGB of the scene white (3,); default the D65 white.

    Returns:
        The path written.
    """
    arr = np.asarray(raw)
    if arr.ndim != 2 or arr.dtype != np.uint16:
        raise DngWriteError(f"raw must be a 2-D uint16 Bayer array; got {arr.dtype} {arr.shape}")
    if camera.cfa_pattern not in CFA_PATTERNS:
        raise DngWriteError(f"unknown CFA pattern {camera.cfa_pattern!r}")
    cm = np.asarray(camera.color_matrix, dtype=np.float64)
    if cm.shape != (3, 3) or not np.isfinite(cm).all() or abs(np.linalg.det(cm)) < 1e-9:
        raise DngWriteError(f"color_matrix must be an invertible finite 3x3; got {cm.tolist()}")
    neutral = camera.neutral() if as_shot_neutral is None else np.asarray(as_shot_neutral, float)
    if neutral.shape != (3,) or not (np.isfinite(neutral).all() and (neutral > 0).all()):
        raise DngWriteError(f"as_shot_neutral must be 3 positive numbers; got {neutral.tolist()}")
    h, w = arr.shape
    extratags = [
        (33421, "H", 2, (2, 2), True),  # CFARepeatPatternDim
        (33422, "B", 4, bytes(CFA_PATTERNS[camera.cfa_pattern]), True),  # CFAPattern
        (271, "s", 0, camera.make, True),  # Make
        (272, "s", 0, camera.model, True),  # Model
        (50706, "B", 4, bytes((1, 4, 0, 0)), True),  # DNGVersion
        (50707, "B", 4, bytes((1, 1, 0, 0)), True),  # DNGBackwardVersion
        (50708, "s", 0, f"{camera.make} {camera.model}", True),  # UniqueCameraModel
        (50710, "B", 3, bytes((0, 1, 2)), True),  # CFAPlaneColor
        (50711, "H", 1, 1, True),  # CFALayout: rectangular
        (50713, "H", 2, (1, 1), True),  # BlackLevelRepeatDim
        (50714, "I", 1, int(camera.black_level), True),  # BlackLevel
        (50717, "I", 1, int(camera.white_level), True),  # WhiteLevel
        (50721, 10, 9, _srational(cm), True),  # ColorMatrix1 (SRATIONAL)
        (50728, 5, 3, _srational(neutral), True),  # AsShotNeutral (RATIONAL)
        (50778, "H", 1, ILLUMINANT_D65, True),  # CalibrationIlluminant1
    ]
    p = Path(path)
    try:
        tifffile.imwrite(
            p,
            arr,
            photometric=32803,  # CFA
            subfiletype=0,
            compression=None,
            metadata=None,
            extratags=extratags,
            rowsperstrip=h,
        )
    except (OSError, ValueError) as exc:
        raise DngWriteError(f"cannot write DNG {p} ({w}x{h}): {exc}") from exc
    return p


def write_linear_dng(
    path: str | Path,
    xyz: ArrayLike,
    camera: DngCamera | None = None,
    *,
    exposure: float = 1.0,
    as_shot_neutral: ArrayLike | None = None,
) -> Path:
    """Photograph scene XYZ (H, W, 3; D65-relative, Y of white = 1) with ``camera`` into a DNG.

    Convenience for a virtual camera: camera RGB = ColorMatrix1 . XYZ, Bayer-sampled, scaled by
    ``exposure`` into [black, white] and written with :func:`write_dng`.
    """
    cam = camera or DngCamera()
    rgb = cam.camera_rgb_from_xyz(xyz)
    if (rgb < 0).any():
        raise DngWriteError(
            "the scene has colours outside the camera's gamut (negative camera RGB); "
            "use a wider camera matrix or less saturated colours"
        )
    return write_dng(path, mosaic(rgb, cam, exposure), cam, as_shot_neutral=as_shot_neutral)
