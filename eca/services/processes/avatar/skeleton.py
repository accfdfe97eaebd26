"""The node tree as a `Skeleton`: every node a joint, parents before children, with its rest local transform.

The tree is checked before it is walked: no node is its own child or the child of two parents, the scene's roots
are roots, no node sits more than `max_node_depth` levels down, and every node is reached from some root (one
that is not sits in a cycle). A node's rest transform is its `matrix` (column-major, affine) or T * R * S.

Face bones by name: a plain glTF has no humanoid map, so the head, neck, jaw and eye joints are found by their
names in the spellings rigs use (`Head`, `mixamorig:Neck`, `CC_Base_JawRoot`, `LeftEye`, `eye.L`, `J_Adj_L_FaceEye`,
`Eye_R` ...), never a node that holds a skinned mesh (its transform moves nothing). A VRM's own humanoid map wins;
names fill only the face bones it leaves out.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np
import pygltflib as gl

from eca.services.processes.avatar.errors import AvatarError
from eca.services.processes.avatar.limits import AvatarLimits

FACE_BONES = ("head", "neck", "jaw", "leftEye", "rightEye")


@dataclass(frozen=True)
class NodeTree:
    """The checked tree: `order` the glTF node of each joint (parents first), `joint_of` the joint of each node,
    `parents` each joint's parent joint (-1 for a root), `in_scene` whether a node is drawn (under the scene)."""

    order: tuple[int, ...]
    joint_of: np.ndarray  # (N,) int64
    parents: np.ndarray  # (J,) int32
    in_scene: np.ndarray  # (N,) bool


def build_tree(document: gl.GLTF2, limits: AvatarLimits) -> NodeTree:
    """The node tree of a checked document, refused when it is no tree or too deep; see the module docstring."""
    nodes = document.nodes
    n = len(nodes)
    parent = [-1] * n
    for i, node in enumerate(nodes):
        seen: set[int] = set()
        for child in node.children or ():
            if child == i:
                raise AvatarError(f"nodes[{i}] is its own child")
            if child in seen:
                raise AvatarError(f"nodes[{i}].children lists nodes[{child}] twice")
            seen.add(child)
            if parent[child] != -1:
                raise AvatarError(f"nodes[{child}] has two parents, nodes[{parent[child]}] and nodes[{i}]")
            parent[child] = i
    roots = [i for i in range(n) if parent[i] == -1]
    scene_roots = roots
    if document.scenes:
        s = document.scene if document.scene is not None else 0
        scene_roots = list(dict.fromkeys(document.scenes[s].nodes or ()))
        for r in scene_roots:
            if parent[r] != -1:
                raise AvatarError(f"scenes[{s}].nodes lists nodes[{r}], which is the child of nodes[{parent[r]}]")
    in_scene = np.zeros(n, dtype=bool)
    order: list[int] = []
    depth_of = [0] * n
    visited = np.zeros(n, dtype=bool)
    for group, drawn in ((scene_roots, True), (roots, False)):
        for root in group:
            if visited[root]:
                continue
            stack = [root]
            visited[root] = True
            while stack:
                i = stack.pop()
                order.append(i)
                in_scene[i] = drawn
                depth = depth_of[i]
                children = nodes[i].children or ()
                if children and depth >= limits.max_node_depth:
                    raise AvatarError(f"nodes[{i}] sits {depth} levels below a root; its children would be deeper "
                                      f"than the limit of {limits.max_node_depth} (max_node_depth)")
                for child in reversed(children):
                    visited[child] = True
                    depth_of[child] = depth + 1
                    stack.append(child)
    if len(order) < n:
        lost = int(np.flatnonzero(~visited)[0])
        raise AvatarError(f"nodes[{lost}] is in a cycle of children (no root leads to it)")
    joint_of = np.full(n, -1, dtype=np.int64)
    joint_of[np.array(order, dtype=np.int64)] = np.arange(n)
    parents = np.array([-1 if parent[i] < 0 else joint_of[parent[i]] for i in order], dtype=np.int32)
    return NodeTree(tuple(order), joint_of, parents, in_scene)


def quaternion_matrix(q: tuple[float, ...] | list[float]) -> np.ndarray:
    """The 3x3 rotation of a quaternion (x, y, z, w), normalised first."""
    x, y, z, w = (float(v) for v in q)
    norm = math.sqrt(x * x + y * y + z * z + w * w)
    x, y, z, w = x / norm, y / norm, z / norm, w / norm
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])  # fmt: skip


def rest_matrix(node: gl.Node, where: str) -> np.ndarray:
    """A node's local rest transform (parent from node), 4x4 float64."""
    if node.matrix is not None:
        matrix = np.array(node.matrix, dtype=np.float64).reshape(4, 4).T  # glTF stores columns
        if not np.allclose(matrix[3], (0.0, 0.0, 0.0, 1.0), atol=1e-6):
            raise AvatarError(f"{where}.matrix is not an affine transform (its last row is {matrix[3].tolist()})")
        matrix[3] = (0.0, 0.0, 0.0, 1.0)
        return matrix
    matrix = np.eye(4)
    matrix[:3, :3] = quaternion_matrix(node.rotation) * np.asarray(node.scale, dtype=np.float64)[None, :]
    matrix[:3, 3] = node.translation
    return matrix


def rest_transforms(document: gl.GLTF2, tree: NodeTree) -> np.ndarray:
    """(J, 4, 4) rest local transforms in joint order, refused when they or their products down the tree (what a
    drawer computes) overflow."""
    rest = np.empty((len(tree.order), 4, 4))
    for j, i in enumerate(tree.order):
        rest[j] = rest_matrix(document.nodes[i], f"nodes[{i}]")
    world = np.empty_like(rest)
    for j, parent in enumerate(tree.parents.tolist()):
        world[j] = rest[j] if parent < 0 else world[parent] @ rest[j]
    if not (np.isfinite(rest).all() and np.isfinite(world).all()):
        bad = int(np.flatnonzero(~np.isfinite(world).all(axis=(1, 2)))[0])
        raise AvatarError(f"the transform of nodes[{tree.order[bad]}] overflows to infinity")
    return rest


_SPLIT = re.compile(r"[^A-Za-z0-9]+")
_WORDS = re.compile(r"[A-Z]+(?![a-z])|[A-Z]?[a-z]+|\d+")
_NOT_THE_BONE = frozenset({"end", "top", "tip", "nub", "lid", "lids", "lash", "lashes", "brow", "brows", "blink",
                           "highlight", "hilight", "socket", "occlusion", "tear", "lens", "mesh", "geo", "target",
                           "ik", "ctrl", "control", "look", "aim", "null", "offset", "twist", "roll", "teeth",
                           "tongue", "shadow", "wet", "spec"})
_LEFT, _RIGHT = frozenset({"l", "left"}), frozenset({"r", "right"})


def name_words(name: str) -> list[str]:
    """A node name's words, lower case: `mixamorig:LeftEye` -> mixamorig, left, eye; `J_Adj_L_FaceEye` ->
    j, adj, l, face, eye."""
    return [w.lower() for part in _SPLIT.split(name[:200]) for w in _WORDS.findall(part)]


def face_bone_of(name: str) -> str | None:
    """Which face bone (FACE_BONES) a node's name says it is, if any."""
    words = name_words(name)
    if not words or _NOT_THE_BONE.intersection(words):
        return None
    core = [w for w in words if not w.isdigit()]
    if not core:
        return None
    if "eye" in core or "eyeball" in core:
        left, right = bool(_LEFT.intersection(core)), bool(_RIGHT.intersection(core))
        if left != right:
            return "leftEye" if left else "rightEye"
        return None
    if core[-1] == "head":
        return "head"
    if core[-1] == "neck":
        return "neck"
    if "jaw" in core:
        return "jaw"
    return None


def face_bones_by_name(document: gl.GLTF2, tree: NodeTree) -> dict[str, int]:
    """Face bone -> joint of the first node (parents first) whose name says it is that bone; see the module
    docstring."""
    found: dict[str, int] = {}
    for j, i in enumerate(tree.order):
        node = document.nodes[i]
        if node.skin is not None:
            continue
        bone = face_bone_of(node.name or "")
        if bone is not None and bone not in found:
            found[bone] = j
    return found
