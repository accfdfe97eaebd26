"""`AvatarDriver`: a rig frame (eca/agent/rig/frame.py) as what a drawer applies to an Avatar each frame: a weight
per morph target of each primitive, and turns of the head, neck, jaw and eye joints.

Morph targets, by what the avatar has (capabilities.py; each part from one source, so nothing moves twice):

- targets named as ARKit shapes take the frame's ARKit weights, and so do the binds of a custom VRM expression
  named as one ("Perfect Sync"), with its bind weights; eyeLook shapes when the eyes turn by shapes, and with eyes
  turned by joints those that move the lids and skin around them (the lids follow the gaze) but not the eyeballs;
  eyeBlink shapes only when the blink is by shapes;
- `viseme_*` targets take the frame's visemes when the mouth is by visemes (no ARKit JawOpen: the ARKit mouth
  already carries the speech);
- VRM expressions take the frame's VRM presets through their binds: the emotions (and neutral) unless the face
  shows emotions by ARKit shapes (capabilities.Inventory.arkit_emotions), blink presets when the blink is VRM's,
  vowels when the mouth is VRM's, look* from the model's own lookAt range maps (expression type) with the eyes'
  mean direction. Then VRM 1.0's overrides (expressions.md): a binary expression counts as 0 or 1 (over 0.5);
  each category (blink, lookAt, mouth) is scaled by 1 - (the blocking expressions that are on + the blending
  expressions' weights), floored at 0, and a binary expression of the category is cut to 0 by any override;
- each target's weight is the sum of what reaches it, clipped to 0..1.

Joints (`turns`: rotations in the model's axes about each joint's own pivot, what the drawer's skeleton takes;
`local`: the same as each joint's local transform, rest @ turn, to put in place of Skeleton.rest[j]):

- the head's yaw, pitch and roll, 30 % on the neck and 70 % on the head (all on the head without a neck joint),
  as eca's VMC sender splits it;
- each eye joint by its own eye's angles (vergence kept), through the VRM lookAt range maps when the lookAt is of
  bone type (horizontal inner toward the nose, outer away from it, vertical up and down), as they are otherwise;
- a jaw joint by JawOpen (jaw_open_deg at 1, the chin down) when no ARKit JawOpen shape opens the mouth.

Sign conventions (glTF: +Y up, the model faces +Z, its left is +X; eca: yaw + toward the agent's right, pitch + up,
roll + toward the right shoulder): the turn is R = Ry(-yaw) @ Rx(-pitch) @ Rz(roll), i.e. a look to the agent's
right turns +Z toward -X, a look up turns +Z toward +Y, a roll to the right shoulder turns +Y toward -X; yaw after
pitch after roll (Unity's Euler order, as the VMC sender composes them). VRM's lookAt signs (yaw + = the model's
left, pitch + = down) are eca's negated. A joint whose rest axes point anywhere turns the same way: its local turn
is G^-1 R G for its rest orientation G in the model.

Pure numpy. `drive_many` poses many agents' frames of one avatar in one batch of array operations (the web
service's conversations, which share the default head); `drive` is a batch of one.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from eca.agent.rig.frame import RigBatch, RigFrame
from eca.agent.rig.names import (
    ARKIT_INDEX,
    ARKIT_NAMES,
    N_ARKIT,
    N_VISEMES,
    VRM_EMOTIONS,
    VRM_INDEX,
    VRM_VOWELS,
    viseme_index,
    viseme_names,
)
from eca.services.processes.avatar.capabilities import EYE_LOOKS_HORIZONTAL, EYE_LOOKS_VERTICAL, Inventory, inventory
from eca.services.processes.avatar.model import Avatar, LookAt, LookAtType, Override, Primitive, RangeMap
from eca.services.processes.avatar.skeleton import FACE_BONES

NECK_SHARE = 0.3  # of the head's turn, on the neck (eca's VMC sender: 30 % neck, 70 % head)
JAW_OPEN_DEG = 22.0  # a jaw joint's turn at JawOpen = 1: a wide-open human jaw drops about 20-25 degrees
BLINKS = ("blink", "blinkLeft", "blinkRight")
LOOKS = ("lookUp", "lookDown", "lookLeft", "lookRight")
_EYE_LOOKS = frozenset(EYE_LOOKS_HORIZONTAL + EYE_LOOKS_VERTICAL)
_BLINK_SHAPES = frozenset({"EyeBlinkLeft", "EyeBlinkRight"})
_VISEMES_AT = N_ARKIT
_GLTF_VISEMES = frozenset(viseme_names("gltf"))
_EXPRESSIONS_AT = N_ARKIT + N_VISEMES


def rotation_x(deg: np.ndarray | float) -> np.ndarray:
    """(..., 3, 3) the turn about the model's x axis by each angle (degrees)."""
    a = np.radians(np.asarray(deg, dtype=np.float64))
    c, s = np.cos(a), np.sin(a)
    m = np.zeros(a.shape + (3, 3))
    m[..., 0, 0] = 1.0
    m[..., 1, 1], m[..., 1, 2], m[..., 2, 1], m[..., 2, 2] = c, -s, s, c
    return m


def agent_rotation(yaw_deg: np.ndarray | float, pitch_deg: np.ndarray | float,
                   roll_deg: np.ndarray | float = 0.0) -> np.ndarray:
    """(..., 3, 3) the rotation in glTF model axes of eca's yaw, pitch and roll (see the module docstring), for
    each of (broadcast) arrays of them: Ry(-yaw) @ Rx(-pitch) @ Rz(roll), multiplied out (equal to the matrix
    products to the last bit or so; entry by entry: a few joints a frame cost more in numpy calls than in
    arithmetic)."""
    a, b, g = np.broadcast_arrays(np.radians(-np.asarray(yaw_deg, dtype=np.float64)),
                                  np.radians(-np.asarray(pitch_deg, dtype=np.float64)),
                                  np.radians(np.asarray(roll_deg, dtype=np.float64)))
    ca, sa, cb, sb, cg, sg = np.cos(a), np.sin(a), np.cos(b), np.sin(b), np.cos(g), np.sin(g)
    # Ry(-yaw) @ Rx(-pitch) has columns (ca, 0, -sa), (sa sb, cb, ca sb), (sa cb, -sb, ca cb); the roll mixes the
    # first two: c0 cg + c1 sg and c1 cg - c0 sg
    p, q = sa * sb, ca * sb
    m = np.empty(a.shape + (3, 3))
    m[..., 0, 0], m[..., 1, 0], m[..., 2, 0] = ca * cg + p * sg, cb * sg, q * sg - sa * cg
    m[..., 0, 1], m[..., 1, 1], m[..., 2, 1] = p * cg - ca * sg, cb * cg, q * cg + sa * sg
    m[..., 0, 2], m[..., 1, 2], m[..., 2, 2] = sa * cb, -sb, ca * cb
    return m


def _mapped(angle: float, m: RangeMap) -> float:
    """A range map of |angle|: min(|a|, inputMaxValue) / inputMaxValue * outputScale (VRM lookAt.md)."""
    return min(abs(angle), m.input_max_deg) / m.input_max_deg * m.output_scale


def expression_look(yaw_deg: float, pitch_deg: float, look_at: LookAt) -> tuple[float, float, float, float]:
    """An expression-type VRM lookAt's weights (lookUp, lookDown, lookLeft, lookRight) for a direction in eca's
    signs: both horizontal looks through horizontal outer (lookAt.md), each clipped to 0..1."""
    up = _mapped(pitch_deg, look_at.vertical_up) if pitch_deg > 0.0 else 0.0
    down = _mapped(pitch_deg, look_at.vertical_down) if pitch_deg < 0.0 else 0.0
    left = _mapped(yaw_deg, look_at.horizontal_outer) if yaw_deg < 0.0 else 0.0  # the agent's (model's) left
    right = _mapped(yaw_deg, look_at.horizontal_outer) if yaw_deg > 0.0 else 0.0
    return tuple(min(max(w, 0.0), 1.0) for w in (up, down, left, right))  # type: ignore[return-value]


def bone_look(yaw_deg: np.ndarray, pitch_deg: np.ndarray, look_at: LookAt,
              left_eye: bool) -> tuple[np.ndarray, np.ndarray]:
    """A bone-type VRM lookAt's turn of one eye, in eca's signs (degrees), for arrays of that eye's angles in eca's
    signs: the yaw through horizontal outer when the eye turns away from the nose (the left eye toward the agent's
    left), inner toward it; the pitch through vertical up or down (lookAt.md's table; each a range map of |angle|:
    min(|a|, inputMaxValue) / inputMaxValue * outputScale)."""
    outward = yaw_deg < 0.0 if left_eye else yaw_deg > 0.0
    outer, inner = look_at.horizontal_outer, look_at.horizontal_inner
    up, down = look_at.vertical_up, look_at.vertical_down
    h_max = np.where(outward, outer.input_max_deg, inner.input_max_deg)
    h_scale = np.where(outward, outer.output_scale, inner.output_scale)
    v_up = pitch_deg > 0.0
    v_max = np.where(v_up, up.input_max_deg, down.input_max_deg)
    v_scale = np.where(v_up, up.output_scale, down.output_scale)
    yaw = np.minimum(np.abs(yaw_deg), h_max) / h_max * h_scale
    pitch = np.minimum(np.abs(pitch_deg), v_max) / v_max * v_scale
    return np.copysign(yaw, yaw_deg), np.copysign(pitch, pitch_deg)


def _batch_of(frame: RigFrame) -> RigBatch:
    """One frame as a batch of one."""
    left, right = frame.left_eye, frame.right_eye
    return RigBatch(frame.t_ns, frame.arkit[None], np.array([frame.head_deg]),
                    np.array([[left.yaw_deg, left.pitch_deg, right.yaw_deg, right.pitch_deg]]),
                    frame.visemes[None], frame.vrm[None])


@dataclass(frozen=True, eq=False)
class BatchPose:
    """Many frames' poses (AvatarDriver.drive_many): `flat` (N, targets) float32 morph weights; `turns` and `local`
    joint -> (N, 3, 3): its turn, and the rotation part of its local transform (rest @ turn), as AvatarPose's."""

    flat: np.ndarray
    turns: dict[int, np.ndarray]
    local: dict[int, np.ndarray]


@dataclass(frozen=True, eq=False)
class AvatarPose:
    """One frame's pose (see the module docstring): `weights[p]` primitive p's morph weights (float32, 0..1, one per
    target; views of `flat`), `turns` joint -> 3x3 rotation in model axes about the joint's pivot, `local` joint
    -> 4x4 local transform (the joint's rest with its turn) for the same joints."""

    weights: tuple[np.ndarray, ...]
    turns: dict[int, np.ndarray]
    local: dict[int, np.ndarray]
    flat: np.ndarray


def moves_the_eyeballs(prim: Primitive, target: int, eye_joints: set[int]) -> bool:
    """Whether most of a morph target's motion is on vertices that ride the eye joints (an eyeball turned by a
    shape), rather than on the lids and the skin around the eyes."""
    moved = np.sqrt((prim.targets[target].positions.astype(np.float64) ** 2).sum(axis=1))
    total = float(moved.sum())
    if total == 0.0 or not eye_joints:
        return False
    if prim.joints is None or prim.weights is None:
        return prim.node in eye_joints
    riding = (np.isin(prim.joints, list(eye_joints)) * prim.weights).sum(axis=1)
    return float((moved * riding).sum()) > 0.5 * total


class AvatarDriver:
    """Turns rig frames into an avatar's poses; see the module docstring. `drive(frame)` -> AvatarPose."""

    def __init__(self, avatar: Avatar, neck_share: float = NECK_SHARE, jaw_open_deg: float = JAW_OPEN_DEG) -> None:
        if not (0.0 <= neck_share <= 1.0 and math.isfinite(jaw_open_deg)):
            raise ValueError(f"neck_share must be within 0..1 and jaw_open_deg finite, got {neck_share}, "
                             f"{jaw_open_deg}")
        self.avatar = avatar
        self.neck_share = float(neck_share)
        self.jaw_open_deg = float(jaw_open_deg)
        caps = avatar.capabilities
        bones = {b: j for b, j in avatar.skeleton.humanoid.items() if b in FACE_BONES}
        self.inventory: Inventory = inventory(avatar.shapes, avatar.expressions, bones, avatar.look_at)
        inv = self.inventory

        counts = [len(p.targets) for p in avatar.primitives]
        self._offsets = np.concatenate([[0], np.cumsum(counts, dtype=np.int64)]).astype(np.int64)
        self.n_targets = int(self._offsets[-1])
        self._slices = [(int(a), int(b)) for a, b in zip(self._offsets[:-1], self._offsets[1:], strict=True)]
        by_mesh: dict[int, list[int]] = {}
        for p, prim in enumerate(avatar.primitives):
            by_mesh.setdefault(prim.mesh, []).append(p)

        names = list(avatar.expressions)
        self._expression_names = tuple(names)
        entries: dict[tuple[int, int], float] = {}

        eye_joints = {j for b, j in bones.items() if b in ("leftEye", "rightEye")}

        def allowed(arkit: str, p: int, t: int) -> bool:
            if arkit in _EYE_LOOKS:
                # Eyes turned by their joints still want the eyeLook shapes that move the lids and the skin around
                # the eyes (the lids follow the gaze: Face Units' and most ARKit heads'); only a shape that turns
                # the eyeball itself would turn it twice.
                return caps.eyes == "arkit shapes" or (
                    caps.eyes == "bones" and not moves_the_eyeballs(avatar.primitives[p], t, eye_joints))
            if arkit in _BLINK_SHAPES:
                return caps.blink == "arkit shapes"
            return True

        for name in ARKIT_NAMES:  # targets named as ARKit shapes
            for p, t in avatar.shapes.get(name, ()):
                if allowed(name, p, t):
                    entries[(int(self._offsets[p]) + t, ARKIT_INDEX[name])] = 1.0
        def reached(mesh: int, target: int) -> list[int]:
            # the primitives of the mesh a bind names that have its target (an Avatar not from the loader may err)
            return [p for p in by_mesh.get(mesh, ()) if 0 <= target < counts[p]]

        for arkit, expression_name in inv.arkit_expressions.items():  # custom expressions named as ARKit shapes
            for bind in avatar.expressions[expression_name].binds:
                for p in reached(bind.mesh, bind.target):
                    if allowed(arkit, p, bind.target):
                        entries[(int(self._offsets[p]) + bind.target, ARKIT_INDEX[arkit])] = bind.weight
        if caps.mouth == "visemes":
            for name, pairs in avatar.shapes.items():
                if name in _GLTF_VISEMES:
                    column = _VISEMES_AT + viseme_index(name)
                    for p, t in pairs:
                        entries[(int(self._offsets[p]) + t, column)] = 1.0

        active = self._active_expressions(caps.eyes, caps.blink, caps.mouth)
        from_vrm: list[tuple[int, int]] = []
        self._look_at_rows: tuple[int, int, int, int] | None = None
        for k, name in enumerate(names):
            if name not in active:
                continue
            column = _EXPRESSIONS_AT + k
            for bind in avatar.expressions[name].binds:
                for p in reached(bind.mesh, bind.target):
                    key = (int(self._offsets[p]) + bind.target, column)
                    entries[key] = entries.get(key, 0.0) + bind.weight
            if name not in LOOKS:
                from_vrm.append((k, VRM_INDEX[name]))
        if caps.eyes == "vrm lookAt" and avatar.look_at is not None:
            self._look_at_rows = tuple(names.index(n) if n in names else -1 for n in LOOKS)  # type: ignore[assignment]
        self._from_vrm_k = np.array([k for k, _ in from_vrm], dtype=np.intp)
        self._from_vrm_src = np.array([s for _, s in from_vrm], dtype=np.intp)

        keys = list(entries)
        self._rows = np.array([r for r, _ in keys], dtype=np.intp)
        self._cols = np.array([c for _, c in keys], dtype=np.intp)
        self._vals = np.array([entries[k] for k in keys], dtype=np.float64)
        # the same table as a (source, target) matrix: many frames' weights in one product
        self._dense = np.zeros((_EXPRESSIONS_AT + len(names), self.n_targets))
        self._dense[self._cols, self._rows] = self._vals  # (target, source) pairs are unique: dict keys
        self._build_overrides(names)
        self._build_joints(bones, caps.eyes)

    def source_table(self) -> tuple[np.ndarray, np.ndarray]:
        """(target, source) pairs of what reaches what: flat target indices and source columns (the frame's 52
        ARKit weights, then its visemes, then the avatar's expressions in Avatar.expressions order)."""
        return self._rows.copy(), self._cols.copy()

    def target_slice(self, primitive: int) -> tuple[int, int]:
        """Where primitive `primitive`'s targets are in AvatarPose.flat."""
        return self._slices[primitive]

    def _active_expressions(self, eyes: str, blink: str, mouth: str) -> set[str]:
        """The VRM expressions a frame drives (see the module docstring); custom ones never."""
        inv = self.inventory
        active: set[str] = set()
        if not inv.arkit_emotions:
            active.update(VRM_EMOTIONS + ("neutral",))
        if blink == "vrm blink":
            active.update(BLINKS)
        if mouth == "vrm vowels":
            active.update(VRM_VOWELS)
        if eyes == "vrm lookAt":
            active.update(LOOKS)
        return active & set(self.avatar.expressions) - set(inv.arkit_expressions.values())

    def _build_overrides(self, names: list[str]) -> None:
        expressions = self.avatar.expressions
        n = len(names)
        self._binary = np.array([expressions[name].is_binary for name in names], dtype=bool)
        self._any_binary = bool(self._binary.any())
        self._categories: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []
        for members, attribute in ((BLINKS, "override_blink"), (LOOKS, "override_look_at"),
                                   (VRM_VOWELS, "override_mouth")):
            member = np.array([name in members for name in names], dtype=bool)
            # an override of the category's own kind counts for nothing (expressions.md)
            kinds = [Override.NONE if member[k] else getattr(expressions[name], attribute)
                     for k, name in enumerate(names)]
            block = np.array([o is Override.BLOCK for o in kinds], dtype=bool)
            blend = np.array([o is Override.BLEND for o in kinds], dtype=bool)
            if n and member.any() and (block.any() or blend.any()):
                self._categories.append((member, block, blend, member & self._binary))

    def _build_joints(self, bones: dict[str, int], eyes: str) -> None:
        skeleton = self.avatar.skeleton
        rest = np.asarray(skeleton.rest, dtype=np.float64)
        world = np.empty_like(rest)
        for j, parent in enumerate(np.asarray(skeleton.parents).tolist()):
            world[j] = rest[j] if parent < 0 else world[parent] @ rest[j]
        self._rest = rest
        self._frames: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # joint -> (G, G^-1)
        self.head = bones.get("head", -1)
        self.neck = bones.get("neck", -1) if self.head >= 0 else -1
        if eyes == "bones":
            self.eyes = (bones.get("leftEye", -1), bones.get("rightEye", -1))
        else:
            self.eyes = (-1, -1)
        self.jaw = bones.get("jaw", -1) if "JawOpen" not in self.inventory.arkit else -1
        look_at = self.avatar.look_at
        self.eye_maps = look_at if look_at is not None and look_at.type is LookAtType.BONE else None
        for joint in (self.head, self.neck, self.jaw, *self.eyes):
            if joint >= 0:
                g = world[joint, :3, :3]
                try:
                    g_inv = np.linalg.inv(g)
                except np.linalg.LinAlgError:
                    u, _, vt = np.linalg.svd(g)  # a joint scaled to nothing: turn it by its orientation alone
                    g = u @ vt
                    g_inv = g.T
                self._frames[joint] = (g, g_inv)

    def drive(self, frame: RigFrame) -> AvatarPose:
        """The avatar's pose for `frame`; see the module docstring. One frame is a batch of one (drive_many)."""
        many = self.drive_many(_batch_of(frame), [0])
        flat = many.flat[0]
        local = {}
        for joint, rotation in many.local.items():
            transform = self._rest[joint].copy()
            transform[:3, :3] = rotation[0]
            local[joint] = transform
        return AvatarPose(tuple(flat[a:b] for a, b in self._slices), {j: t[0] for j, t in many.turns.items()},
                          local, flat)

    def expression_weights(self, frame: RigFrame) -> np.ndarray:
        """The avatar's expressions' weights for `frame` (Avatar.expressions order), overrides applied."""
        weights: np.ndarray = self._expression_weights(_batch_of(frame), np.zeros(1, dtype=np.intp))[0]
        return weights

    def drive_many(self, batch: RigBatch, rows: Sequence[int]) -> BatchPose:
        """The poses of `batch`'s rows `rows` at once (see the module docstring): a fraction of the cost per face
        when many agents share one avatar (the web service's conversations)."""
        at = np.asarray(rows, dtype=np.intp)
        n = len(at)
        sources = np.empty((n, self._dense.shape[0]))
        sources[:, :N_ARKIT] = batch.arkit[at]
        sources[:, _VISEMES_AT:_EXPRESSIONS_AT] = batch.visemes[at]
        if len(self._expression_names):
            sources[:, _EXPRESSIONS_AT:] = self._expression_weights(batch, at)
        flat = sources @ self._dense
        np.clip(flat, 0.0, 1.0, out=flat)

        yaw, pitch, roll = batch.head_deg[at].T
        eyes = batch.eyes_deg[at]
        turns: dict[int, np.ndarray] = {}
        if self.head >= 0:
            share = self.neck_share if self.neck >= 0 else 0.0
            if share > 0.0:
                turns[self.neck] = agent_rotation(share * yaw, share * pitch, share * roll)
            rest_share = 1.0 - share
            turns[self.head] = agent_rotation(rest_share * yaw, rest_share * pitch, rest_share * roll)
        for joint, column, left in ((self.eyes[0], 0, True), (self.eyes[1], 2, False)):
            if joint >= 0:
                e_yaw, e_pitch = eyes[:, column], eyes[:, column + 1]
                if self.eye_maps is not None:
                    e_yaw, e_pitch = bone_look(e_yaw, e_pitch, self.eye_maps, left)
                turns[joint] = agent_rotation(e_yaw, e_pitch)
        if self.jaw >= 0:
            turns[self.jaw] = rotation_x(self.jaw_open_deg * batch.arkit[at, ARKIT_INDEX["JawOpen"]])
        local = {}
        for joint, turn in turns.items():
            g, g_inv = self._frames[joint]
            local[joint] = self._rest[joint, :3, :3] @ (g_inv @ turn @ g)
        return BatchPose(flat.astype(np.float32), turns, local)

    def _expression_weights(self, batch: RigBatch, at: np.ndarray) -> np.ndarray:
        """The avatar's expressions' weights (Avatar.expressions order) of `batch`'s rows `at`, overrides applied."""
        e = np.zeros((len(at), len(self._expression_names)))
        if self._from_vrm_k.size:
            e[:, self._from_vrm_k] = batch.vrm[at][:, self._from_vrm_src]
        if self._look_at_rows is not None:
            assert self.avatar.look_at is not None
            eyes = batch.eyes_deg[at]
            for i in range(len(at)):
                yaw = 0.5 * (float(eyes[i, 0]) + float(eyes[i, 2]))
                pitch = 0.5 * (float(eyes[i, 1]) + float(eyes[i, 3]))
                for k, w in zip(self._look_at_rows, expression_look(yaw, pitch, self.avatar.look_at), strict=True):
                    if k >= 0:
                        e[i, k] = w
        if self._any_binary:
            e[:, self._binary] = (e[:, self._binary] > 0.5).astype(np.float64)
        for member, block, blend, binary_member in self._categories:
            amount = np.count_nonzero(e[:, block] > 0.0, axis=1) + e[:, blend].sum(axis=1)
            factor = np.maximum(0.0, 1.0 - amount)
            overridden = factor < 1.0
            e[np.ix_(overridden, member)] *= factor[overridden, None]
            e[np.ix_(overridden, binary_member)] = 0.0
        return e

    def local_transforms(self, pose: AvatarPose) -> np.ndarray:
        """(J, 4, 4) every joint's local transform under `pose` (the rest pose but for the turned joints)."""
        out = self._rest.copy()
        for joint, transform in pose.local.items():
            out[joint] = transform
        return out
