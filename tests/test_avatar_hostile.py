"""Hostile and broken avatar files: each refusal's message, that a refusal comes before the allocation a file's
claim would cause, and a fuzz test (hypothesis) mutating a valid file's JSON, bytes and binary data that finds
nothing but AvatarError: no other exception, no hang, no big memory.

Every case starts from the small valid face of tests/test_avatar_files.py, changes one thing, and checks the
message names the file and what is wrong.
"""

from __future__ import annotations

import copy
import json
import os
import struct
import time
import tracemalloc
import zlib
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from eca.agent.face.composed import EyeAngles
from eca.agent.rig.frame import RigFrame
from eca.services.processes.avatar.drive import AvatarDriver
from eca.services.processes.avatar.errors import AvatarError
from eca.services.processes.avatar.limits import DEFAULT_LIMITS, AvatarLimits
from eca.services.processes.avatar.loader import load_avatar
from tests.test_avatar_files import face, glb_bytes, png_bytes, vrm0_document, vrm1_document

Doc = dict[str, Any]
_FACE = face("camel")
BASE_DOC: Doc = _FACE.builder.document()
BASE_BLOB = bytes(_FACE.builder.blob)
BASE_GLB = glb_bytes(BASE_DOC, BASE_BLOB)
_VRM = face(None)
VRM1_DOC: Doc = vrm1_document(_VRM)
VRM0_DOC: Doc = vrm0_document(face(None, vrm0=True))
VRM_BLOB = bytes(_VRM.builder.blob)
FACE_MESH = _FACE.mesh
POSITION = BASE_DOC["meshes"][FACE_MESH]["primitives"][0]["attributes"]["POSITION"]
INDICES = BASE_DOC["meshes"][FACE_MESH]["primitives"][0]["indices"]


def refused(path: Path, limits: AvatarLimits = DEFAULT_LIMITS) -> str:
    """The message of the AvatarError loading `path` raises (the test fails if it loads or raises otherwise)."""
    with pytest.raises(AvatarError) as caught:
        load_avatar(path, limits)
    message = str(caught.value)
    assert message.startswith(f"{path}: "), message
    assert "unexpected failure" not in message, message
    return message


def glb_file(tmp_path: Path, doc: Doc | None = None, blob: bytes = BASE_BLOB, name: str = "bad.glb") -> Path:
    path = tmp_path / name
    path.write_bytes(glb_bytes(BASE_DOC if doc is None else doc, blob))
    return path


def raw_file(tmp_path: Path, data: bytes, name: str = "bad.glb") -> Path:
    path = tmp_path / name
    path.write_bytes(data)
    return path


def json_chunk_glb(text: bytes, blob: bytes = BASE_BLOB) -> bytes:
    text += b" " * (-len(text) % 4)
    chunks = struct.pack("<II", len(text), 0x4E4F534A) + text + struct.pack("<II", len(blob), 0x004E4942) + blob
    return struct.pack("<4sII", b"glTF", 2, 12 + len(chunks)) + chunks


def edited(change: Callable[[Doc], None], base: Doc = BASE_DOC) -> Doc:
    doc = copy.deepcopy(base)
    change(doc)
    return doc


def png_header_only(width: int, height: int) -> bytes:
    """A PNG signature and IHDR chunk claiming width x height, then a broken IDAT: a decompression bomb's header."""
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 6, 0, 0, 0)
    chunk = struct.pack(">I", len(ihdr)) + b"IHDR" + ihdr + struct.pack(">I", zlib.crc32(b"IHDR" + ihdr))
    idat = zlib.compress(b"\x00" * 64)
    return (b"\x89PNG\r\n\x1a\n" + chunk + struct.pack(">I", len(idat)) + b"IDAT" + idat
            + struct.pack(">I", zlib.crc32(b"IDAT" + idat)) + b"\x00\x00\x00\x00IEND\xaeB`\x82")


# --- the container ---------------------------------------------------------------------------------------------------

def test_a_file_over_the_size_limit_is_refused_before_it_is_read(tmp_path: Path) -> None:
    message = refused(raw_file(tmp_path, BASE_GLB), replace(DEFAULT_LIMITS, max_file_bytes=1000))
    assert f"the file has {len(BASE_GLB)} bytes, more than the limit of 1000 (max_file_bytes)" in message


def test_a_file_that_is_neither_glb_nor_json_is_refused(tmp_path: Path) -> None:
    assert "neither a binary glTF" in refused(raw_file(tmp_path, b"PK\x03\x04 a zip, say"))


def test_a_missing_file_and_a_folder_are_refused(tmp_path: Path) -> None:
    assert "cannot open the file" in refused(tmp_path / "nowhere.glb")
    assert "the file is not a regular file" in refused(tmp_path)


@pytest.mark.parametrize("data, expected", [
    (b"glTF\x02\x00", "a GLB header is 12 bytes, the file has 6"),
    (struct.pack("<4sII", b"glTF", 1, 12), "GLB version 1: eca reads version 2"),
    (struct.pack("<4sII", b"glTF", 2, 16), "the GLB header says the file has 16 bytes, it has 12"),
    (struct.pack("<4sII", b"glTF", 2, 12), "the GLB has no chunks"),
    (struct.pack("<4sII", b"glTF", 2, 16) + b"\x00" * 4, "its 8-byte header is cut off"),
    (struct.pack("<4sIIII", b"glTF", 2, 20, 1 << 31, 0x4E4F534A), "claims 2147483648 bytes, only 0 follow"),
    (struct.pack("<4sIIII", b"glTF", 2, 24, 4, 0x004E4942) + b"\x00" * 4, "the first GLB chunk must be JSON"),
])
def test_a_broken_glb_header_or_chunk_is_refused(tmp_path: Path, data: bytes, expected: str) -> None:
    assert expected in refused(raw_file(tmp_path, data))


def test_a_second_json_or_bin_chunk_is_refused(tmp_path: Path) -> None:
    for chunk_type, expected in ((0x004E4942, "is a second BIN chunk"), (0x4E4F534A, "is a second JSON chunk")):
        extra = struct.pack("<II", 4, chunk_type) + b"\x00" * 4
        data = BASE_GLB + extra
        data = data[:8] + struct.pack("<I", len(data)) + data[12:]
        assert expected in refused(raw_file(tmp_path, data))


# --- the JSON --------------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("text, expected", [
    (b"\xff\xfe{}", "the JSON chunk is not UTF-8 text (byte 0)"),
    (b'{"asset": ', "the JSON chunk is not valid JSON"),
    (b'{"asset": {"version": NaN}}', "holds NaN, which glTF numbers cannot be"),
    (b'{"asset": {"version": -Infinity}}', "holds -Infinity"),
    (b'{"asset": {"version": 1e999}}', "the JSON number '1e999' is too big for a float"),
    (b'{"a": ' + b"1" * 5000 + b"}", "the JSON chunk is not valid JSON"),
    (b"[1, 2]", "the JSON chunk must be a JSON object, it is a list"),
    (b'{"extras": ' + b"[" * 100 + b"]" * 100 + b"}", "nests deeper than the limit of 64 (max_json_depth)"),
    (b'{"extras": ' + b"[" * 200_000 + b"]" * 200_000 + b"}", "nests deeper than the limit of 64"),
    (b'{"asset": {}}', "asset.version is missing: not a glTF 2.0 document"),
    (b'{"asset": {"version": "1.0"}}', "asset.version is '1.0': eca reads glTF 2.0"),
])
def test_bad_json_is_refused(tmp_path: Path, text: bytes, expected: str) -> None:
    assert expected in refused(raw_file(tmp_path, json_chunk_glb(text)))


def test_json_over_its_size_or_value_limits_is_refused(tmp_path: Path) -> None:
    path = glb_file(tmp_path)
    assert "(max_json_bytes)" in refused(path, replace(DEFAULT_LIMITS, max_json_bytes=100))
    assert "holds more than 50 values (max_json_values)" in refused(path, replace(DEFAULT_LIMITS, max_json_values=50))


def test_a_gltf_json_file_that_is_no_object_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "bad.gltf"
    path.write_text('{"asset": {"version": "2.0"}, "nodes": 5}')
    assert "nodes must be a list, got the integer 5" in refused(path)


# --- the document ----------------------------------------------------------------------------------------------------

def _set(path: str, value: Any) -> Callable[[Doc], None]:
    """A change setting the member at a dotted path (list indices as numbers) to `value`."""
    keys = [int(k) if k.isdigit() else k for k in path.split(".")]

    def change(doc: Doc) -> None:
        target = doc
        for key in keys[:-1]:
            target = target[key]
        target[keys[-1]] = value
    return change


DOCUMENT_CASES: list[tuple[str, Callable[[Doc], None], str]] = [
    ("required extension", _set("extensionsRequired", ["KHR_draco_mesh_compression"]),
     "requires the glTF extension 'KHR_draco_mesh_compression', which eca does not read"),
    ("2 GB buffer", _set("buffers.0.byteLength", 2**31),
     "buffers[0].byteLength claims 2147483648 bytes, more than the file size limit"),
    ("view past buffer", _set("bufferViews.0.byteLength", 10**6),
     "bufferViews[0] (bytes 0..1000000) runs past buffers[0]"),
    ("accessor past view", _set(f"accessors.{POSITION}.count", 1000),
     f"accessors[{POSITION}]: 1000 elements of 12 bytes from byte 0 run past bufferViews["),
    ("accessor count claim", _set(f"accessors.{POSITION}.count", 2**32), "run past bufferViews["),
    ("component type", _set(f"accessors.{POSITION}.componentType", 5124), "componentType 5124 is none of glTF's"),
    ("accessor type", _set(f"accessors.{POSITION}.type", "VEC5"), "type 'VEC5' is none of SCALAR"),
    ("stride", _set("bufferViews.0.byteStride", 4), "byteStride 4 is smaller than its 12-byte elements"),
    ("index out of range", _set(f"meshes.{FACE_MESH}.primitives.0.attributes.POSITION", 999),
     "attributes.POSITION is 999, but there are only"),
    ("negative index", _set(f"meshes.{FACE_MESH}.primitives.0.indices", -1), "indices is -1, outside 0.."),
    ("not an integer", _set("nodes.0.mesh", 1.5), "nodes[0].mesh must be an integer, got the number 1.5"),
    ("zero quaternion", _set("nodes.0.rotation", [0, 0, 0, 0]),
     "nodes[0].rotation [0.0, 0.0, 0.0, 0.0] is no rotation"),
    ("own child", _set("nodes.1.children", [1]), "nodes[1] is its own child"),
    ("two parents", _set("nodes.0.children", [1, 2]), "nodes[2] has two parents, nodes[0] and nodes[1]"),
    ("cycle", lambda d: (d["nodes"][2]["children"].append(1), d["nodes"][0]["children"].remove(1)),
     "nodes[1] is in a cycle of children"),
    ("scene root child", _set("scenes.0.nodes", [0, 1]),
     "scenes[0].nodes lists nodes[1], which is the child of nodes[0]"),
    ("overflow", lambda d: [n.__setitem__("scale", [1e300] * 3) for n in d["nodes"][1:3]],
     "the transform of nodes[2] overflows to infinity"),
    ("alpha mode", _set("materials.0.alphaMode", "GLOW"), "materials[0].alphaMode 'GLOW' is none of OPAQUE"),
    ("empty skin", _set("skins.0.joints", []), "skins[0].joints is empty"),
    ("sparse index past", _set(f"accessors.{POSITION}.sparse", {
        "count": 1, "indices": {"bufferView": 0, "componentType": 5125}, "values": {"bufferView": 0}}),
     "a sparse index"),
    ("sparse past view", _set(f"accessors.{POSITION}.sparse", {
        "count": 4, "indices": {"bufferView": 0, "componentType": 5125, "byteOffset": 40},
        "values": {"bufferView": 0}}),
     ".sparse.indices: 4 elements of 4 bytes from byte 40 run past bufferViews[0]"),
]


@pytest.mark.parametrize("name, change, expected", DOCUMENT_CASES, ids=[c[0] for c in DOCUMENT_CASES])
def test_a_bad_document_is_refused(tmp_path: Path, name: str, change: Callable[[Doc], None], expected: str) -> None:
    assert expected in refused(glb_file(tmp_path, edited(change)))


def _doubled(key: str) -> Callable[[Doc], None]:
    """A change giving the document a second copy of its first `key` entry (a second image, skin, ...)."""
    return lambda d: d[key].append(copy.deepcopy(d[key][0]))


LIMIT_CASES: list[tuple[str, int, Callable[[Doc], None] | None, str]] = [
    ("max_nodes", 4, None, "nodes has 7 nodes, more than the limit of 4"),
    ("max_meshes", 1, None, "meshes has 2 meshes, more than the limit of 1"),
    ("max_accessors", 5, None, "accessors has"),
    ("max_buffer_views", 5, None, "bufferViews has"),
    ("max_buffers", 1, _doubled("buffers"), "buffers has 2 buffers, more than the limit of 1"),
    ("max_images", 1, _doubled("images"), "images has 2 images, more than the limit of 1"),
    ("max_textures", 1, _doubled("textures"), "textures has 2 textures, more than the limit of 1"),
    ("max_skins", 1, _doubled("skins"), "skins has 2 skins, more than the limit of 1"),
    ("max_materials", 1, None, "materials has 2 materials, more than the limit of 1"),
    ("max_node_depth", 1, None, "(max_node_depth)"),
    ("max_primitives", 1, None, "the meshes hold more than 1 primitives in all (max_primitives)"),
    ("max_targets", 5, None, "targets has 6 targets, more than the limit of 5"),
    ("max_vertices", 3, None, "has 4 vertices, more than the limit of 3 (max_vertices)"),
    ("max_indices", 5, None, "has 6 elements, more than the limit of 5 (max_indices)"),
    ("max_joints", 1, None, "skins[0].joints has 2 entries, more than the limit of 1"),
    ("max_total_vertices", 5, None, "more than 5 vertices in all (max_total_vertices)"),
    ("max_total_indices", 5, None, "more than 5 indices in all (max_total_indices)"),
    ("max_total_targets", 5, None, "more than 5 morph targets in all (max_total_targets)"),
    ("max_total_target_vertices", 10, None, "(max_total_target_vertices)"),
    ("max_texture_pixels", 15, None, "images[0] is 4x4 pixels, more than the limit of 15 (max_texture_pixels)"),
]


@pytest.mark.parametrize("limit, value, change, expected", LIMIT_CASES, ids=[c[0] for c in LIMIT_CASES])
def test_each_count_limit_refuses_a_file_over_it(tmp_path: Path, limit: str, value: int,
                                                 change: Callable[[Doc], None] | None, expected: str) -> None:
    doc = edited(change) if change is not None else None
    assert expected in refused(glb_file(tmp_path, doc), replace(DEFAULT_LIMITS, **{limit: value}))


def test_limits_must_be_positive_integers() -> None:
    with pytest.raises(ValueError, match="AvatarLimits.max_nodes must be a positive integer"):
        AvatarLimits(max_nodes=0)


# --- the data --------------------------------------------------------------------------------------------------------

def _blob_with(offset: int, data: bytes) -> bytes:
    blob = bytearray(BASE_BLOB)
    blob[offset:offset + len(data)] = data
    return bytes(blob)


def _view_offset(accessor: int) -> int:
    return int(BASE_DOC["bufferViews"][BASE_DOC["accessors"][accessor]["bufferView"]].get("byteOffset", 0))


def test_an_index_past_the_vertices_is_refused(tmp_path: Path) -> None:
    blob = _blob_with(_view_offset(INDICES), struct.pack("<H", 7))
    assert "indices: index 7 is past the 4 vertices" in refused(glb_file(tmp_path, blob=blob))


def test_indices_that_make_no_whole_triangles_are_refused(tmp_path: Path) -> None:
    doc = edited(_set(f"accessors.{INDICES}.count", 5))
    assert "5 indices are no whole number of triangles" in refused(glb_file(tmp_path, doc))


def test_non_finite_vertex_data_is_refused(tmp_path: Path) -> None:
    blob = _blob_with(_view_offset(POSITION), struct.pack("<f", float("nan")))
    assert f"accessors[{POSITION}] (meshes[{FACE_MESH}].primitives[0].attributes.POSITION) holds non-finite" in \
        refused(glb_file(tmp_path, blob=blob))


def test_a_joint_outside_the_skin_is_refused(tmp_path: Path) -> None:
    joints = BASE_DOC["meshes"][FACE_MESH]["primitives"][0]["attributes"]["JOINTS_0"]
    blob = _blob_with(_view_offset(joints), bytes([9]))
    assert "attributes.JOINTS_0: joint 9 is not among the skin's 2 joints" in refused(glb_file(tmp_path, blob=blob))


def test_too_few_inverse_bind_matrices_are_refused(tmp_path: Path) -> None:
    ibm = BASE_DOC["skins"][0]["inverseBindMatrices"]
    doc = edited(_set(f"accessors.{ibm}.count", 1))
    assert "skins[0].inverseBindMatrices holds 1 matrices for 2 joints" in refused(glb_file(tmp_path, doc))


def test_skins_binding_a_joint_differently_are_refused(tmp_path: Path) -> None:
    ibm = BASE_DOC["skins"][0]["inverseBindMatrices"]
    scaled = _view_offset(ibm) + 64  # the second matrix's first element: the head's bind scaled along x
    doc = edited(lambda d: (d["skins"].append(copy.deepcopy(d["skins"][0])),
                            d["nodes"].append({"mesh": FACE_MESH, "skin": 1}),
                            d["scenes"][0]["nodes"].append(len(d["nodes"]) - 1)))
    doc["accessors"].append(copy.deepcopy(doc["accessors"][ibm]))
    doc["bufferViews"].append({"buffer": 0, "byteOffset": len(BASE_BLOB), "byteLength": 128})
    doc["accessors"][-1]["bufferView"] = len(doc["bufferViews"]) - 1
    doc["skins"][1]["inverseBindMatrices"] = len(doc["accessors"]) - 1
    doc["buffers"][0]["byteLength"] = len(BASE_BLOB) + 128
    matrices = bytearray(BASE_BLOB[_view_offset(ibm):_view_offset(ibm) + 128])
    matrices[64:68] = struct.pack("<f", 2.0)
    assert scaled
    message = refused(glb_file(tmp_path, doc, BASE_BLOB + bytes(matrices)))
    assert "skins[1] binds its joints otherwise than skins[0] does" in message


def test_a_bin_chunk_shorter_than_its_buffer_is_refused(tmp_path: Path) -> None:
    doc = edited(_set("buffers.0.byteLength", len(BASE_BLOB) + 64))
    assert f"buffers[0].byteLength says {len(BASE_BLOB) + 64} bytes, the GLB's BIN chunk holds" in \
        refused(glb_file(tmp_path, doc))


# --- files and URIs a model names ------------------------------------------------------------------------------------

def gltf_with_buffer_uri(tmp_path: Path, uri: str, length: int | None = None) -> Path:
    doc = copy.deepcopy(BASE_DOC)
    doc["buffers"] = [{"uri": uri, "byteLength": len(BASE_BLOB) if length is None else length}]
    (tmp_path / "model").mkdir(exist_ok=True)
    path = tmp_path / "model" / "m.gltf"
    path.write_text(json.dumps(doc))
    return path


@pytest.mark.parametrize("uri, expected", [
    ("../secret.bin", "buffers[0]: uri '../secret.bin' points outside the model's folder"),
    ("/etc/passwd", "is neither a data URI nor a path relative to the model's file"),
    ("https://example.com/a.bin", "is neither a data URI nor a path relative"),
    ("missing.bin", "cannot open buffers[0] ('missing.bin')"),
    ("data:application/octet-stream;base64,@@@@", "buffers[0]: its data URI is not valid base64"),
    ("data:application/octet-stream,plain", "a data URI must be base64"),
])
def test_bad_buffer_uris_are_refused(tmp_path: Path, uri: str, expected: str) -> None:
    (tmp_path / "secret.bin").write_bytes(BASE_BLOB)
    assert expected in refused(gltf_with_buffer_uri(tmp_path, uri))


def test_a_buffer_file_that_is_a_device_a_pipe_or_too_short_is_refused(tmp_path: Path) -> None:
    path = gltf_with_buffer_uri(tmp_path, "zero.bin")
    os.symlink("/dev/zero", tmp_path / "model" / "zero.bin")  # a link out of the folder, to a file without end
    assert "buffers[0]: uri 'zero.bin' points outside the model's folder" in refused(path)
    os.mkfifo(tmp_path / "model" / "pipe.bin")  # reading it would wait for a writer forever
    assert "buffers[0] ('pipe.bin') is not a regular file" in refused(gltf_with_buffer_uri(tmp_path, "pipe.bin"))
    (tmp_path / "model" / "short.bin").write_bytes(BASE_BLOB[:16])
    assert "buffers[0].byteLength says" in refused(gltf_with_buffer_uri(tmp_path, "short.bin"))


def test_a_gltf_buffer_without_uri_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "m.gltf"
    path.write_text(json.dumps(BASE_DOC))
    assert "buffers[0] has no uri (only a GLB's buffers[0] may use its BIN chunk)" in refused(path)


def test_files_named_by_a_model_count_against_its_size_limit(tmp_path: Path) -> None:
    path = gltf_with_buffer_uri(tmp_path, "b.bin")
    (tmp_path / "model" / "b.bin").write_bytes(BASE_BLOB)
    limits = replace(DEFAULT_LIMITS, max_file_bytes=path.stat().st_size + 100)
    assert "buffers[0] needs" in refused(path, limits) and "max_file_bytes counts the model" in refused(path, limits)


# --- images ----------------------------------------------------------------------------------------------------------

def with_image(data: bytes) -> tuple[Doc, bytes]:
    doc = copy.deepcopy(BASE_DOC)
    pad = b"\x00" * (-len(BASE_BLOB) % 4)
    doc["bufferViews"].append({"buffer": 0, "byteOffset": len(BASE_BLOB) + len(pad), "byteLength": len(data)})
    doc["images"][0] = {"bufferView": len(doc["bufferViews"]) - 1, "mimeType": "image/png"}
    blob = BASE_BLOB + pad + data
    doc["buffers"][0]["byteLength"] = len(blob)
    return doc, blob


def test_a_large_image_is_refused_from_its_header_before_decoding(tmp_path: Path) -> None:
    doc, blob = with_image(png_header_only(5000, 5000))
    assert "images[0] is 5000x5000 pixels, more than the limit of 16777216 (max_texture_pixels)" in \
        refused(glb_file(tmp_path, doc, blob))


def test_a_texture_bomb_is_refused_from_its_header_before_decoding(tmp_path: Path) -> None:
    doc, blob = with_image(png_header_only(60_000, 60_000))
    tracemalloc.start()
    try:
        message = refused(glb_file(tmp_path, doc, blob))
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert "images[0] is 3600000000 pixels by its header, more than the limit of 16777216 (max_texture_pixels)" \
        in message
    assert peak < 20 * 2**20  # the 14 GB of pixels were never allocated


def test_images_over_the_total_pixel_limit_are_refused(tmp_path: Path) -> None:
    doc, blob = with_image(png_bytes(8, 8))
    limits = replace(DEFAULT_LIMITS, max_total_texture_pixels=32)
    assert "images[0] (8x8) takes the images past 32 pixels in all" in refused(glb_file(tmp_path, doc, blob), limits)


@pytest.mark.parametrize("data", [b"not an image at all", png_header_only(4, 4)[:40], b"GIF89a" + b"\x00" * 20])
def test_an_image_pillow_cannot_decode_is_refused(tmp_path: Path, data: bytes) -> None:
    doc, blob = with_image(data)
    assert "images[0] is no PNG, JPEG or WebP image Pillow can decode" in refused(glb_file(tmp_path, doc, blob))


# --- VRM -------------------------------------------------------------------------------------------------------------

VRM_CASES: list[tuple[str, Doc, Callable[[Doc], None], str]] = [
    ("override", VRM1_DOC, _set("extensions.VRMC_vrm.expressions.preset.happy.overrideBlink", "mute"),
     "expressions.preset.'happy'.overrideBlink 'mute' is none of none, block, blend"),
    ("lookAt type", VRM1_DOC, _set("extensions.VRMC_vrm.lookAt.type", "laser"),
     "extensions.VRMC_vrm.lookAt.type 'laser' is neither 'bone' nor 'expression'"),
    ("range map", VRM1_DOC, _set("extensions.VRMC_vrm.lookAt.rangeMapVerticalUp.inputMaxValue", -5),
     "rangeMapVerticalUp.inputMaxValue is -5.0: a range map's input must not be negative"),
    ("human bone node", VRM1_DOC, _set("extensions.VRMC_vrm.humanoid.humanBones.head.node", 99),
     "humanBones.'head'.node is 99, but there are only 7 nodes"),
    ("bind node", VRM1_DOC, _set("extensions.VRMC_vrm.expressions.preset.aa.morphTargetBinds.0.node", -2),
     "morphTargetBinds[0].node is -2, outside 0.."),
    ("expressions type", VRM1_DOC, _set("extensions.VRMC_vrm.expressions", []),
     "extensions.VRMC_vrm.expressions must be an object, got a list of 0"),
    ("0.x lookAt type", VRM0_DOC, _set("extensions.VRM.firstPerson.lookAtTypeName", "Eyes"),
     "lookAtTypeName 'Eyes' is neither 'Bone' nor 'BlendShape'"),
    ("0.x bind mesh", VRM0_DOC, _set("extensions.VRM.blendShapeMaster.blendShapeGroups.0.binds.0.mesh", 50),
     "blendShapeGroups[0].binds[0].mesh is 50, but there are only 2 meshes"),
    ("0.x bone name", VRM0_DOC, _set("extensions.VRM.humanoid.humanBones.0.bone", 7),
     "a human bone name must be a short string, got 7"),
]


@pytest.mark.parametrize("name, base, change, expected", VRM_CASES, ids=[c[0] for c in VRM_CASES])
def test_a_bad_vrm_extension_is_refused(tmp_path: Path, name: str, base: Doc, change: Callable[[Doc], None],
                                       expected: str) -> None:
    assert expected in refused(glb_file(tmp_path, edited(change, base), VRM_BLOB, "bad.vrm"))


def test_expressions_over_their_limits_are_refused(tmp_path: Path) -> None:
    path = glb_file(tmp_path, VRM1_DOC, VRM_BLOB, "m.vrm")
    assert "holds 8 expressions, more than the limit of 4 (max_expressions)" in \
        refused(path, replace(DEFAULT_LIMITS, max_expressions=4))
    assert "morphTargetBinds has 2 morphTargetBinds, more than the limit of 1" in \
        refused(path, replace(DEFAULT_LIMITS, max_binds=1))
    assert "(max_bind_targets)" in refused(path, replace(DEFAULT_LIMITS, max_bind_targets=3))


# --- claims are checked before anything follows them ----------------------------------------------------------------

@pytest.mark.parametrize("change", [
    _set("buffers.0.byteLength", 2**31 - 1),
    _set(f"accessors.{POSITION}.count", 2**31),
    lambda d: d["accessors"].__setitem__(POSITION, {"componentType": 5126, "count": 2**31, "type": "VEC3"}),
    lambda d: d["accessors"].__setitem__(INDICES, {"componentType": 5125, "count": 2**31, "type": "SCALAR"}),
])
def test_a_huge_claim_is_refused_without_allocating_it(tmp_path: Path, change: Callable[[Doc], None]) -> None:
    path = glb_file(tmp_path, edited(change))
    tracemalloc.start()
    try:
        start = time.perf_counter()
        refused(path)
        elapsed = time.perf_counter() - start
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 20 * 2**20 and elapsed < 5.0


# --- fuzzing ---------------------------------------------------------------------------------------------------------

JSON_VALUES = st.recursive(
    st.none() | st.booleans() | st.integers(-(2**40), 2**40) | st.sampled_from([0, 1, 2, 3, -1, 4, 5, 2**31, 2**32 + 1])
    | st.floats(allow_nan=False, allow_infinity=False) | st.text(max_size=12)
    | st.sampled_from(["VEC3", "SCALAR", "MAT4", "BLEND", "bone", "expression", "block", "blend", "Bone", "2.0",
                       "../x", "data:,", "data:a;base64,AAAA"]),
    lambda children: st.lists(children, max_size=4) | st.dictionaries(st.text(max_size=8), children, max_size=4),
    max_leaves=12,
)


def _paths(value: Any, prefix: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    """Every path to a member of the document (dict keys, list indices), for mutation."""
    out = [prefix] if prefix else []
    if isinstance(value, dict):
        for key, child in value.items():
            out.extend(_paths(child, (*prefix, key)))
    elif isinstance(value, list):
        for index, child in enumerate(value):
            out.extend(_paths(child, (*prefix, index)))
    return out


BASE_PATHS = {name: _paths(doc) for name, doc in (("gltf", BASE_DOC), ("vrm1", VRM1_DOC), ("vrm0", VRM0_DOC))}
BASES = {"gltf": (BASE_DOC, BASE_BLOB), "vrm1": (VRM1_DOC, VRM_BLOB), "vrm0": (VRM0_DOC, VRM_BLOB)}


RIG = RigFrame(0, np.full(52, 0.5), 10.0, -5.0, 3.0, EyeAngles(-12.0, 4.0), EyeAngles(-8.0, 4.0), np.eye(15)[3],
               np.full(18, 0.5))


def loads_or_refuses(path: Path) -> None:
    """Loading `path` returns an Avatar (which a driver then drives) or raises AvatarError (not the catch-all),
    within time and memory bounds."""
    tracemalloc.start()
    start = time.perf_counter()
    try:
        pose = AvatarDriver(load_avatar(path)).drive(RIG)
        assert all(np.isfinite(w).all() for w in pose.weights)
        assert all(np.isfinite(t).all() for t in pose.local.values())
    except AvatarError as error:
        assert "unexpected failure" not in str(error), str(error)
    finally:
        elapsed = time.perf_counter() - start
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
    assert elapsed < 5.0, f"took {elapsed:.1f} s"
    assert peak < 64 * 2**20, f"peaked at {peak / 2**20:.0f} MB"


# ECA_AVATAR_FUZZ_EXAMPLES=5000 for a longer search than the suite's
FUZZ = settings(max_examples=int(os.environ.get("ECA_AVATAR_FUZZ_EXAMPLES", "200")), deadline=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])


@FUZZ
@given(base=st.sampled_from(sorted(BASES)), data=st.data())
def test_fuzz_mutated_json_loads_or_refuses(tmp_path: Path, base: str, data: st.DataObject) -> None:
    doc, blob = BASES[base]
    doc = copy.deepcopy(doc)
    for _ in range(data.draw(st.integers(1, 3), label="mutations")):
        paths = _paths(doc)
        if not paths:
            break
        path = data.draw(st.sampled_from(paths), label="path")
        parent = doc
        for key in path[:-1]:
            parent = parent[key]
        if data.draw(st.booleans(), label="delete") and isinstance(parent, dict):
            del parent[path[-1]]
        else:
            parent[path[-1]] = data.draw(JSON_VALUES, label="value")
    loads_or_refuses(glb_file(tmp_path, doc, blob, "fuzz.glb"))


@FUZZ
@given(base=st.sampled_from(sorted(BASES)),
       edits=st.lists(st.tuples(st.integers(0, 1 << 16), st.binary(min_size=1, max_size=8)), min_size=1, max_size=6),
       cut=st.none() | st.integers(0, 1 << 16))
def test_fuzz_mutated_bytes_load_or_refuse(tmp_path: Path, base: str, edits: list[tuple[int, bytes]],
                                           cut: int | None) -> None:
    doc, blob = BASES[base]
    data = bytearray(glb_bytes(doc, blob))
    for position, patch in edits:
        at = position % len(data)
        data[at:at + len(patch)] = patch
    if cut is not None:
        del data[cut % len(data):]
    loads_or_refuses(raw_file(tmp_path, bytes(data), "fuzz.glb"))


@FUZZ
@given(base=st.sampled_from(sorted(BASES)),
       edits=st.lists(st.tuples(st.integers(0, 1 << 16), st.binary(min_size=1, max_size=8)), min_size=1, max_size=8))
def test_fuzz_mutated_binary_data_loads_or_refuses(tmp_path: Path, base: str, edits: list[tuple[int, bytes]]) -> None:
    doc, blob = BASES[base]
    data = bytearray(blob)
    for position, patch in edits:
        at = position % len(data)
        data[at:at + len(patch)] = patch[: len(data) - at]
    loads_or_refuses(glb_file(tmp_path, doc, bytes(data), "fuzz.glb"))


def test_the_fuzz_bases_load(tmp_path: Path) -> None:
    for name, (doc, blob) in BASES.items():
        assert load_avatar(glb_file(tmp_path, doc, blob, f"{name}.glb")).primitives
