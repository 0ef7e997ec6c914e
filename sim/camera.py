"""Pinhole camera maths (numpy): the measurement quad on the image plane and a framing view.

World metres; the image plane lies one metre in front of the eye, perpendicular to the line
from the eye to the centre of the measured pixel's top.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from grassd.sim.errors import SceneError


def image_quad(eye: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """Project world corners (4, 3) [m] onto the image plane one metre in front of ``eye``,
    looking at their centroid. Returns (4, 3) world points on that plane."""
    forward = corners.mean(axis=0) - eye
    forward /= np.linalg.norm(forward)
    rel = corners - eye
    depth = rel @ forward
    if np.any(depth <= 1e-6):
        raise SceneError("the measurement quad is not in front of the eye")
    return eye + rel / depth[:, None]


@dataclass(frozen=True)
class Framing:
    """A square view from ``eye`` towards ``target`` that shows the whole quad with a margin.

    ``right``/``up`` are unit vectors of the image plane (image x grows along ``right``, image
    y grows along ``-up``); ``half`` is the half-width of the view on the plane one metre away.
    """

    eye: np.ndarray
    target: np.ndarray
    forward: np.ndarray
    right: np.ndarray
    up: np.ndarray
    half: float

    @property
    def fov_deg(self) -> float:
        """Full horizontal (= vertical) field of view in degrees."""
        return math.degrees(2 * math.atan(self.half))

def frame_quad(eye: np.ndarray, corners: np.ndarray, margin: float = 0.1) -> Framing:
    """The square view of ``corners`` (4, 3) [m] from ``eye`` with a relative ``margin``."""
    target = corners.mean(axis=0)
    forward = (target - eye) / np.linalg.norm(target - eye)
    right = np.cross(forward, [0.0, 0.0, 1.0])
    norm = np.linalg.norm(right)
    if norm < 1e-9:
        raise SceneError("the eye is straight above the pixel; the view direction is undefined")
    right /= norm
    up = np.cross(right, forward)
    quad = image_quad(eye, corners) - (eye + forward)
    half = max(np.abs(quad @ right).max(), np.abs(quad @ up).max()) * (1 + margin)
    return Framing(eye=eye, target=target, forward=forward, right=right, up=up, half=half)
