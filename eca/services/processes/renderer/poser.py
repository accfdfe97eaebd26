"""From a flexor vector to a Pose: the bones (head, jaw, eyes, lids; compiled with numba: a frame needs a
dozen 3x3 products, where Python's and numpy's per-call costs would be the cost), the head's model matrix,
the pupils, and the dynamic parts' vertices (curves.py)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from eca.agent.face.flexors import FLEXOR_INDEX
from eca.agent.face.settings import FlexorUnits, load_flexor_units
from eca.services.processes.renderer.curves import DynamicLayout, MouthShape, build_dynamic, clean_flexors, mouth_shape
from eca.services.processes.renderer.geometry import (
    BONE_EYE_L,
    BONE_HEAD,
    BONE_JAW,
    BONE_LLID_L,
    BONE_ULID_L,
    EYE_RADIUS,
    JAW_PIVOT,
    LIDS_CLOSED,
    LOWER_FOLLOWS_PITCH,
    LOWER_RIM_REST,
    N_BONES,
    NECK_PIVOT,
    UPPER_FOLLOWS_PITCH,
    UPPER_RIM_NARROW,
    UPPER_RIM_REST,
    UPPER_RIM_WIDE,
    eye_centre,
)


@dataclass
class Pose:
    """Everything a frame needs from the flexors: bone matrices, the head's model matrix, dynamic vertices."""

    bones: np.ndarray  # (N_BONES, 4, 4) float64, head frame
    model: np.ndarray  # (4, 4) head frame -> world
    dynamic: np.ndarray  # (layout.n_vertices, 13) float32; see FacePoser.pose and build_dynamic for what is current
    pupils: np.ndarray  # (2, 3) world positions of the agent's left (+x) and right pupil centres
    flexors: np.ndarray | None = None  # the cleaned flexors the pose was made from
    mouth: MouthShape | None = None


@numba.njit(cache=True)
def lid_elevations(blink: float, lids: float, pitch_deg: float) -> tuple[float, float]:
    """Upper and lower rim elevations (degrees) for one eye."""
    blink = min(max(blink, 0.0), 1.0)
    upper = UPPER_RIM_REST + (
        lids * (UPPER_RIM_WIDE - UPPER_RIM_REST) if lids > 0 else -lids * (UPPER_RIM_NARROW - UPPER_RIM_REST)
    )
    upper += UPPER_FOLLOWS_PITCH * pitch_deg
    lower = LOWER_RIM_REST + LOWER_FOLLOWS_PITCH * pitch_deg + 22.0 * max(-lids, 0.0)
    upper = upper + (LIDS_CLOSED - upper) * blink
    lower = lower + (LIDS_CLOSED - 3.0 - lower) * blink
    upper = max(upper, lower + 1.0)
    return upper, lower


# The bones are posed by compiled code (numba): a frame needs a dozen 3x3 products, where Python's and
# numpy's per-call costs, not the arithmetic, would be the cost.
_TURN, _NOD, _TILT, _LOOK_X, _LOOK_Y = (FLEXOR_INDEX[n] for n in ("turn", "nod", "tilt", "look_x", "look_y"))
_BLINK = (FLEXOR_INDEX["blink_l"], FLEXOR_INDEX["blink_r"])  # the agent's left eye (+x) first
_LIDS = (FLEXOR_INDEX["lids_l"], FLEXOR_INDEX["lids_r"])


@numba.njit(cache=True)
def _rotation(axis: int, deg: float) -> np.ndarray:
    """The 3x3 rotation by `deg` about x (axis 0), y (1) or z (2)."""
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    i, j = (1, 2) if axis == 0 else ((2, 0) if axis == 1 else (0, 1))
    r = np.eye(3)
    r[i, i] = c
    r[i, j] = -s
    r[j, i] = s
    r[j, j] = c
    return r


@numba.njit(cache=True)
def _mul3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    out = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            out[i, j] = a[i, 0] * b[0, j] + a[i, 1] * b[1, j] + a[i, 2] * b[2, j]
    return out


@numba.njit(cache=True)
def _about(pivot: np.ndarray, rotation: np.ndarray, out: np.ndarray) -> None:
    """Write into `out` the 4x4 matrix of `rotation` about `pivot` instead of the origin."""
    for k in range(3):
        for j in range(3):
            out[k, j] = rotation[k, j]
        out[k, 3] = pivot[k] - (rotation[k, 0] * pivot[0] + rotation[k, 1] * pivot[1] + rotation[k, 2] * pivot[2])
        out[3, k] = 0.0
    out[3, 3] = 1.0


@numba.njit(cache=True)
def _pose_bones(
    f: np.ndarray,
    degrees: np.ndarray,
    centres: np.ndarray,
    jaw_deg: float,
    bones: np.ndarray,
    model: np.ndarray,
    pupils: np.ndarray,
) -> None:
    """Bones (N_BONES, 4, 4), the head's model matrix and the pupils' world positions (agent's left eye
    first) for the clean flexors f; `degrees` per flexor unit: look_x, look_y, turn, nod, tilt."""
    # turn +1 = toward the agent's right (-x): a negative yaw about +y; nod +1 = chin up: a negative
    # rotation about +x; tilt +1 = toward the agent's right shoulder: the top of the head moves to -x.
    head = _mul3(_mul3(_rotation(1, -f[_TURN] * degrees[2]), _rotation(0, -f[_NOD] * degrees[3])),
                 _rotation(2, f[_TILT] * degrees[4]))  # fmt: skip
    _about(NECK_PIVOT, head, model)
    pitch = f[_LOOK_Y] * degrees[1]
    eye = _mul3(_rotation(1, -f[_LOOK_X] * degrees[0]), _rotation(0, -pitch))
    _about(NECK_PIVOT, np.eye(3), bones[BONE_HEAD])  # the identity
    # Rotating the jaw about +x by a positive angle swings the chin down and back.
    _about(JAW_PIVOT, _rotation(0, jaw_deg), bones[BONE_JAW])
    for side in range(2):
        c = centres[side]
        _about(c, eye, bones[BONE_EYE_L + side])
        up, low = lid_elevations(f[_BLINK[side]], f[_LIDS[side]], pitch)
        _about(c, _rotation(0, -up), bones[BONE_ULID_L + side])
        _about(c, _rotation(0, -low), bones[BONE_LLID_L + side])
        # The pupil: the eye's forward pole, rotated about its centre, then moved with the head.
        x, y, z = c[0] + EYE_RADIUS * eye[0, 2], c[1] + EYE_RADIUS * eye[1, 2], c[2] + EYE_RADIUS * eye[2, 2]
        for k in range(3):
            pupils[side, k] = model[k, 0] * x + model[k, 1] * y + model[k, 2] * z + model[k, 3]


class FacePoser:
    """Turns a flexor vector into a Pose; holds the reusable buffers for the dynamic vertices."""

    def __init__(self, units: FlexorUnits | None = None) -> None:
        self.units = units or load_flexor_units()
        self.layout = DynamicLayout()
        self._dynamic = self.layout.template()
        self._centres = {1: eye_centre(1), -1: eye_centre(-1)}
        self._centre_rows = np.array([self._centres[1], self._centres[-1]])  # the agent's left eye first
        u = self.units
        self._degrees = np.array([u.look_x_deg, u.look_y_deg, u.turn_deg, u.nod_deg, u.tilt_deg], dtype=np.float64)

    def pose(self, flexors: np.ndarray, dynamic: bool = True) -> Pose:
        """The pose for `flexors`. With dynamic=False the brows and mouth are left for build_dynamic(),
        which a renderer can ask for only what its vertex shader needs."""
        f = clean_flexors(flexors)
        shape = mouth_shape(f)
        bones, model, pupils = np.empty((N_BONES, 4, 4)), np.empty((4, 4)), np.empty((2, 3))
        _pose_bones(f, self._degrees, self._centre_rows, shape.jaw_deg, bones, model, pupils)
        pose = Pose(bones=bones, model=model, dynamic=self._dynamic, pupils=pupils, flexors=f, mouth=shape)
        if dynamic:
            self.build_dynamic(pose)
        return pose

    def build_dynamic(self, pose: Pose, curves: np.ndarray | None = None) -> np.ndarray:
        """Write the brows and mouth of `pose` into its dynamic vertices (pose(..., dynamic=False) skips
        it); with `curves`, only the points the vertex shader builds them from (build_dynamic)."""
        assert pose.flexors is not None and pose.mouth is not None
        build_dynamic(pose.flexors, pose.mouth, self.layout, pose.dynamic, curves)
        return pose.dynamic

    def gaze_points(self, gaze: np.ndarray, model: np.ndarray) -> np.ndarray:
        """World positions of both pupil centres for each (look_x, look_y) row: shape (2, N, 3)."""
        gaze = np.asarray(gaze, dtype=np.float64).reshape(-1, 2)
        yaw = np.radians(-np.clip(gaze[:, 0], -1, 1) * self.units.look_x_deg)
        pitch = np.radians(np.clip(gaze[:, 1], -1, 1) * self.units.look_y_deg)
        # Ry(yaw) @ Rx(-pitch) applied to +z
        d = np.stack([np.sin(yaw) * np.cos(pitch), np.sin(pitch), np.cos(yaw) * np.cos(pitch)], -1)
        out = np.empty((2, gaze.shape[0], 3))
        for k, side in enumerate((1, -1)):
            p = self._centres[side] + d * EYE_RADIUS
            out[k] = p @ model[:3, :3].T + model[:3, 3]
        return out


def skin(vertices: np.ndarray, bones: np.ndarray, model: np.ndarray) -> np.ndarray:
    """World positions of vertices under a pose: the same blend the vertex shader does, for tests."""
    pos = np.concatenate([vertices[:, 0:3].astype(np.float64), np.ones((vertices.shape[0], 1))], axis=1)
    b0 = vertices[:, 10].astype(int)
    b1 = vertices[:, 11].astype(int)
    w = vertices[:, 12:13].astype(np.float64)
    p0 = np.einsum("nij,nj->ni", bones[b0], pos)
    p1 = np.einsum("nij,nj->ni", bones[b1], pos)
    blended = p0 * (1 - w) + p1 * w
    return (blended @ model.T)[:, :3]
