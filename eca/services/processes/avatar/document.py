"""The glTF JSON as pygltflib's document model, every member the loader uses checked first.

`build_document` reads the parsed JSON once, top to bottom: each list's length against its limit before it is
walked, each member's JSON type and range, every index into another list (an accessor's buffer view, a node's
children, a material's texture ...) against that list's length, and every buffer view and accessor against the
bytes its buffer or view claims to hold (arithmetic on the numbers the file states: nothing is read or allocated
here). What comes out is a `pygltflib.GLTF2` whose members the rest of the loader may trust: indices in range,
accessors inside their views, numbers finite, names strings.

pygltflib's own JSON reader (dataclasses-json) would coerce and pass through whatever a file holds and costs
~0.3 ms per object; building its dataclasses from checked values keeps its model and drops both problems.
Members the loader does not use (cameras, animations, samplers) are not read.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pygltflib as gl

from eca.services.processes.avatar.errors import AvatarError, show
from eca.services.processes.avatar.fields import (
    JSON,
    as_index,
    as_object,
    get_bool,
    get_index,
    get_int,
    get_list,
    get_number,
    get_numbers,
    get_object,
    get_objects,
    get_str,
    need_int,
)
from eca.services.processes.avatar.limits import AvatarLimits

COMPONENT_DTYPES: dict[int, np.dtype] = {
    gl.BYTE: np.dtype("<i1"),
    gl.UNSIGNED_BYTE: np.dtype("<u1"),
    gl.SHORT: np.dtype("<i2"),
    gl.UNSIGNED_SHORT: np.dtype("<u2"),
    gl.UNSIGNED_INT: np.dtype("<u4"),
    gl.FLOAT: np.dtype("<f4"),
}
TYPE_SIZES = {gl.SCALAR: 1, gl.VEC2: 2, gl.VEC3: 3, gl.VEC4: 4, gl.MAT2: 4, gl.MAT3: 9, gl.MAT4: 16}
SPARSE_INDEX_TYPES = (gl.UNSIGNED_BYTE, gl.UNSIGNED_SHORT, gl.UNSIGNED_INT)
ALPHA_MODES = ("OPAQUE", "MASK", "BLEND")
ATTRIBUTES = ("POSITION", "NORMAL", "TEXCOORD_0", "JOINTS_0", "WEIGHTS_0", "JOINTS_1", "WEIGHTS_1")
TARGET_ATTRIBUTES = ("POSITION", "NORMAL")
# Extensions a file may require that the loader reads or may ignore without drawing a wrong face.
SUPPORTED_REQUIRED = frozenset({
    "KHR_materials_unlit", "KHR_texture_transform", "KHR_mesh_quantization", "KHR_materials_emissive_strength",
    "KHR_materials_specular", "KHR_materials_ior", "KHR_materials_clearcoat", "KHR_materials_sheen",
    "KHR_materials_transmission", "KHR_materials_volume", "KHR_materials_variants", "EXT_texture_webp",
    "VRMC_materials_mtoon", "VRMC_vrm", "VRMC_springBone", "VRMC_node_constraint",
    "VRMC_materials_hdr_emissiveMultiplier",
})  # fmt: skip
MAX_EXTENSION_NAMES = 256


@dataclass(frozen=True)
class Layout:
    """Sizes of one accessor's elements: component dtype, components per element, bytes per element, stride."""

    dtype: np.dtype
    components: int
    element_bytes: int
    stride: int


def accessor_layout(accessor: gl.Accessor, views: list[gl.BufferView]) -> Layout:
    """The layout of a checked accessor (its stride is its view's byteStride, or its elements packed)."""
    dtype = COMPONENT_DTYPES[accessor.componentType]
    components = TYPE_SIZES[accessor.type]
    element = components * dtype.itemsize
    stride = element
    if accessor.bufferView is not None and views[accessor.bufferView].byteStride:
        stride = views[accessor.bufferView].byteStride
    return Layout(dtype, components, element, stride)


def build_document(doc: dict[str, JSON], limits: AvatarLimits) -> gl.GLTF2:
    """A checked `pygltflib.GLTF2` of a parsed glTF JSON document; see the module docstring."""
    asset = get_object(doc, "asset", "")
    version = get_str(asset, "version", "asset", "")
    if not version:
        raise AvatarError("asset.version is missing: not a glTF 2.0 document")
    if version.split(".")[0] != "2":
        raise AvatarError(f"asset.version is {show(version)}: eca reads glTF 2.0")
    _check_required_extensions(doc)

    buffers = _buffers(doc, limits)
    views = _buffer_views(doc, limits, buffers)
    accessors = _accessors(doc, limits, views)
    images = _images(doc, limits, views)
    textures = _textures(doc, limits, len(images))
    materials = _materials(doc, limits, len(textures))
    meshes = _meshes(doc, limits, len(accessors), len(materials))
    nodes_raw = get_objects(doc, "nodes", "", limits.max_nodes, "max_nodes")
    skins = _skins(doc, limits, len(nodes_raw), len(accessors))
    nodes = _nodes(nodes_raw, limits, len(meshes), len(skins))
    scenes = [gl.Scene(nodes=_node_list(s, "nodes", f"scenes[{i}]", len(nodes), limits.max_nodes,
                                         "max_nodes"))
              for i, s in enumerate(get_objects(doc, "scenes", "", limits.max_nodes, "max_nodes"))]
    scene = get_index(doc, "scene", "", len(scenes), "scenes")
    extensions = get_object(doc, "extensions", "")
    used = [e for e in get_list(doc, "extensionsUsed", "", MAX_EXTENSION_NAMES) if isinstance(e, str)]
    return gl.GLTF2(
        asset=gl.Asset(version=version), buffers=buffers, bufferViews=views, accessors=accessors, images=images,
        textures=textures, materials=materials, meshes=meshes, nodes=nodes, skins=skins, scenes=scenes, scene=scene,
        extensions=extensions, extensionsUsed=used,
    )


def _check_required_extensions(doc: dict[str, JSON]) -> None:
    required = get_list(doc, "extensionsRequired", "", MAX_EXTENSION_NAMES)
    for i, name in enumerate(required):
        if not isinstance(name, str):
            raise AvatarError(f"extensionsRequired[{i}] must be a string")
        if name not in SUPPORTED_REQUIRED:
            raise AvatarError(f"the file requires the glTF extension {show(name)}, which eca does not read "
                              "(export without it: e.g. no Draco or meshopt compression)")


def _buffers(doc: dict[str, JSON], limits: AvatarLimits) -> list[gl.Buffer]:
    out = []
    for i, raw in enumerate(get_objects(doc, "buffers", "", limits.max_buffers, "max_buffers")):
        where = f"buffers[{i}]"
        length = need_int(raw, "byteLength", where)
        if length > limits.max_file_bytes:
            raise AvatarError(f"{where}.byteLength claims {length} bytes, more than the file size limit of "
                              f"{limits.max_file_bytes} (max_file_bytes)")
        uri = raw.get("uri")
        if uri is not None and not isinstance(uri, str):
            raise AvatarError(f"{where}.uri must be a string")
        out.append(gl.Buffer(uri=uri, byteLength=length))
    return out


def _buffer_views(doc: dict[str, JSON], limits: AvatarLimits, buffers: list[gl.Buffer]) -> list[gl.BufferView]:
    out = []
    for i, raw in enumerate(get_objects(doc, "bufferViews", "", limits.max_buffer_views, "max_buffer_views")):
        where = f"bufferViews[{i}]"
        buffer = as_index(raw.get("buffer"), f"{where}.buffer", len(buffers), "buffers")
        offset = get_int(raw, "byteOffset", where, 0)
        length = need_int(raw, "byteLength", where)
        assert offset is not None
        size = buffers[buffer].byteLength
        if offset + length > size:
            raise AvatarError(f"{where} (bytes {offset}..{offset + length}) runs past buffers[{buffer}] "
                              f"({size} bytes)")
        stride = get_int(raw, "byteStride", where, None, 1, 252)
        out.append(gl.BufferView(buffer=buffer, byteOffset=offset, byteLength=length, byteStride=stride))
    return out


def _accessors(doc: dict[str, JSON], limits: AvatarLimits, views: list[gl.BufferView]) -> list[gl.Accessor]:
    out = []
    for i, raw in enumerate(get_objects(doc, "accessors", "", limits.max_accessors, "max_accessors")):
        where = f"accessors[{i}]"
        component = need_int(raw, "componentType", where)
        if component not in COMPONENT_DTYPES:
            raise AvatarError(f"{where}.componentType {component} is none of glTF's "
                              f"{', '.join(map(str, COMPONENT_DTYPES))}")
        kind = get_str(raw, "type", where)
        if kind not in TYPE_SIZES:
            raise AvatarError(f"{where}.type {show(kind)} is none of {', '.join(TYPE_SIZES)}")
        count = need_int(raw, "count", where, 0, 2**32)
        view = get_index(raw, "bufferView", where, len(views), "bufferViews")
        offset = get_int(raw, "byteOffset", where, 0)
        assert offset is not None
        accessor = gl.Accessor(bufferView=view, byteOffset=offset, componentType=component,
                               normalized=get_bool(raw, "normalized", where), count=count, type=kind)
        layout = accessor_layout(accessor, views)
        if view is not None:
            if layout.stride < layout.element_bytes:
                raise AvatarError(f"{where}: bufferViews[{view}].byteStride {layout.stride} is smaller than its "
                                  f"{layout.element_bytes}-byte elements")
            end = offset + (layout.stride * (count - 1) + layout.element_bytes if count else 0)
            if end > views[view].byteLength:
                raise AvatarError(f"{where}: {count} elements of {layout.element_bytes} bytes from byte {offset} "
                                  f"run past bufferViews[{view}] ({views[view].byteLength} bytes)")
        elif offset:
            raise AvatarError(f"{where} has a byteOffset but no bufferView")
        sparse = raw.get("sparse")
        if sparse is not None:
            accessor.sparse = _sparse(as_object(sparse, f"{where}.sparse"), f"{where}.sparse", count, layout, views)
        out.append(accessor)
    return out


def _sparse(raw: dict[str, JSON], where: str, count: int, layout: Layout, views: list[gl.BufferView]) -> gl.Sparse:
    n = need_int(raw, "count", where, 1, count)
    indices = get_object(raw, "indices", where)
    values = get_object(raw, "values", where)
    index_view = as_index(indices.get("bufferView"), f"{where}.indices.bufferView", len(views), "bufferViews")
    index_offset = get_int(indices, "byteOffset", f"{where}.indices", 0)
    index_type = need_int(indices, "componentType", f"{where}.indices")
    if index_type not in SPARSE_INDEX_TYPES:
        raise AvatarError(f"{where}.indices.componentType {index_type} must be 5121, 5123 or 5125")
    value_view = as_index(values.get("bufferView"), f"{where}.values.bufferView", len(views), "bufferViews")
    value_offset = get_int(values, "byteOffset", f"{where}.values", 0)
    assert index_offset is not None and value_offset is not None
    for part, view, offset, size in (("indices", index_view, index_offset, COMPONENT_DTYPES[index_type].itemsize),
                                     ("values", value_view, value_offset, layout.element_bytes)):
        if offset + n * size > views[view].byteLength:
            raise AvatarError(f"{where}.{part}: {n} elements of {size} bytes from byte {offset} run past "
                              f"bufferViews[{view}] ({views[view].byteLength} bytes)")
    return gl.Sparse(
        count=n,
        indices=gl.AccessorSparseIndices(bufferView=index_view, byteOffset=index_offset, componentType=index_type),
        values=gl.AccessorSparseValues(bufferView=value_view, byteOffset=value_offset),
    )


def _images(doc: dict[str, JSON], limits: AvatarLimits, views: list[gl.BufferView]) -> list[gl.Image]:
    out = []
    for i, raw in enumerate(get_objects(doc, "images", "", limits.max_images, "max_images")):
        where = f"images[{i}]"
        uri = raw.get("uri")
        if uri is not None and not isinstance(uri, str):
            raise AvatarError(f"{where}.uri must be a string")
        view = get_index(raw, "bufferView", where, len(views), "bufferViews")
        out.append(gl.Image(uri=uri, bufferView=view, mimeType=get_str(raw, "mimeType", where) or None,
                            name=get_str(raw, "name", where) or None))
    return out


def _textures(doc: dict[str, JSON], limits: AvatarLimits, n_images: int) -> list[gl.Texture]:
    out = []
    for i, raw in enumerate(get_objects(doc, "textures", "", limits.max_textures, "max_textures")):
        where = f"textures[{i}]"
        source = get_index(raw, "source", where, n_images, "images")
        if source is None:  # EXT_texture_webp keeps its image in the extension
            webp = get_object(get_object(raw, "extensions", where), "EXT_texture_webp", f"{where}.extensions")
            source = get_index(webp, "source", f"{where}.extensions.EXT_texture_webp", n_images, "images")
        out.append(gl.Texture(source=source))
    return out


def _texture_info(raw: dict[str, JSON], key: str, where: str, n_textures: int) -> gl.TextureInfo | None:
    info = raw.get(key)
    if info is None:
        return None
    info = as_object(info, f"{where}.{key}")
    index = as_index(info.get("index"), f"{where}.{key}.index", n_textures, "textures")
    return gl.TextureInfo(index=index, texCoord=get_int(info, "texCoord", f"{where}.{key}", 0, 0, 7))


def _materials(doc: dict[str, JSON], limits: AvatarLimits, n_textures: int) -> list[gl.Material]:
    out = []
    for i, raw in enumerate(get_objects(doc, "materials", "", limits.max_materials, "max_materials")):
        where = f"materials[{i}]"
        pbr = get_object(raw, "pbrMetallicRoughness", where)
        pbr_where = f"{where}.pbrMetallicRoughness"
        color = get_numbers(pbr, "baseColorFactor", pbr_where, 4) or (1.0, 1.0, 1.0, 1.0)
        alpha_mode = get_str(raw, "alphaMode", where, "OPAQUE")
        if alpha_mode not in ALPHA_MODES:
            raise AvatarError(f"{where}.alphaMode {show(alpha_mode)} is none of {', '.join(ALPHA_MODES)}")
        extensions = get_object(raw, "extensions", where)
        for name, value in extensions.items():
            as_object(value, f"{where}.extensions.{name}")
        out.append(gl.Material(
            name=get_str(raw, "name", where, f"material{i}"),
            pbrMetallicRoughness=gl.PbrMetallicRoughness(
                baseColorFactor=list(color),
                baseColorTexture=_texture_info(pbr, "baseColorTexture", pbr_where, n_textures),
                roughnessFactor=get_number(pbr, "roughnessFactor", pbr_where, 1.0),
            ),
            alphaMode=alpha_mode,
            alphaCutoff=get_number(raw, "alphaCutoff", where, 0.5),
            doubleSided=get_bool(raw, "doubleSided", where),
            extensions=extensions,
        ))
    return out


def _attributes(raw: dict[str, JSON], names: tuple[str, ...], where: str, n_accessors: int) -> dict[str, int]:
    found = {}
    for name in names:
        index = get_index(raw, name, where, n_accessors, "accessors")
        if index is not None:
            found[name] = index
    return found


def _meshes(doc: dict[str, JSON], limits: AvatarLimits, n_accessors: int, n_materials: int) -> list[gl.Mesh]:
    out = []
    total = 0
    for m, raw in enumerate(get_objects(doc, "meshes", "", limits.max_meshes, "max_meshes")):
        where = f"meshes[{m}]"
        primitives = []
        for p, prim in enumerate(get_objects(raw, "primitives", where, limits.max_primitives, "max_primitives")):
            total += 1
            if total > limits.max_primitives:
                raise AvatarError(f"the meshes hold more than {limits.max_primitives} primitives in all "
                                  "(max_primitives)")
            pwhere = f"{where}.primitives[{p}]"
            attributes = _attributes(get_object(prim, "attributes", pwhere), ATTRIBUTES, f"{pwhere}.attributes",
                                     n_accessors)
            targets = [_attributes(target, TARGET_ATTRIBUTES, f"{pwhere}.targets[{t}]", n_accessors)
                       for t, target in enumerate(get_objects(prim, "targets", pwhere, limits.max_targets,
                                                                   "max_targets"))]
            primitives.append(gl.Primitive(
                attributes=gl.Attributes(**attributes),
                indices=get_index(prim, "indices", pwhere, n_accessors, "accessors"),
                mode=get_int(prim, "mode", pwhere, gl.TRIANGLES, 0, 6),
                material=get_index(prim, "material", pwhere, n_materials, "materials"),
                targets=targets,  # pygltflib keeps a target as its attribute dict
                extras=_extras(prim, pwhere),
            ))
        out.append(gl.Mesh(primitives=primitives, name=get_str(raw, "name", where) or None,
                           extras=_extras(raw, where)))
    return out


def _extras(raw: dict[str, JSON], where: str) -> dict[str, JSON]:
    """An object's extras when they are an object ({} otherwise: extras are free-form, glTF says)."""
    extras = raw.get("extras")
    return extras if isinstance(extras, dict) else {}


def _node_list(raw: dict[str, JSON], key: str, where: str, n_nodes: int, limit: int, limit_name: str) -> list[int]:
    items = get_list(raw, key, where, limit, limit_name=limit_name)
    return [as_index(v, f"{where}.{key}[{k}]", n_nodes, "nodes") for k, v in enumerate(items)]


def _skins(doc: dict[str, JSON], limits: AvatarLimits, n_nodes: int, n_accessors: int) -> list[gl.Skin]:
    out = []
    for i, raw in enumerate(get_objects(doc, "skins", "", limits.max_skins, "max_skins")):
        where = f"skins[{i}]"
        joints = _node_list(raw, "joints", where, n_nodes, limits.max_joints, "max_joints")
        if not joints:
            raise AvatarError(f"{where}.joints is empty")
        out.append(gl.Skin(joints=joints,
                           inverseBindMatrices=get_index(raw, "inverseBindMatrices", where, n_accessors, "accessors"),
                           skeleton=get_index(raw, "skeleton", where, n_nodes, "nodes"),
                           name=get_str(raw, "name", where) or None))
    return out


def _nodes(nodes_raw: list[dict[str, JSON]], limits: AvatarLimits, n_meshes: int, n_skins: int) -> list[gl.Node]:
    out = []
    n_nodes = len(nodes_raw)
    for i, raw in enumerate(nodes_raw):
        where = f"nodes[{i}]"
        matrix = get_numbers(raw, "matrix", where, 16)
        rotation = get_numbers(raw, "rotation", where, 4)
        if rotation is not None and sum(v * v for v in rotation) < 1e-12:
            raise AvatarError(f"{where}.rotation {list(rotation)} is no rotation (a zero quaternion)")
        out.append(gl.Node(
            name=get_str(raw, "name", where, f"node{i}"),
            mesh=get_index(raw, "mesh", where, n_meshes, "meshes"),
            skin=get_index(raw, "skin", where, n_skins, "skins"),
            children=_node_list(raw, "children", where, n_nodes, limits.max_nodes, "max_nodes"),
            matrix=list(matrix) if matrix is not None else None,
            translation=list(get_numbers(raw, "translation", where, 3) or (0.0, 0.0, 0.0)),
            rotation=list(rotation or (0.0, 0.0, 0.0, 1.0)),
            scale=list(get_numbers(raw, "scale", where, 3) or (1.0, 1.0, 1.0)),
            extras=_extras(raw, where),
        ))
    return out
