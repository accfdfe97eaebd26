"""`load_avatar(path) -> Avatar`: a glTF 2.0 (.glb, or .gltf with its buffers and images beside it) or VRM 0.x/1.0
file as eca's Avatar (model.py), checked for what a face needs.

The steps, each in its own module, each refusing what it cannot take with an AvatarError that names the file and
what is wrong, before anything follows what the file claims:

1. container.py: the file (size), the GLB header and chunks, the JSON (size, depth, values, finite numbers);
2. document.py: the JSON as pygltflib's GLTF2, every member type-, range- and reference-checked, every accessor
   and buffer view inside what its view or buffer claims;
3. skeleton.py: the node tree (one parent each, no cycles, bounded depth) as joints, parents first;
4. vrm.py: the VRM extension (0.x or 1.0) in VRM 1.0's terms: humanoid, expressions, lookAt;
5. meshes.py, accessors.py: skins and primitives, their data read with numpy (strides, normalisation, sparse);
6. materials.py: materials and their textures (image sizes checked before decoding);
7. shapes.py, capabilities.py: normalised shape names, and the three things a face needs (eyes that turn, a
   blink, a mouth), refused together when missing; what it lacks beyond them said once as a logging warning.

A VRM 0.x model faces -Z: its vertices, joints and binds are turned half a turn about +Y so every Avatar faces +Z.
Anything else that goes wrong inside (a bug, not the file) still comes out as an AvatarError, saying so.
"""

from __future__ import annotations

import logging
from importlib import resources
from pathlib import Path

import numpy as np

from eca.services.processes.avatar.accessors import AccessorReader
from eca.services.processes.avatar.capabilities import check, inventory
from eca.services.processes.avatar.container import read_container
from eca.services.processes.avatar.document import build_document
from eca.services.processes.avatar.errors import AvatarError
from eca.services.processes.avatar.limits import DEFAULT_LIMITS, AvatarLimits
from eca.services.processes.avatar.materials import DEFAULT_MATERIAL, TextureDecoder, build_materials
from eca.services.processes.avatar.meshes import TURN_4X4, Notes, build_primitives, build_skins
from eca.services.processes.avatar.model import Avatar, Expression, Primitive, Skeleton
from eca.services.processes.avatar.shapes import ShapeNamer, shape_table
from eca.services.processes.avatar.skeleton import FACE_BONES, build_tree, face_bones_by_name, rest_transforms
from eca.services.processes.avatar.vrm import read_vrm

log = logging.getLogger("avatar")

# the default head: package data (eca/assets/), baked by `eca bake-head` (eca/services/tools/head_bake/)
DEFAULT_HEAD = Path(str(resources.files("eca") / "assets" / "default_head.glb"))


def load_avatar(path: str | Path, limits: AvatarLimits = DEFAULT_LIMITS) -> Avatar:
    """The avatar in `path` (.glb, .vrm or .gltf), or AvatarError naming the file and what is wrong with it."""
    source = str(path)
    try:
        with np.errstate(all="ignore"):  # overflow is looked for where it matters, and refused by name
            avatar, notes = _load(Path(path), limits)
    except AvatarError as error:
        raise error.at(source) from None
    except RecursionError:
        raise AvatarError("nested too deeply to read", source) from None
    except MemoryError:
        raise AvatarError("ran out of memory reading it", source) from None
    except Exception as error:  # noqa: BLE001 - whatever a file does, the caller gets an AvatarError
        raise AvatarError(f"unexpected failure reading it ({type(error).__name__}: {error})", source) from error
    said = [*avatar.capabilities.missing, *([notes.text()] if notes.lines else [])]
    if said:
        log.warning("%s: loaded; %s", source, "; ".join(said))
    return avatar


def _load(path: Path, limits: AvatarLimits) -> tuple[Avatar, Notes]:
    notes = Notes()
    container = read_container(path, limits)
    document = build_document(container.document, limits)
    tree = build_tree(document, limits)
    vrm = read_vrm(document, limits, notes)
    turn = vrm is not None and vrm.version == 0
    reader = AccessorReader(container, document)

    rest = rest_transforms(document, tree)
    skins = build_skins(document, reader, tree, limits)
    primitives, needs_default = build_primitives(document, reader, tree, skins, limits, notes, turn)
    inverse_bind = skins.inverse_bind
    if turn:
        rest, inverse_bind = rest * TURN_4X4, inverse_bind * TURN_4X4

    used = {p.material for p in primitives}
    decoder = TextureDecoder(document, container, reader, limits, notes)
    materials = build_materials(document, decoder, used, notes, vrm.material_properties if vrm else None)
    if needs_default:
        materials.append(DEFAULT_MATERIAL)

    humanoid: dict[str, int] = {}
    if vrm is not None:
        humanoid = {bone: int(tree.joint_of[node]) for bone, node in vrm.humanoid.items()}
    for bone, joint in face_bones_by_name(document, tree).items():
        humanoid.setdefault(bone, joint)  # names fill only the face bones a humanoid map leaves out
    names = tuple(document.nodes[i].name or f"node{i}" for i in tree.order)
    skeleton = Skeleton(names=names, parents=_frozen(tree.parents), rest=_frozen(rest),
                        inverse_bind=_frozen(inverse_bind), humanoid=humanoid, nodes=tree.order)

    expressions = vrm.expressions if vrm else {}
    _check_bind_reach(expressions, primitives, limits)
    shapes = shape_table(primitives, expressions, ShapeNamer())
    face_bones = {bone: joint for bone, joint in humanoid.items() if bone in FACE_BONES}
    look_at = vrm.look_at if vrm else None
    capabilities = check(inventory(shapes, expressions, face_bones, look_at))
    avatar = Avatar(
        name=(vrm.title if vrm and vrm.title else path.stem),
        primitives=tuple(primitives),
        materials=tuple(materials),
        skeleton=skeleton,
        expressions=dict(expressions),
        look_at=look_at,
        capabilities=capabilities,
        shapes=shapes,
        source=str(path),
        format="gltf" if vrm is None else f"vrm{vrm.version}",
        license_url=vrm.license_url[:2048] if vrm else "",
    )
    return avatar, notes


def _check_bind_reach(expressions: dict[str, Expression], primitives: list[Primitive], limits: AvatarLimits) -> None:
    """Refuses expressions whose binds reach more (bind, primitive) pairs than max_bind_targets: a driver builds one
    entry per pair, and a mesh drawn on many nodes multiplies them."""
    per_mesh: dict[int, int] = {}
    for prim in primitives:
        per_mesh[prim.mesh] = per_mesh.get(prim.mesh, 0) + 1
    reach = sum(per_mesh.get(bind.mesh, 0) for e in expressions.values() for bind in e.binds)
    if reach > limits.max_bind_targets:
        raise AvatarError(f"the expressions' binds reach {reach} morph targets of primitives in all, more than the "
                          f"limit of {limits.max_bind_targets} (max_bind_targets)")


def _frozen(array: np.ndarray) -> np.ndarray:
    array = np.ascontiguousarray(array)
    array.flags.writeable = False
    return array
