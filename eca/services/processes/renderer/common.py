"""What every kind of face drawer shares besides the face: the switches a window's keys set (`RenderToggles`)
and the camera's projection (`perspective`). Nothing here loads GL or the compiled drawing code (numba), so
whoever only names these (the stage, the service, the 3D head) does not pay for the 2D face's kernels."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass
class RenderToggles:
    """The paper's front-end switches (its 'Face Properties' panel)."""

    eyebrows: bool = True
    eye_cover: bool = True  # the lids
    wireframe: bool = False  # the polygon mesh over the surface
    surface_3d: bool = False  # smooth 3D shading instead of flat cartoon bands
    eye_centre: bool = False  # a marker on each pupil centre
    trajectory: bool = True  # the recent gaze polyline, when render() is given overlay_points


def perspective(fov_deg: float, aspect: float, near: float, far: float) -> np.ndarray:
    f = 1.0 / math.tan(math.radians(fov_deg) / 2.0)
    return np.array(
        [
            [f / aspect, 0, 0, 0],
            [0, f, 0, 0],
            [0, 0, (far + near) / (near - far), 2 * far * near / (near - far)],
            [0, 0, -1, 0],
        ]
    )
