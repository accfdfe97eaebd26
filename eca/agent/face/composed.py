"""The composed face: the one type every consumer of the face takes (a drawer, a rig retargeting, a sender,
an offline render's CSV).

A `ComposedFace` is the face at one display time: its flexor frame (the paper's face: expression, head,
eyes, lids and mouth as flexor values in [-1, 1], what the 2D face draws) and the same pose in physical
units, converted once, in FaceModel.compose, with the flexor units (configs/flexor_units.toml): the head's
yaw, pitch and roll and each eye's yaw and pitch in degrees. The eyes are given per eye, as shown in the
head: the gaze model's direction, unclipped, or that direction counter-rotated for the head shown (a
conversation); the two eyes are equal unless a producer gives a vergence. `lid` is the gaze model's lid
closure (blinks and the lid's follow of the eyes), `role` and `emotion` what the agent is in at that time.

Angles follow the agent's own frame: yaw + = toward the agent's right, pitch + = up (for the head: chin
up), roll + = toward the agent's right shoulder.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from eca.agent.face.flexors import FLEXOR_INDEX
from eca.agent.face.frame import FlexorFrame
from eca.agent.face.settings import FlexorUnits

_TURN, _NOD, _TILT = FLEXOR_INDEX["turn"], FLEXOR_INDEX["nod"], FLEXOR_INDEX["tilt"]
_LOOK_X, _LOOK_Y = FLEXOR_INDEX["look_x"], FLEXOR_INDEX["look_y"]


@dataclass(frozen=True)
class EyeAngles:
    """One eye's direction in the head, degrees: yaw + = the agent's right, pitch + = up."""

    yaw_deg: float
    pitch_deg: float


@dataclass(frozen=True)
class ComposedFace:
    """The face at `frame.t_ns`; see the module docstring."""

    frame: FlexorFrame
    head_yaw_deg: float
    head_pitch_deg: float
    head_roll_deg: float
    left_eye: EyeAngles
    right_eye: EyeAngles
    lid: float = 0.0
    role: str = ""
    emotion: str = ""
    emotion_intensity: float = 0.0

    @property
    def t_ns(self) -> int:
        return self.frame.t_ns

    @property
    def flexors(self) -> np.ndarray:
        """The flexor values (FLEXOR_NAMES order, read-only)."""
        return self.frame.values

    @classmethod
    def from_frame(cls, frame: FlexorFrame, units: FlexorUnits,
                   eyes: EyeAngles | tuple[EyeAngles, EyeAngles] | None = None, *, lid: float = 0.0,
                   role: str = "", emotion: str = "", emotion_intensity: float = 0.0) -> ComposedFace:
        """The face of a flexor frame: the head's angles from its flexors and the units; the eyes `eyes`
        (one direction for both, or (left, right) with a vergence), or from the frame's look flexors when
        None."""
        v = frame.values
        if eyes is None:
            eyes = EyeAngles(float(v[_LOOK_X]) * units.look_x_deg, float(v[_LOOK_Y]) * units.look_y_deg)
        left, right = eyes if isinstance(eyes, tuple) else (eyes, eyes)
        return cls(frame, float(v[_TURN]) * units.turn_deg, float(v[_NOD]) * units.nod_deg,
                   float(v[_TILT]) * units.tilt_deg, left, right, float(lid), role, emotion,
                   float(emotion_intensity))

    def with_flexors(self, values: np.ndarray, units: FlexorUnits) -> ComposedFace:
        """The same face with other flexor values (a drawer's staging turn, say): the head's angles follow
        them, the eyes and everything else stay."""
        frame = FlexorFrame.composed(np.array(values, dtype=np.float64), self.t_ns)
        v = frame.values
        return ComposedFace(frame, float(v[_TURN]) * units.turn_deg, float(v[_NOD]) * units.nod_deg,
                            float(v[_TILT]) * units.tilt_deg, self.left_eye, self.right_eye, self.lid, self.role,
                            self.emotion, self.emotion_intensity)
