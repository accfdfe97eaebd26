"""An avatar as data: what a glTF 2.0 or VRM (0.x, 1.0) file holds that eca draws and drives, apart from any GL.

The loader (loader.py) fills these from a file; the 3D drawer (eca/services/processes/renderer/head/) uploads
them once and moves them each frame from a rig frame (eca/agent/rig): morph-target weights by name, and the
rotations of the head, neck, jaw and eye joints. All arrays are numpy, read-only once built.

Frames and units are glTF's: right-handed, +Y up, +Z toward the viewer of a model facing the camera (glTF's
"front" is +Z), metres. A VRM 0.x model faces -Z; the loader turns it to face +Z, so every Avatar faces +Z.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import Enum

import numpy as np


class AlphaMode(Enum):
    OPAQUE = "OPAQUE"
    MASK = "MASK"
    BLEND = "BLEND"


@dataclass(frozen=True, eq=False)
class Texture:
    """An RGBA8 image, rows top to bottom, as decoded (sRGB for base colour)."""

    rgba: np.ndarray  # (height, width, 4) uint8


@dataclass(frozen=True, eq=False)
class Material:
    """What the drawer needs of a glTF material (metallic-roughness ignored but for roughness) or VRM MToon."""

    name: str
    base_color: tuple[float, float, float, float] = (1.0, 1.0, 1.0, 1.0)  # linear RGBA factor
    texture: Texture | None = None  # base colour texture, multiplied by the factor
    alpha_mode: AlphaMode = AlphaMode.OPAQUE
    alpha_cutoff: float = 0.5
    double_sided: bool = False
    roughness: float = 0.6
    toon: bool = False  # VRM MToon: drawn with a toon ramp instead of the physically based shade
    shade_color: tuple[float, float, float] = (0.6, 0.6, 0.6)  # MToon's shade colour (the dark side), linear


@dataclass(frozen=True, eq=False)
class MorphTarget:
    """One morph target of a primitive: position (and, where given, normal) deltas per vertex."""

    name: str  # as the file names it (extras.targetNames, or "target<k>")
    positions: np.ndarray  # (V, 3) float32
    normals: np.ndarray | None = None  # (V, 3) float32


@dataclass(frozen=True, eq=False)
class Primitive:
    """One drawable piece: triangles of one material, skinned or rigidly attached to a joint."""

    positions: np.ndarray  # (V, 3) float32, in the bind pose (skinned) or the node's frame (rigid)
    normals: np.ndarray  # (V, 3) float32
    indices: np.ndarray  # (3T,) uint32, triangles
    material: int  # index into Avatar.materials
    uvs: np.ndarray | None = None  # (V, 2) float32
    joints: np.ndarray | None = None  # (V, 4) uint16 indices into Avatar.skeleton.joints
    weights: np.ndarray | None = None  # (V, 4) float32, rows summing to 1
    node: int = -1  # for an unskinned primitive: the skeleton joint it moves with (-1: the model's root)
    targets: tuple[MorphTarget, ...] = ()
    mesh: int = 0  # index of the glTF mesh this primitive belongs to (expressions bind a mesh's targets)
    # (glTF node, index in its mesh's primitives) of the file: what a page that loads the same file itself finds it
    # by (web/browser_face.py); (-1, -1) for a primitive made in memory
    source: tuple[int, int] = (-1, -1)


@dataclass(frozen=True, eq=False)
class Skeleton:
    """The node tree, as joints: every node that moves anything (skin joints and the nodes of rigid meshes)."""

    names: tuple[str, ...]
    parents: np.ndarray  # (J,) int32, -1 for a root; a parent always comes before its children
    rest: np.ndarray  # (J, 4, 4) float64 local rest transforms (parent from child)
    inverse_bind: np.ndarray  # (J, 4, 4) float64 (identity for nodes that are no skin joint)
    humanoid: dict[str, int] = field(default_factory=dict)  # VRM humanoid bone name (head, neck, leftEye, ...) -> joint
    # the glTF node of each joint (the loader makes every node a joint, parents first); () when not from a file
    nodes: tuple[int, ...] = ()


class LookAtType(Enum):
    BONE = "bone"
    EXPRESSION = "expression"


@dataclass(frozen=True)
class RangeMap:
    """A VRM lookAt range map: output = min(|angle|, input_max_deg) / input_max_deg * output_scale."""

    input_max_deg: float = 90.0
    output_scale: float = 10.0


@dataclass(frozen=True)
class LookAt:
    """How the eyes turn: by the eye joints (bone) or by the look* expressions (expression), with VRM's maps."""

    type: LookAtType
    horizontal_inner: RangeMap = RangeMap()
    horizontal_outer: RangeMap = RangeMap()
    vertical_down: RangeMap = RangeMap()
    vertical_up: RangeMap = RangeMap()
    offset: tuple[float, float, float] = (0.0, 0.06, 0.0)  # from the head joint to between the eyes


class Override(Enum):
    """What an active expression does to the blink, lookAt or mouth expressions (VRM 1.0)."""

    NONE = "none"
    BLOCK = "block"
    BLEND = "blend"


@dataclass(frozen=True)
class MorphBind:
    """An expression's effect on one morph target: mesh, target index within each of its primitives, weight."""

    mesh: int
    target: int
    weight: float  # 0..1: the target's weight when the expression is at 1


@dataclass(frozen=True)
class Expression:
    """A VRM expression (or preset) under its VRM 1.0 name: happy, blink, aa, lookUp, ... or a custom name."""

    name: str
    binds: tuple[MorphBind, ...]
    is_binary: bool = False
    override_blink: Override = Override.NONE
    override_look_at: Override = Override.NONE
    override_mouth: Override = Override.NONE


@dataclass(frozen=True)
class Capabilities:
    """What the avatar can show, found at load (loader.check): the three required, the rest degrade."""

    eyes: str  # "bones", "arkit shapes" or "vrm lookAt"
    blink: str  # "arkit shapes" or "vrm blink"
    mouth: str  # "jaw bone", "arkit jawOpen", "visemes" or "vrm vowels"
    missing: tuple[str, ...] = ()  # what it lacks beyond that, said once at load (e.g. "brows: no brow shapes")


@dataclass(frozen=True, eq=False)
class Avatar:
    """Everything eca draws and drives of one model; see the module docstring."""

    name: str
    primitives: tuple[Primitive, ...]
    materials: tuple[Material, ...]
    skeleton: Skeleton
    expressions: dict[str, Expression]  # by VRM 1.0 name; empty for a plain glTF
    look_at: LookAt | None
    capabilities: Capabilities
    # morph target name (normalised: an ARKit name in PascalCase, viseme_*, or the file's own) -> the
    # (primitive index, target index) pairs that carry it
    shapes: dict[str, tuple[tuple[int, int], ...]] = field(default_factory=dict)
    source: str = "<memory>"  # the file it came from, for messages
    format: str = "gltf"  # what the file was: "gltf" (plain glTF 2.0), "vrm0" (VRM 0.x) or "vrm1" (VRM 1.0)
    license_url: str = ""  # a VRM 1.0's meta.licenseUrl (first 2048 characters)
