"""Eye direction as rig weights: ARKit's eight eyeLook shapes, and VRM 1.0's lookAt range maps.

eca's eye angles are per eye, in the head, in degrees, in the agent's own frame: yaw + = toward the agent's
right, pitch + = up (agent/face/composed.py).

ARKit has no eye angles among its 52 shapes, only eyeLook{Up,Down,In,Out}{Left,Right} in 0..1. "In" is toward
the nose: for the LEFT eye that is a look to the agent's right (Apple / Unity Live Capture: "EyeLookInLeft: the
movement of the left eyelids consistent with a rightward gaze"), for the right eye a look to its left. Apple
documents no angle for a full weight; `EyeLookScale` holds one per direction (configs/rig.toml [eye_look]), and
the weights convert back to the angles exactly within that range (`eye_angles_from_arkit`).

VRM 1.0 lookAt (vrm-specification VRMC_vrm-1.0/lookAt.md) has one direction for both eyes (no vergence), in its
own signs: yaw + = the model's left (+X of a model facing +Z), pitch + = down. Each of four range maps turns an
angle into an output: output = min(|angle|, inputMaxValue) / inputMaxValue * outputScale, a weight of the
lookLeft/lookRight/lookUp/lookDown expressions (expression type: horizontal looks use rangeMapHorizontalOuter)
or a bone angle in degrees (bone type: a look toward the nose uses rangeMapHorizontalInner).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from eca.agent.rig.names import ARKIT_INDEX

# ARKit positions of the eight eyeLook shapes, in the column order of `eye_look_weights`.
EYE_LOOK_NAMES: tuple[str, ...] = (
    "EyeLookInLeft", "EyeLookOutLeft", "EyeLookUpLeft", "EyeLookDownLeft",
    "EyeLookInRight", "EyeLookOutRight", "EyeLookUpRight", "EyeLookDownRight",
)  # fmt: skip
EYE_LOOK_INDEX = np.array([ARKIT_INDEX[n] for n in EYE_LOOK_NAMES], dtype=np.intp)


@dataclass(frozen=True)
class EyeLookScale:
    """Degrees of eye rotation that give an eyeLook weight of 1, per direction (all > 0)."""

    in_deg: float
    out_deg: float
    up_deg: float
    down_deg: float


def eye_look_weights(eyes_deg: np.ndarray, scale: EyeLookScale) -> np.ndarray:
    """(..., 8) eyeLook weights in EYE_LOOK_NAMES order from (..., 4) eye angles [left yaw, left pitch, right yaw,
    right pitch] in degrees: each the angle toward its direction over that direction's scale, clipped to 0..1.
    (The retargeter makes the same weights inside its one matrix product: config.eye_look_rows.)"""
    yaw_l, pitch_l, yaw_r, pitch_r = (np.asarray(eyes_deg, dtype=np.float64)[..., k] for k in range(4))
    toward = np.stack(
        (
            yaw_l / scale.in_deg,  # the left eye's nose is on the agent's right
            -yaw_l / scale.out_deg,
            pitch_l / scale.up_deg,
            -pitch_l / scale.down_deg,
            -yaw_r / scale.in_deg,
            yaw_r / scale.out_deg,
            pitch_r / scale.up_deg,
            -pitch_r / scale.down_deg,
        ),
        axis=-1,
    )
    return np.clip(toward, 0.0, 1.0)


def eye_angles_from_arkit(arkit: np.ndarray, scale: EyeLookScale) -> np.ndarray:
    """The inverse of `eye_look_weights` on (..., 52) ARKit weights: (..., 4) [left yaw, left pitch, right yaw,
    right pitch] in degrees (exact within the scale's range; beyond it the weights saturated)."""
    w = arkit[..., EYE_LOOK_INDEX]
    in_l, out_l, up_l, down_l, in_r, out_r, up_r, down_r = (w[..., k] for k in range(8))
    return np.stack(
        (
            in_l * scale.in_deg - out_l * scale.out_deg,
            up_l * scale.up_deg - down_l * scale.down_deg,
            out_r * scale.out_deg - in_r * scale.in_deg,
            up_r * scale.up_deg - down_r * scale.down_deg,
        ),
        axis=-1,
    )


@dataclass(frozen=True)
class RangeMap:
    """A VRM 1.0 lookAt range map: `inputMaxValue` (degrees, > 0) and `outputScale` (> 0)."""

    input_max_deg: float
    output_scale: float

    def apply(self, angle_deg: np.ndarray | float) -> np.ndarray:
        """min(|angle|, inputMaxValue) / inputMaxValue * outputScale (lookAt.md, for either lookAt type)."""
        return np.minimum(np.abs(angle_deg), self.input_max_deg) * (self.output_scale / self.input_max_deg)

    def value(self, angle_deg: float) -> float:
        """`apply` of one angle, as a float."""
        return min(abs(angle_deg), self.input_max_deg) / self.input_max_deg * self.output_scale

    def invert(self, output: np.ndarray) -> np.ndarray:
        """The |angle| an output came from (exact for angles within inputMaxValue)."""
        return np.asarray(output) * (self.input_max_deg / self.output_scale)


@dataclass(frozen=True)
class VrmLookAt:
    """The four range maps of a VRM 1.0 lookAt (configs/rig.toml [vrm_look_at])."""

    horizontal_inner: RangeMap
    horizontal_outer: RangeMap
    vertical_down: RangeMap
    vertical_up: RangeMap

    def expression_weights(self, yaw_deg: np.ndarray, pitch_deg: np.ndarray) -> np.ndarray:
        """(N, 4) weights [lookUp, lookDown, lookLeft, lookRight] (RigFrame.vrm's order) of one gaze direction in
        eca's signs (yaw + = the agent's right, pitch + = up). lookLeft is a look to the agent's own left (VRM's
        yaw > 0); both horizontal looks use the outer range map, as lookAt.md says for the expression type."""
        yaw, pitch = np.asarray(yaw_deg, dtype=np.float64), np.asarray(pitch_deg, dtype=np.float64)
        return self.expression_from_signed(np.stack((pitch, -pitch, -yaw, yaw), axis=-1))

    def expression_from_signed(self, signed: np.ndarray) -> np.ndarray:
        """The weights of (..., 4) angles already signed toward [up, down, left, right]: a negative angle is a
        look the other way (weight 0), a positive one goes through its range map (and is kept within 1)."""
        limits, gains = self._expression_maps
        weights = np.minimum(np.maximum(signed, 0.0), limits) * gains
        return np.minimum(weights, 1.0, out=weights)  # a weight, whatever outputScale a model's map has

    @cached_property
    def _expression_maps(self) -> tuple[np.ndarray, np.ndarray]:
        maps = (self.vertical_up, self.vertical_down, self.horizontal_outer, self.horizontal_outer)
        limits = np.array([m.input_max_deg for m in maps])
        gains = np.array([m.output_scale / m.input_max_deg for m in maps])
        return limits, gains

    def angles_from_expression_weights(self, weights: np.ndarray) -> np.ndarray:
        """The inverse of `expression_weights` on (..., 4) [lookUp, lookDown, lookLeft, lookRight]: (..., 2)
        [yaw, pitch] in eca's signs, degrees."""
        up, down, left, right = (weights[..., k] for k in range(4))
        yaw = self.horizontal_outer.invert(right) - self.horizontal_outer.invert(left)
        pitch = self.vertical_up.invert(up) - self.vertical_down.invert(down)
        return np.stack((yaw, pitch), axis=-1)

    def bone_angles(self, yaw_deg: float, pitch_deg: float) -> tuple[tuple[float, float], tuple[float, float]]:
        """The bone-type lookAt: ((left eye yaw, pitch), (right eye yaw, pitch)) in VRM's signs (yaw + = the
        model's left, pitch + = down), degrees, for one gaze direction in eca's signs. A look toward the agent's
        right is outward for the right eye and inward for the left (lookAt.md's table)."""
        vrm_yaw, vrm_pitch = -float(yaw_deg), -float(pitch_deg)
        outer, inner = self.horizontal_outer.value(vrm_yaw), self.horizontal_inner.value(vrm_yaw)
        if vrm_yaw > 0.0:  # the model's left: outward for the left eye
            left_yaw, right_yaw = outer, inner
        else:
            left_yaw, right_yaw = -inner, -outer
        if vrm_pitch > 0.0:
            pitch = self.vertical_down.value(vrm_pitch)
        else:
            pitch = -self.vertical_up.value(vrm_pitch)
        return (left_yaw, pitch), (right_yaw, pitch)
