"""VRM 0.x (`extensions.VRM`) and VRM 1.0 (`extensions.VRMC_vrm`): the humanoid bone map, the expressions with their
morph-target binds and override rules, the lookAt, and (0.x) the material properties.

Both versions come out in VRM 1.0's terms (vrm-c/vrm-specification, VRMC_vrm-1.0; three-vrm's 0.x importer):

- humanoid: bone name (head, neck, jaw, leftEye, ...) -> glTF node; 1.0's `humanBones` object, 0.x's list.
- expressions, under their 1.0 names: a 0.x blendShapeGroup's presetName maps to the 1.0 preset (a->aa, i->ih,
  u->ou, e->ee, o->oh, joy->happy, angry->angry, sorrow->sad, fun->relaxed, blink->blink, blink_l->blinkLeft,
  blink_r->blinkRight, lookup->lookUp ..., neutral->neutral; "unknown" is a custom expression under its own name);
  0.x bind weights (0-100) scale to 0-1; 1.0 binds name a node, whose mesh they bind. 0.x has no overrides.
  A bind past its mesh's morph targets, a duplicate preset or a custom name shadowing a preset is left out and
  noted (as three-vrm does).
- lookAt: 1.0's `lookAt` (type bone or expression, range maps, offsetFromHeadBone); 0.x's firstPerson
  (lookAtTypeName Bone or BlendShape, degree maps xRange -> inputMaxValue, yRange -> outputScale; the curve is
  not read, as in three-vrm). Missing maps default to 90 degrees in and 10 (bone) or 1 (expression) out; an
  inputMaxValue below 0.001 is taken as 0.001 (lookAt.md: no division by zero).

A VRM 0.x model faces -Z; the loader turns it to face +Z (meshes.TURN), and its firstPersonBoneOffset, stored in
Unity's mirrored frame, becomes (-x, y, z) (three-vrm reads it as (x, y, -z) in the unturned frame).
"""

from __future__ import annotations

from dataclasses import dataclass

import pygltflib as gl

from eca.agent.rig.names import VRM_INDEX, VRM_NAMES, vrm_index
from eca.services.processes.avatar.errors import AvatarError, show
from eca.services.processes.avatar.fields import (
    JSON,
    as_index,
    as_object,
    get_bool,
    get_int,
    get_list,
    get_number,
    get_numbers,
    get_object,
    get_objects,
    get_str,
)
from eca.services.processes.avatar.limits import AvatarLimits
from eca.services.processes.avatar.meshes import Notes
from eca.services.processes.avatar.model import Expression, LookAt, LookAtType, MorphBind, Override, RangeMap

MAX_HUMAN_BONES = 256
INPUT_MAX_MINIMUM = 0.001
OVERRIDES = {o.value: o for o in Override}


@dataclass(frozen=True)
class Vrm:
    """What a VRM extension says, in VRM 1.0's terms (see the module docstring)."""

    version: int  # 0 or 1
    title: str
    humanoid: dict[str, int]  # bone name -> glTF node
    expressions: dict[str, Expression]  # presets in VRM_NAMES order, then custom ones in file order
    look_at: LookAt | None
    material_properties: list[JSON] | None  # 0.x: materialProperties, by material index
    license_url: str = ""  # 1.0: meta.licenseUrl (a page's three-vrm accepts only the one it is told of)


def read_vrm(document: gl.GLTF2, limits: AvatarLimits, notes: Notes) -> Vrm | None:
    """The document's VRM extension (1.0 first when a file has both, as three-vrm reads it), or None."""
    extensions = document.extensions or {}
    if "VRMC_vrm" in extensions:
        return _vrm1(as_object(extensions["VRMC_vrm"], "extensions.VRMC_vrm"), document, limits, notes)
    if "VRM" in extensions:
        return _vrm0(as_object(extensions["VRM"], "extensions.VRM"), document, limits, notes)
    return None


def _target_counts(document: gl.GLTF2) -> list[int]:
    """Each mesh's morph-target count that every one of its primitives has (a bind indexes all of them)."""
    return [min((len(p.targets or []) for p in mesh.primitives), default=0) for mesh in document.meshes]


def _range_map(raw: dict[str, JSON], key: str, where: str, default_scale: float, version: int) -> RangeMap:
    value = raw.get(key)
    if value is None:
        return RangeMap(90.0, default_scale)
    data = as_object(value, f"{where}.{key}")
    in_key, out_key = ("inputMaxValue", "outputScale") if version == 1 else ("xRange", "yRange")
    input_max = get_number(data, in_key, f"{where}.{key}", 90.0)
    if input_max < 0.0:
        raise AvatarError(f"{where}.{key}.{in_key} is {input_max}: a range map's input must not be negative")
    return RangeMap(max(input_max, INPUT_MAX_MINIMUM), get_number(data, out_key, f"{where}.{key}", default_scale))


def _sorted(presets: dict[str, Expression], custom: dict[str, Expression]) -> dict[str, Expression]:
    ordered = {name: presets[name] for name in VRM_NAMES if name in presets}
    ordered.update(custom)
    return ordered


def _bind(mesh: int, target: int, weight: float, where: str, counts: list[int], notes: Notes) -> MorphBind | None:
    if target >= counts[mesh]:
        notes.add(f"{where} binds morph target {target} of meshes[{mesh}], which has {counts[mesh]}: left out")
        return None
    return MorphBind(mesh, target, min(max(weight, 0.0), 1.0))


def _humanoid(bones: dict[str, int], bone: object, node: int, where: str, notes: Notes) -> None:
    if not isinstance(bone, str) or len(bone) > 64:
        raise AvatarError(f"{where}: a human bone name must be a short string, got {show(bone)}")
    if bone in bones:
        notes.add(f"{where}: human bone {bone} given twice; the first kept")
    else:
        bones[bone] = node


def _vrm1(ext: dict[str, JSON], document: gl.GLTF2, limits: AvatarLimits, notes: Notes) -> Vrm:
    where = "extensions.VRMC_vrm"
    n_nodes = len(document.nodes)
    bones: dict[str, int] = {}
    human = get_object(get_object(ext, "humanoid", where), "humanBones", f"{where}.humanoid")
    if len(human) > MAX_HUMAN_BONES:
        raise AvatarError(f"{where}.humanoid.humanBones has {len(human)} bones, more than {MAX_HUMAN_BONES}")
    for bone, spec in human.items():
        bwhere = f"{where}.humanoid.humanBones.{show(bone, 40)}"
        node = as_index(as_object(spec, bwhere).get("node"), f"{bwhere}.node", n_nodes, "nodes")
        _humanoid(bones, bone, node, bwhere, notes)

    counts = _target_counts(document)
    groups = get_object(ext, "expressions", where)
    presets_raw = get_object(groups, "preset", f"{where}.expressions")
    custom_raw = get_object(groups, "custom", f"{where}.expressions")
    if len(presets_raw) + len(custom_raw) > limits.max_expressions:
        raise AvatarError(f"{where}.expressions holds {len(presets_raw) + len(custom_raw)} expressions, more than "
                          f"the limit of {limits.max_expressions} (max_expressions)")
    presets: dict[str, Expression] = {}
    custom: dict[str, Expression] = {}
    for group, raw_group in (("preset", presets_raw), ("custom", custom_raw)):
        for name, raw in raw_group.items():
            ewhere = f"{where}.expressions.{group}.{show(name, 40)}"
            if group == "preset" and name not in VRM_INDEX:
                notes.add(f"{ewhere}: no VRM 1.0 preset of that name; left out")
                continue
            if group == "custom" and name in VRM_INDEX:
                notes.add(f"{ewhere}: a custom expression may not take a preset's name; left out")
                continue
            expression = _expression1(name, as_object(raw, ewhere), ewhere, document, counts, limits, notes)
            (presets if group == "preset" else custom)[name] = expression

    look_at = None
    raw_look = ext.get("lookAt")
    if raw_look is not None:
        lwhere = f"{where}.lookAt"
        look = as_object(raw_look, lwhere)
        kind = get_str(look, "type", lwhere, "bone")
        if kind not in ("bone", "expression"):
            raise AvatarError(f"{lwhere}.type {show(kind)} is neither 'bone' nor 'expression'")
        scale = 10.0 if kind == "bone" else 1.0
        offset = get_numbers(look, "offsetFromHeadBone", lwhere, 3) or (0.0, 0.06, 0.0)
        look_at = LookAt(
            type=LookAtType(kind),
            horizontal_inner=_range_map(look, "rangeMapHorizontalInner", lwhere, scale, 1),
            horizontal_outer=_range_map(look, "rangeMapHorizontalOuter", lwhere, scale, 1),
            vertical_down=_range_map(look, "rangeMapVerticalDown", lwhere, scale, 1),
            vertical_up=_range_map(look, "rangeMapVerticalUp", lwhere, scale, 1),
            offset=(offset[0], offset[1], offset[2]),
        )
    meta = get_object(ext, "meta", where)
    title = get_str(meta, "name", f"{where}.meta")
    license_url = get_str(meta, "licenseUrl", f"{where}.meta", "")
    return Vrm(1, title, bones, _sorted(presets, custom), look_at, None, license_url)


def _override(raw: dict[str, JSON], key: str, where: str) -> Override:
    value = get_str(raw, key, where, "none")
    if value not in OVERRIDES:
        raise AvatarError(f"{where}.{key} {show(value)} is none of none, block, blend")
    return OVERRIDES[value]


def _expression1(name: str, raw: dict[str, JSON], where: str, document: gl.GLTF2, counts: list[int],
                 limits: AvatarLimits, notes: Notes) -> Expression:
    binds = []
    for b, bind in enumerate(get_objects(raw, "morphTargetBinds", where, limits.max_binds, "max_binds")):
        bwhere = f"{where}.morphTargetBinds[{b}]"
        node = as_index(bind.get("node"), f"{bwhere}.node", len(document.nodes), "nodes")
        mesh = document.nodes[node].mesh
        if mesh is None:
            notes.add(f"{bwhere}: nodes[{node}] has no mesh; left out")
            continue
        target = get_int(bind, "index", bwhere, None)
        if target is None:
            raise AvatarError(f"{bwhere}.index is missing")
        found = _bind(mesh, target, get_number(bind, "weight", bwhere, 1.0), bwhere, counts, notes)
        if found is not None:
            binds.append(found)
    return Expression(
        name=name,
        binds=tuple(binds),
        is_binary=get_bool(raw, "isBinary", where),
        override_blink=_override(raw, "overrideBlink", where),
        override_look_at=_override(raw, "overrideLookAt", where),
        override_mouth=_override(raw, "overrideMouth", where),
    )


def _vrm0(ext: dict[str, JSON], document: gl.GLTF2, limits: AvatarLimits, notes: Notes) -> Vrm:
    where = "extensions.VRM"
    n_nodes = len(document.nodes)
    bones: dict[str, int] = {}
    humanoid = get_object(ext, "humanoid", where)
    for i, bone in enumerate(get_objects(humanoid, "humanBones", f"{where}.humanoid", MAX_HUMAN_BONES)):
        bwhere = f"{where}.humanoid.humanBones[{i}]"
        node = as_index(bone.get("node"), f"{bwhere}.node", n_nodes, "nodes")
        _humanoid(bones, bone.get("bone"), node, bwhere, notes)

    counts = _target_counts(document)
    n_meshes = len(document.meshes)
    master = get_object(ext, "blendShapeMaster", where)
    presets: dict[str, Expression] = {}
    custom: dict[str, Expression] = {}
    for g, group in enumerate(get_objects(master, "blendShapeGroups", f"{where}.blendShapeMaster",
                                          limits.max_expressions, "max_expressions")):
        gwhere = f"{where}.blendShapeMaster.blendShapeGroups[{g}]"
        preset_name = get_str(group, "presetName", gwhere, "unknown")
        own_name = get_str(group, "name", gwhere)
        preset = None
        if preset_name.lower() != "unknown" and len(preset_name) <= 16:
            try:
                preset = VRM_NAMES[vrm_index(preset_name)]
            except ValueError:
                notes.add(f"{gwhere}.presetName {show(preset_name)} is no VRM 0.x preset; taken as custom")
        name = preset or own_name
        if not name:
            notes.add(f"{gwhere} is a custom blend shape without a name; left out")
            continue
        if preset is not None and preset in presets:
            notes.add(f"{gwhere}: preset {show(preset_name)} given twice; the first kept")
            continue
        if preset is None and (name in VRM_INDEX or name in custom):
            notes.add(f"{gwhere}: custom name {show(name)} taken already; left out")
            continue
        binds = []
        for b, bind in enumerate(get_objects(group, "binds", gwhere, limits.max_binds, "max_binds")):
            bwhere = f"{gwhere}.binds[{b}]"
            mesh = as_index(bind.get("mesh"), f"{bwhere}.mesh", n_meshes, "meshes")
            target = get_int(bind, "index", bwhere, None)
            if target is None:
                raise AvatarError(f"{bwhere}.index is missing")
            found = _bind(mesh, target, get_number(bind, "weight", bwhere, 100.0) / 100.0, bwhere, counts, notes)
            if found is not None:
                binds.append(found)
        expression = Expression(name=name, binds=tuple(binds), is_binary=get_bool(group, "isBinary", gwhere))
        (presets if preset is not None else custom)[name] = expression

    look_at = None
    first = ext.get("firstPerson")
    if first is not None:
        fwhere = f"{where}.firstPerson"
        person = as_object(first, fwhere)
        kind = get_str(person, "lookAtTypeName", fwhere, "Bone")
        if kind not in ("Bone", "BlendShape"):
            raise AvatarError(f"{fwhere}.lookAtTypeName {show(kind)} is neither 'Bone' nor 'BlendShape'")
        scale = 10.0 if kind == "Bone" else 1.0
        offset_raw = get_object(person, "firstPersonBoneOffset", fwhere)
        owhere = f"{fwhere}.firstPersonBoneOffset"
        x = get_number(offset_raw, "x", owhere, 0.0)
        y = get_number(offset_raw, "y", owhere, 0.06)
        z = get_number(offset_raw, "z", owhere, 0.0)
        look_at = LookAt(
            type=LookAtType.BONE if kind == "Bone" else LookAtType.EXPRESSION,
            horizontal_inner=_range_map(person, "lookAtHorizontalInner", fwhere, scale, 0),
            horizontal_outer=_range_map(person, "lookAtHorizontalOuter", fwhere, scale, 0),
            vertical_down=_range_map(person, "lookAtVerticalDown", fwhere, scale, 0),
            vertical_up=_range_map(person, "lookAtVerticalUp", fwhere, scale, 0),
            offset=(-x, y, z),
        )
    title = get_str(get_object(ext, "meta", where), "title", f"{where}.meta")
    properties = get_list(ext, "materialProperties", where, limits.max_materials, limit_name="max_materials")
    return Vrm(0, title, bones, _sorted(presets, custom), look_at, properties)
