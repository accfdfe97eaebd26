"""The retargeter: a composed face (flexors + head and eye angles) in, a `RigFrame` out.

The rig is a retargeting of the composed flexors, not a second emotion model: no emotion name goes in. The
paper's emotions stay defined by their flexor poses (configs/emotions.toml); whatever the layers below made of
them (an emotion blending in, a blink, the lip-sync's mouth) is what the rig shows.

- ARKit: every shape but the eyeLooks is a clipped linear map of the flexors' two directions (mapping.py) with
  the FACS <-> ARKit correspondences of configs/rig.toml [arkit]; the eyeLooks come from each eye's angles
  (lookat.py, [eye_look]).
- Visemes and VRM vowels come from the five mouth weights (visemes.py, [visemes]).
- VRM emotions are clipped linear maps of the flexors too ([vrm_emotions]); neutral = 1 - the largest of them.
  blink is the closure both lids share (the smaller EyeBlink), blinkLeft/blinkRight what one lid has beyond it,
  so each side's total is its EyeBlink. lookUp/Down/Left/Right follow VRM 1.0's lookAt range maps ([vrm_look_at])
  from the mean direction of the two eyes (VRM has one direction for both).

Everything is numpy over N faces at once; one face is the batch of one, so `retarget` and `retarget_many` agree
(to rounding: BLAS may sum a product of one row and of many rows in different orders). Deterministic, no state:
the same face gives the same frame.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from eca.agent.face.composed import ComposedFace
from eca.agent.face.flexors import FLEXOR_INDEX, N_FLEXORS
from eca.agent.face.settings import FlexorUnits, load_flexor_units
from eca.agent.rig.config import RigConfig, load_rig_config
from eca.agent.rig.frame import RigBatch, RigFrame
from eca.agent.rig.mapping import INPUT_INDEX, FlexorMap, rig_inputs
from eca.agent.rig.names import ARKIT_INDEX, N_ARKIT, N_VRM, VRM_INDEX
from eca.agent.rig.visemes import MOUTH_SHAPES

_MOUTH_INPUTS = np.array([INPUT_INDEX[f"{name}+"] for name in MOUTH_SHAPES], dtype=np.intp)
_HEAD = np.array([FLEXOR_INDEX[name] for name in ("turn", "nod", "tilt")], dtype=np.intp)
_LOOK = np.array([FLEXOR_INDEX[name] for name in ("look_x", "look_y")], dtype=np.intp)
_BLINK_L, _BLINK_R = ARKIT_INDEX["EyeBlinkLeft"], ARKIT_INDEX["EyeBlinkRight"]
_EMOTIONS = slice(VRM_INDEX["happy"], VRM_INDEX["surprised"] + 1)
_VOWELS = slice(VRM_INDEX["aa"], VRM_INDEX["oh"] + 1)
_BLINK, _BLINK_LEFT, _BLINK_RIGHT = VRM_INDEX["blink"], VRM_INDEX["blinkLeft"], VRM_INDEX["blinkRight"]
_LOOKS = slice(VRM_INDEX["lookUp"], VRM_INDEX["lookRight"] + 1)
_NEUTRAL = VRM_INDEX["neutral"]

# Eye angles [left yaw, left pitch, right yaw, right pitch] -> the mean direction signed toward VRM's
# [up, down, left, right] (eca's yaw + is the agent's right, so a look left is a negative yaw).
_CYCLOPEAN_SIGNED = 0.5 * np.array([
    [0.0, 0.0, -1.0, 1.0],
    [1.0, -1.0, 0.0, 0.0],
    [0.0, 0.0, -1.0, 1.0],
    [1.0, -1.0, 0.0, 0.0],
])  # fmt: skip


class Retargeter:
    """Composed faces onto ARKit, visemes and VRM; see the module docstring."""

    def __init__(self, config: RigConfig | None = None, units: FlexorUnits | None = None) -> None:
        self.config = config if config is not None else load_rig_config()
        self.units = units if units is not None else load_flexor_units()
        # ARKit rows and VRM emotion rows in one matrix product.
        self._map = FlexorMap.concat((self.config.arkit, self.config.vrm_emotions))
        u = self.units
        self._head_scale = np.array([u.turn_deg, u.nod_deg, u.tilt_deg])
        self._look_scale = np.array([u.look_x_deg, u.look_y_deg, u.look_x_deg, u.look_y_deg])

    @classmethod
    def load(cls, path: str | Path | None = None, units: FlexorUnits | None = None) -> Retargeter:
        """A retargeter of configs/rig.toml (or the file at `path`) and the flexor units."""
        return cls(load_rig_config(path), units)

    def retarget(self, face: ComposedFace) -> RigFrame:
        """The rig frame of one composed face."""
        left, right = face.left_eye, face.right_eye
        eyes = np.array([[left.yaw_deg, left.pitch_deg, right.yaw_deg, right.pitch_deg]])
        arkit, visemes, vrm = self._weights(face.frame.values[None, :], eyes)
        return RigFrame.trusted(face.t_ns, arkit[0], (face.head_yaw_deg, face.head_pitch_deg, face.head_roll_deg),
                                left, right, visemes[0], vrm[0])

    def retarget_many(self, flexors: np.ndarray, t_ns: int = 0, eyes_deg: np.ndarray | None = None,
                      head_deg: np.ndarray | None = None) -> RigBatch:
        """Rig weights of N agents' (N, 21) flexor vectors at once. `eyes_deg` (N, 4) [left yaw, left pitch, right
        yaw, right pitch] and `head_deg` (N, 3) [yaw, pitch, roll] replace the angles the flexors give through the
        flexor units (look_x/look_y for both eyes; turn, nod, tilt), as ComposedFace.from_frame does."""
        values = np.asarray(flexors, dtype=np.float64)
        if values.ndim != 2 or values.shape[1] != N_FLEXORS:
            raise ValueError(f"flexors need shape (N, {N_FLEXORS}), got {values.shape}")
        if not np.isfinite(values).all():
            raise ValueError("flexors must be finite (a composed face has no 'do not care' values)")
        values = np.clip(values, -1.0, 1.0)
        n = values.shape[0]
        eyes = self._angles(eyes_deg, values[:, _LOOK][:, [0, 1, 0, 1]] * self._look_scale, (n, 4), "eyes_deg")
        head = self._angles(head_deg, values[:, _HEAD] * self._head_scale, (n, 3), "head_deg")
        arkit, visemes, vrm = self._weights(values, eyes)
        return RigBatch(int(t_ns), arkit, head, eyes, visemes, vrm)

    def retarget_faces(self, faces: Sequence[ComposedFace]) -> list[RigFrame]:
        """Rig frames of many composed faces (one batch inside); frame i has faces[i]'s time."""
        if not faces:
            return []
        values = np.stack([face.frame.values for face in faces])
        eyes = np.array([[f.left_eye.yaw_deg, f.left_eye.pitch_deg, f.right_eye.yaw_deg, f.right_eye.pitch_deg]
                         for f in faces])
        arkit, visemes, vrm = self._weights(values, eyes)
        return [
            RigFrame.trusted(f.t_ns, arkit[i], (f.head_yaw_deg, f.head_pitch_deg, f.head_roll_deg), f.left_eye,
                             f.right_eye, visemes[i], vrm[i])
            for i, f in enumerate(faces)
        ]

    @staticmethod
    def _angles(given: np.ndarray | None, default: np.ndarray, shape: tuple[int, int], what: str) -> np.ndarray:
        if given is None:
            return default
        angles = np.array(given, dtype=np.float64)
        if angles.shape != shape or not np.isfinite(angles).all():
            raise ValueError(f"{what} needs finite values of shape {shape}, got shape {angles.shape}")
        return angles

    def _weights(self, values: np.ndarray, eyes: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(arkit (N, 52), visemes (N, 15), vrm (N, 18)) of (N, 21) flexor vectors and (N, 4) eye angles."""
        inputs = rig_inputs(values, eyes)
        linear = self._map.apply(inputs)
        arkit = linear[:, :N_ARKIT]
        # The mouth's positive parts are its weights in 0..1 (values lie in [-1, 1]).
        visemes, vowels = self.config.visemes.weights_unclipped(inputs[:, _MOUTH_INPUTS])

        vrm = np.empty((values.shape[0], N_VRM))
        vrm[:, _EMOTIONS] = linear[:, N_ARKIT:]
        vrm[:, _VOWELS] = vowels
        lid_l, lid_r = arkit[:, _BLINK_L], arkit[:, _BLINK_R]
        both = np.minimum(lid_l, lid_r, out=vrm[:, _BLINK])
        np.subtract(lid_l, both, out=vrm[:, _BLINK_LEFT])
        np.subtract(lid_r, both, out=vrm[:, _BLINK_RIGHT])
        vrm[:, _LOOKS] = self.config.look_at.expression_from_signed(eyes @ _CYCLOPEAN_SIGNED)
        np.subtract(1.0, vrm[:, _EMOTIONS].max(axis=1), out=vrm[:, _NEUTRAL])
        for array in (arkit, visemes, vrm):
            array.flags.writeable = False
        return arkit, visemes, vrm
