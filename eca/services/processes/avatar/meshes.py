"""Meshes as drawable `Primitive`s: positions, normals (computed when missing), UVs, triangle indices (generated
for non-indexed geometry, strips and fans unrolled), skin joints and weights, and morph targets with the names the
file gives them.

Every primitive of every mesh on a node under the scene becomes one Primitive (a mesh on two nodes: twice). Before
a primitive's data is read its vertex count, its index count and its morph targets are checked against the
limits, per primitive and over the whole model, so a file cannot make the loader allocate more than the limits
allow however its accessors are shared. Indices are checked against the vertex count, joint indices against the
skin's joints, every float for finiteness.

Skins: eca keeps one inverse bind matrix per joint (Skeleton.inverse_bind). Two skins that bind a joint
differently by one common transform (a mesh bound in another place) are reconciled by moving that skin's
vertices; binds that disagree otherwise are refused.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pygltflib as gl

from eca.services.processes.avatar.accessors import AccessorReader
from eca.services.processes.avatar.errors import AvatarError
from eca.services.processes.avatar.limits import AvatarLimits
from eca.services.processes.avatar.model import MorphTarget, Primitive
from eca.services.processes.avatar.skeleton import NodeTree

# glTF's 180-degree turn about +Y, as a sign per coordinate: a VRM 0.x model faces -Z, every Avatar faces +Z.
TURN = np.array([-1.0, 1.0, -1.0])
TURN_4X4 = np.outer(np.append(TURN, 1.0), np.append(TURN, 1.0))  # R @ M @ R for R = diag(-1, 1, -1, 1)


@dataclass
class Notes:
    """What the loader noticed but took (said once, as one logging warning), bounded in number."""

    limit: int = 20
    lines: list[str] = field(default_factory=list)
    dropped: int = 0

    def add(self, line: str) -> None:
        if len(self.lines) < self.limit:
            self.lines.append(line)
        else:
            self.dropped += 1

    def text(self) -> str:
        more = f"; and {self.dropped} more" if self.dropped else ""
        return "; ".join(self.lines) + more


@dataclass(frozen=True)
class SkinBinds:
    """Each skin's joints as skeleton joints, the vertex transform that rebinds its meshes (None: none needed),
    and the skeleton's inverse bind matrices."""

    joints: tuple[np.ndarray, ...]  # per skin: (n,) int64 skeleton joint of each skin joint
    rebind: tuple[np.ndarray | None, ...]  # per skin: 4x4 applied to its vertices, or None
    inverse_bind: np.ndarray  # (J, 4, 4)


def build_skins(document: gl.GLTF2, reader: AccessorReader, tree: NodeTree, limits: AvatarLimits) -> SkinBinds:
    """Each skin's joint map and inverse binds, merged into one inverse bind per joint; see the module docstring."""
    n_joints = len(tree.order)
    inverse_bind = np.tile(np.eye(4), (n_joints, 1, 1))
    bound_by = np.full(n_joints, -1, dtype=np.int64)
    joint_maps: list[np.ndarray] = []
    rebinds: list[np.ndarray | None] = []
    for s, skin in enumerate(document.skins):
        where = f"skins[{s}]"
        joints = tree.joint_of[np.asarray(skin.joints, dtype=np.int64)]
        if len(set(joints.tolist())) != len(joints):
            raise AvatarError(f"{where}.joints lists a node twice")
        if skin.inverseBindMatrices is None:
            binds = np.tile(np.eye(4), (len(joints), 1, 1))
        else:
            flat = reader.read(skin.inverseBindMatrices, f"{where}.inverseBindMatrices", (gl.MAT4,),
                               limits.max_joints, "max_joints")
            if flat.shape[0] < len(joints):
                raise AvatarError(f"{where}.inverseBindMatrices holds {flat.shape[0]} matrices for "
                                  f"{len(joints)} joints")
            binds = flat[: len(joints)].astype(np.float64).reshape(-1, 4, 4).transpose(0, 2, 1)
        shared = bound_by[joints] >= 0
        rebind = None
        if shared.any():
            first = int(np.flatnonzero(shared)[0])
            other = int(bound_by[joints[first]])
            try:
                rebind = np.linalg.inv(inverse_bind[joints[first]]) @ binds[first]
            except np.linalg.LinAlgError:
                raise AvatarError(f"{where}: the inverse bind matrix of nodes[{skin.joints[first]}] is singular") \
                    from None
            expected = inverse_bind[joints[shared]] @ rebind
            scale = max(1.0, float(np.abs(binds[shared]).max()))
            if not np.allclose(expected, binds[shared], atol=1e-4 * scale):
                raise AvatarError(f"{where} binds its joints otherwise than skins[{other}] does, beyond one common "
                                  "transform (eca keeps one inverse bind matrix per joint)")
            if np.allclose(rebind, np.eye(4), atol=1e-6):
                rebind = None
            else:
                try:
                    binds = binds @ np.linalg.inv(rebind)
                except np.linalg.LinAlgError:
                    raise AvatarError(f"{where}: its binds differ from skins[{other}]'s by a singular transform") \
                        from None
        fresh = ~shared
        inverse_bind[joints[fresh]] = binds[fresh]
        bound_by[joints[fresh]] = s
        joint_maps.append(joints)
        rebinds.append(rebind)
    if not np.isfinite(inverse_bind).all():
        raise AvatarError("an inverse bind matrix overflows to infinity")
    return SkinBinds(tuple(joint_maps), tuple(rebinds), inverse_bind)


@dataclass
class _Target:
    name: str
    positions: np.ndarray
    normals: np.ndarray | None


@dataclass
class _Budget:
    vertices: int = 0
    indices: int = 0
    targets: int = 0
    target_vertices: int = 0


def build_primitives(document: gl.GLTF2, reader: AccessorReader, tree: NodeTree, skins: SkinBinds,
                     limits: AvatarLimits, notes: Notes, turn: bool) -> tuple[list[Primitive], bool]:
    """The drawable primitives of every mesh on a node under the scene, in joint order, and whether one of them
    has no material (the loader adds a default one at index len(materials)); `turn` turns them to face +Z."""
    primitives: list[Primitive] = []
    budget = _Budget()
    needs_default = False
    for joint, node_index in enumerate(tree.order):
        node = document.nodes[node_index]
        if node.mesh is None or not tree.in_scene[node_index]:
            continue
        mesh = document.meshes[node.mesh]
        for p, prim in enumerate(mesh.primitives):
            where = f"meshes[{node.mesh}].primitives[{p}]"
            built = _primitive(document, reader, prim, where, node, joint, skins, limits, budget, notes, turn,
                               mesh_names=_target_names(mesh.extras), prim_names=_target_names(prim.extras),
                               mesh_index=node.mesh, source=(node_index, p))
            if built is not None:
                needs_default = needs_default or prim.material is None
                primitives.append(built)
    return primitives, needs_default


def _target_names(extras: object) -> list[object] | None:
    names = extras.get("targetNames") if isinstance(extras, dict) else None
    return names if isinstance(names, list) else None


def _primitive(document: gl.GLTF2, reader: AccessorReader, prim: gl.Primitive, where: str, node: gl.Node, joint: int,
               skins: SkinBinds, limits: AvatarLimits, budget: _Budget, notes: Notes, turn: bool,
               mesh_names: list[object] | None, prim_names: list[object] | None, mesh_index: int,
               source: tuple[int, int] = (-1, -1)) -> Primitive | None:
    attributes = prim.attributes
    mode = int(prim.mode if prim.mode is not None else gl.TRIANGLES)
    if mode not in (gl.TRIANGLES, gl.TRIANGLE_STRIP, gl.TRIANGLE_FAN):
        notes.add(f"{where} draws points or lines (mode {mode}): left out")
        return None
    position = getattr(attributes, "POSITION", None)
    if position is None:
        notes.add(f"{where} has no POSITION: left out")
        return None
    n = reader.count(position)
    if n > limits.max_vertices:
        raise AvatarError(f"{where}.attributes.POSITION has {n} vertices, more than the limit of "
                          f"{limits.max_vertices} (max_vertices)")
    budget.vertices += n
    if budget.vertices > limits.max_total_vertices:
        raise AvatarError(f"the primitives hold more than {limits.max_total_vertices} vertices in all "
                          "(max_total_vertices)")
    targets_raw = list(prim.targets or [])
    budget.targets += len(targets_raw)
    if budget.targets > limits.max_total_targets:
        raise AvatarError(f"the primitives hold more than {limits.max_total_targets} morph targets in all "
                          "(max_total_targets)")
    budget.target_vertices += n * len(targets_raw)
    if budget.target_vertices > limits.max_total_target_vertices:
        raise AvatarError(f"the morph targets hold more than {limits.max_total_target_vertices} vertices in all "
                          "(max_total_target_vertices)")
    if n == 0:
        return None

    def vertex_attribute(index: int, name: str, types: tuple[str, ...]) -> np.ndarray:
        values = reader.read(index, f"{where}.{name}", types, limits.max_vertices, "max_vertices")
        if values.shape[0] != n:
            raise AvatarError(f"{where}.{name} has {values.shape[0]} elements, POSITION has {n}")
        return values

    positions = vertex_attribute(position, "attributes.POSITION", (gl.VEC3,))
    budget.indices += n if prim.indices is None else reader.count(prim.indices)
    if budget.indices > limits.max_total_indices:
        raise AvatarError(f"the primitives hold more than {limits.max_total_indices} indices in all "
                          "(max_total_indices)")
    indices = _indices(reader, prim, where, n, mode, limits)
    normal_index = getattr(attributes, "NORMAL", None)
    if normal_index is not None:
        normals = _unit(vertex_attribute(normal_index, "attributes.NORMAL", (gl.VEC3,)))
    else:
        normals = vertex_normals(positions, indices)
    uv_index = getattr(attributes, "TEXCOORD_0", None)
    uvs = vertex_attribute(uv_index, "attributes.TEXCOORD_0", (gl.VEC2,)) if uv_index is not None else None

    joints = weights = None
    rebind = None
    if node.skin is not None:
        if getattr(attributes, "JOINTS_0", None) is None or getattr(attributes, "WEIGHTS_0", None) is None:
            notes.add(f"{where} is on a skinned node but has no JOINTS_0/WEIGHTS_0: drawn with the node")
        else:
            joints, weights = _skinning(reader, attributes, where, n, skins.joints[node.skin], limits)
            rebind = skins.rebind[node.skin]

    names = prim_names if prim_names is not None and len(prim_names) == len(targets_raw) else mesh_names
    if targets_raw and names is not None and len(names) != len(targets_raw):
        notes.add(f"{where}: {len(names)} targetNames for {len(targets_raw)} morph targets")
    targets = []
    for t, target in enumerate(targets_raw):
        twhere = f"targets[{t}]"
        t_positions = (vertex_attribute(target["POSITION"], f"{twhere}.POSITION", (gl.VEC3,))
                       if "POSITION" in target else np.zeros((n, 3), dtype=np.float32))
        t_normals = (vertex_attribute(target["NORMAL"], f"{twhere}.NORMAL", (gl.VEC3,))
                     if "NORMAL" in target else None)
        given = names[t] if names is not None and t < len(names) else None
        targets.append(_Target(given if isinstance(given, str) else f"target{t}", t_positions, t_normals))

    if rebind is not None:  # this skin's vertices, moved to where the skeleton's inverse binds expect them
        linear = rebind[:3, :3]
        normal_matrix = np.linalg.inv(linear).T
        positions = (positions @ linear.T + rebind[:3, 3]).astype(np.float32)
        normals = _unit((normals @ normal_matrix.T).astype(np.float32))
        for target in targets:
            target.positions = (target.positions @ linear.T).astype(np.float32)
            if target.normals is not None:
                target.normals = (target.normals @ normal_matrix.T).astype(np.float32)
    if turn:
        flip = TURN.astype(np.float32)
        positions, normals = positions * flip, normals * flip
        for target in targets:
            target.positions = target.positions * flip
            if target.normals is not None:
                target.normals = target.normals * flip
    for array in (positions, normals):
        if not np.isfinite(array).all():
            raise AvatarError(f"{where}: its vertices overflow to infinity once bound")
    return Primitive(
        positions=_frozen(positions.astype(np.float32)),
        normals=_frozen(normals.astype(np.float32)),
        indices=_frozen(indices),
        material=len(document.materials) if prim.material is None else int(prim.material),
        uvs=None if uvs is None else _frozen(uvs),
        joints=None if joints is None else _frozen(joints),
        weights=None if weights is None else _frozen(weights),
        node=joint,
        targets=tuple(MorphTarget(t.name, _frozen(t.positions.astype(np.float32)),
                                  None if t.normals is None else _frozen(t.normals.astype(np.float32)))
                      for t in targets),
        mesh=mesh_index,
        source=source,
    )


def _frozen(array: np.ndarray) -> np.ndarray:
    array = np.ascontiguousarray(array)
    array.flags.writeable = False
    return array


def _unit(vectors: np.ndarray) -> np.ndarray:
    """Rows scaled to length 1 (zero rows become +Z)."""
    length = np.linalg.norm(vectors, axis=1, keepdims=True)
    safe = length > 1e-12
    out = np.where(safe, vectors / np.where(safe, length, 1.0), np.array([0.0, 0.0, 1.0], dtype=vectors.dtype))
    return out.astype(np.float32)


def vertex_normals(positions: np.ndarray, indices: np.ndarray) -> np.ndarray:
    """Area-weighted vertex normals of triangles (counter-clockwise is the front, as glTF says)."""
    tri = indices.reshape(-1, 3).astype(np.int64)
    p = positions.astype(np.float64)
    face = np.cross(p[tri[:, 1]] - p[tri[:, 0]], p[tri[:, 2]] - p[tri[:, 0]])
    flat = tri.ravel()
    normals = np.stack([np.bincount(flat, weights=np.repeat(face[:, d], 3), minlength=len(p)) for d in range(3)],
                       axis=1)
    return _unit(normals)


def _indices(reader: AccessorReader, prim: gl.Primitive, where: str, n: int, mode: int,
             limits: AvatarLimits) -> np.ndarray:
    """The primitive's triangles as (3T,) uint32 indices, every one below the vertex count."""
    if prim.indices is None:
        raw = np.arange(n, dtype=np.int64)
    else:
        raw = reader.read(prim.indices, f"{where}.indices", (gl.SCALAR,), limits.max_indices, "max_indices",
                          as_float=False)[:, 0]
        if raw.size and int(raw.max()) >= n:
            raise AvatarError(f"{where}.indices: index {int(raw.max())} is past the {n} vertices")
    if mode == gl.TRIANGLES:
        if raw.size % 3:
            raise AvatarError(f"{where}: {raw.size} indices are no whole number of triangles")
        tri = raw
    elif raw.size < 3:
        tri = np.zeros(0, dtype=np.int64)
    elif mode == gl.TRIANGLE_STRIP:  # every other triangle turned back to counter-clockwise
        k = np.arange(raw.size - 2)
        even = k % 2 == 0
        tri = np.stack([raw[k], np.where(even, raw[k + 1], raw[k + 2]), np.where(even, raw[k + 2], raw[k + 1])],
                       axis=1).ravel()
    else:  # TRIANGLE_FAN
        k = np.arange(1, raw.size - 1)
        tri = np.stack([np.full(k.size, raw[0]), raw[k], raw[k + 1]], axis=1).ravel()
    return tri.astype(np.uint32)


def _skinning(reader: AccessorReader, attributes: gl.Attributes, where: str, n: int, skin_joints: np.ndarray,
              limits: AvatarLimits) -> tuple[np.ndarray, np.ndarray]:
    """(V, 4) uint16 skeleton joints and (V, 4) float32 weights summing to 1: the four strongest influences of
    JOINTS_0/WEIGHTS_0 (and _1 when present)."""
    sets = [("JOINTS_0", "WEIGHTS_0")]
    if getattr(attributes, "JOINTS_1", None) is not None and getattr(attributes, "WEIGHTS_1", None) is not None:
        sets.append(("JOINTS_1", "WEIGHTS_1"))
    joint_parts, weight_parts = [], []
    for joints_name, weights_name in sets:
        j = reader.read(getattr(attributes, joints_name), f"{where}.attributes.{joints_name}", (gl.VEC4,),
                        limits.max_vertices, "max_vertices", as_float=False)
        w = reader.read(getattr(attributes, weights_name), f"{where}.attributes.{weights_name}", (gl.VEC4,),
                        limits.max_vertices, "max_vertices")
        for name, values in ((joints_name, j), (weights_name, w)):
            if values.shape[0] != n:
                raise AvatarError(f"{where}.attributes.{name} has {values.shape[0]} elements, POSITION has {n}")
        if j.size and (int(j.min()) < 0 or int(j.max()) >= len(skin_joints)):
            bad = int(j.max()) if int(j.max()) >= len(skin_joints) else int(j.min())
            raise AvatarError(f"{where}.attributes.{joints_name}: joint {bad} is not among the skin's "
                              f"{len(skin_joints)} joints")
        joint_parts.append(j)
        weight_parts.append(np.maximum(w, 0.0))
    joints = np.concatenate(joint_parts, axis=1)
    weights = np.concatenate(weight_parts, axis=1)
    if joints.shape[1] > 4:
        strongest = np.argsort(-weights, axis=1, kind="stable")[:, :4]
        joints = np.take_along_axis(joints, strongest, axis=1)
        weights = np.take_along_axis(weights, strongest, axis=1)
    total = weights.sum(axis=1, keepdims=True)
    unweighted = total[:, 0] <= 1e-12
    weights = np.where(total > 1e-12, weights / np.where(total > 1e-12, total, 1.0), 0.0)
    weights[unweighted, 0] = 1.0  # a vertex no joint moves follows its first joint
    return skin_joints[joints].astype(np.uint16), weights.astype(np.float32)
