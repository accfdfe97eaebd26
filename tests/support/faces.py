"""Composed faces for tests that draw: a face from a few named flexors and the eyes' angles."""

from __future__ import annotations

import numpy as np

from eca.agent.face.composed import ComposedFace, EyeAngles
from eca.agent.face.flexors import FLEXOR_INDEX, N_FLEXORS
from eca.agent.face.frame import FlexorFrame
from eca.agent.face.settings import load_flexor_units

UNITS = load_flexor_units()


def composed_face(eyes: tuple[float, float] = (0.0, 0.0), **flexors: float) -> ComposedFace:
    """All flexors relaxed but those given (any in [-1, 1]), both eyes at (yaw, pitch) degrees."""
    values = np.zeros(N_FLEXORS)
    for name, value in flexors.items():
        values[FLEXOR_INDEX[name]] = value
    return ComposedFace.from_frame(FlexorFrame.composed(values, 0), UNITS, EyeAngles(*eyes))
