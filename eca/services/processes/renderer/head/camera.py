"""Framing a head: the two views of the 2D face ("full", "upper"), measured on the avatar itself.

The 2D face's framings (configs/render.toml [camera]) are in its own head's units; a model file may be a bare
head, a VRM's whole body, in metres or not. So the framing is measured from the avatar at rest: its head and
neck joints, its eye joints, and the bounds of the geometry that moves with the head.

- "full": the head and some neck, the face filling the picture as the 2D face's does (the head is about 80 %
  of the picture's height there; here the head is 79 %, with a little neck under the chin). The camera stays put;
  the head turns and nods in it.
- "upper": the eyes and brows (the paper's experiment view). Its size follows the distance between the eyes, as
  the 2D face's does (a picture 1.5 eye-distances high, the eyes a third of an eye-distance under its centre), and
  it follows the eyes as the head moves, so a nod or turn cannot take them out of the picture.

Both use the 2D face's lens (22 degrees vertically) and keep a 4:3 picture's width on narrower targets.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from eca.services.processes.avatar.model import Avatar
from eca.services.processes.renderer.common import perspective
from eca.services.processes.renderer.config import VIEWS
from eca.services.processes.renderer.head.skeleton import Posed

FOV_DEG = 22.0
FULL_NECK = 0.15  # of the head's height, of neck shown under the chin
FULL_MARGIN = 0.045  # of the picture's height, above the head and below the neck
UPPER_HEIGHT = 1.5  # eye distances
UPPER_ABOVE = 0.30  # the picture's centre this many eye distances above the eyes
HUMAN_EYE_DISTANCE = 0.063  # metres: when a model has no eye joints, its head's width gives a guess


@dataclass(frozen=True)
class HeadMeasure:
    """What framing needs of an avatar at rest, model frame."""

    top: float  # the top of the head (y)
    chin: float  # the lowest point of the head's front
    centre_x: float
    half_width: float  # the head's half-width
    centre_z: float  # where the full view's height is measured: the middle of the head's depth
    depth_z: float  # where the upper view's height is measured: the eyes' z
    eyes: np.ndarray  # (2, 3) the eyes' centres at rest (estimated when there are no eye joints)
    eye_joints: tuple[int, int]  # -1 where there is none
    head_joint: int
    head_rest_inverse: np.ndarray  # (4, 4) joint from model of the head at rest (identity without a head joint)

    @property
    def eye_distance(self) -> float:
        return float(np.linalg.norm(self.eyes[0] - self.eyes[1]))


def rest_positions(avatar: Avatar, posed: Posed) -> list[np.ndarray]:
    """Every primitive's vertices in the model frame at rest (skinned by the rest palette, or moved by its node)."""
    out = []
    g = posed.rest_global
    palette = g @ posed.inverse_bind
    for prim in avatar.primitives:
        p = np.asarray(prim.positions, dtype=np.float64)
        if prim.joints is not None and prim.weights is not None:
            w = np.asarray(prim.weights, dtype=np.float64)
            m = np.einsum("vk,vkij->vij", w, palette[np.asarray(prim.joints, dtype=np.intp)])
            p = np.einsum("vij,vj->vi", m[:, :3, :3], p) + m[:, :3, 3]
        elif prim.node >= 0:
            p = p @ g[prim.node, :3, :3].T + g[prim.node, :3, 3]
        out.append(p)
    return out


def measure(avatar: Avatar, posed: Posed, positions: list[np.ndarray] | None = None) -> HeadMeasure:
    """The head's measures (from `positions`, rest_positions' when given); a model without a head joint is taken
    as a head (or, if tall, the top of a body)."""
    positions = positions if positions is not None else rest_positions(avatar, posed)
    humanoid = avatar.skeleton.humanoid
    head = humanoid.get("head", -1)
    eye_joints = (humanoid.get("leftEye", -1), humanoid.get("rightEye", -1))
    points: list[np.ndarray] = []
    if head >= 0:
        below_head = set(posed.subtree([head]))
        for prim, p in zip(avatar.primitives, positions, strict=True):
            if prim.joints is not None and prim.weights is not None:
                joints = np.asarray(prim.joints, dtype=np.intp)
                on_head = np.isin(joints, list(below_head))
                share = (np.asarray(prim.weights) * on_head).sum(axis=1)
                points.append(p[share >= 0.5])
            elif prim.node in below_head:
                points.append(p)
    cloud = np.concatenate(points) if points and sum(len(p) for p in points) else np.concatenate(positions)
    if head < 0:
        lo, hi = cloud[:, 1].min(), cloud[:, 1].max()
        if hi - lo > 0.6 * (np.ptp(cloud[:, 0]) + 1e-9) * 4:  # much taller than wide: a body; its top eighth
            cloud = cloud[cloud[:, 1] >= hi - (hi - lo) / 8.0]
    top = float(cloud[:, 1].max())
    centre_x = float(posed.rest_global[head, 0, 3]) if head >= 0 else float(np.median(cloud[:, 0]))
    half_width = float(np.abs(cloud[:, 0] - centre_x).max())
    front_z = float(cloud[:, 2].max())
    front = cloud[cloud[:, 2] >= front_z - 0.5 * np.ptp(cloud[:, 2])]
    chin = float(front[:, 1].min())
    if all(j >= 0 for j in eye_joints):
        eyes = np.stack([posed.rest_global[j, :3, 3] for j in eye_joints])
    else:
        # No eye joints: a VRM lookAt's offset from the head, or two fifths down from the top of the head.
        half = max(half_width * 0.42, 1e-6)
        if head >= 0 and avatar.look_at is not None:
            mid = posed.rest_global[head, :3, 3] + np.asarray(avatar.look_at.offset)
        else:
            mid = np.array([centre_x, top - 0.42 * (top - chin), front_z - half])
        eyes = np.stack([mid + (half * 0.36, 0, 0), mid - (half * 0.36, 0, 0)])
    head_rest_inverse = np.linalg.inv(posed.rest_global[head]) if head >= 0 else np.eye(4)
    centre_z = 0.5 * float(cloud[:, 2].max() + cloud[:, 2].min())
    return HeadMeasure(top, chin, centre_x, half_width, centre_z, float(eyes[:, 2].mean()), eyes, eye_joints, head,
                       head_rest_inverse)


class HeadCamera:
    """View and projection matrices of a view at an aspect ratio (see the module docstring)."""

    def __init__(self, measure: HeadMeasure) -> None:
        self.measure = measure
        self._cache: dict[tuple[str, float, float, float], tuple[np.ndarray, np.ndarray]] = {}

    def eyes_now(self, globals_: np.ndarray) -> np.ndarray:
        """The eyes' midpoint under the posed joint transforms (the rest midpoint carried by the head)."""
        m = self.measure
        if all(j >= 0 for j in m.eye_joints):
            return 0.5 * (globals_[m.eye_joints[0], :3, 3] + globals_[m.eye_joints[1], :3, 3])
        mid = np.append(m.eyes.mean(axis=0), 1.0)
        if m.head_joint >= 0:
            return (globals_[m.head_joint] @ (m.head_rest_inverse @ mid))[:3]
        return mid[:3]

    def matrices(self, view: str, aspect: float, globals_: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(view, projection) for `view` at `aspect` (width / height); "upper" follows the posed eyes."""
        if view not in VIEWS:
            raise ValueError(f"unknown view {view!r}; choose one of {', '.join(VIEWS)}")
        m = self.measure
        if view == "full":
            neck = FULL_NECK * (m.top - m.chin)
            bottom = m.chin - neck
            inner = m.top - bottom
            height = max(inner / (1.0 - 2.0 * FULL_MARGIN), 2.3 * m.half_width / (4.0 / 3.0))
            cx, cy, cz = m.centre_x, 0.5 * (m.top + bottom), m.centre_z
        else:
            eyes = self.eyes_now(globals_) if globals_ is not None else m.eyes.mean(axis=0)
            d = m.eye_distance
            height = UPPER_HEIGHT * d
            cx, cy, cz = float(eyes[0]), float(eyes[1]) + UPPER_ABOVE * d, m.depth_z
        key = (view, aspect, round(cx, 7), round(cy, 7))
        if key not in self._cache:
            if len(self._cache) > 64:
                self._cache.clear()
            self._cache[key] = self._matrices(height, aspect, cx, cy, cz)
        return self._cache[key]

    def _matrices(self, height: float, aspect: float, cx: float, cy: float,
                  cz: float) -> tuple[np.ndarray, np.ndarray]:
        height *= max(1.0, (4.0 / 3.0) / aspect)  # keep a 4:3 picture's width on narrower targets
        distance = (height / 2.0) / math.tan(math.radians(FOV_DEG) / 2.0)
        z = cz + distance
        view_m = np.eye(4)
        view_m[:3, 3] = (-cx, -cy, -z)
        size = max(self.measure.top - self.measure.chin, 1e-6)
        near = max(distance - 2.0 * size, 0.05 * distance)
        proj = perspective(FOV_DEG, aspect, near, distance + 4.0 * size)
        view_m.flags.writeable = False
        proj.flags.writeable = False
        return view_m, proj


def avatar_framing(avatar: Avatar, aspect: float, view: str = "full") -> tuple[np.ndarray, np.ndarray]:
    """(view, projection) matrices of `view` for an avatar at rest, as the head drawer frames it: what a page that
    draws the same avatar itself (web/browser_face.py) puts its camera at."""
    return HeadCamera(measure(avatar, Posed(avatar.skeleton))).matrices(view, aspect)
