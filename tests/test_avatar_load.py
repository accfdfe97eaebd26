"""The avatar loader on small glTF and VRM files built here (tests/test_avatar_files.py): what loads, and how.

A plain glTF face with ARKit-named morph targets in three spellings, eye, head, neck and jaw nodes, a skin and a
texture; the same as .gltf with its buffer and image beside it and as data URIs; VRM 1.0 and 0.x variants with
expressions of each override kind and lookAt of each type; the geometry variants glTF allows (strides,
normalised and sparse accessors, strips, non-indexed triangles, matrices); a face that lacks what a face needs.
"""

from __future__ import annotations

import base64
import json
import logging
from pathlib import Path

import numpy as np
import pygltflib as gl
import pytest

from eca.services.processes.avatar.errors import AvatarError
from eca.services.processes.avatar.loader import load_avatar
from eca.services.processes.avatar.model import AlphaMode, Avatar, LookAtType, Override
from tests.test_avatar_files import (
    FACE_POSITIONS,
    Builder,
    face,
    glb_bytes,
    png_bytes,
    vrm0_document,
    vrm1_document,
    write,
)


def load_doc(tmp_path: Path, document: dict, blob: bytes, name: str = "model.glb") -> Avatar:
    return load_avatar(write(tmp_path, name, glb_bytes(document, blob)))


def face_primitive(avatar: Avatar) -> int:
    """The index of the skinned face quad among the avatar's primitives."""
    return next(p for p, prim in enumerate(avatar.primitives) if prim.joints is not None)


@pytest.mark.parametrize("spelling", ["camel", "pascal", "raw"])
def test_a_gltf_face_loads_with_its_arkit_shapes_under_their_pascal_names(tmp_path: Path, spelling: str) -> None:
    avatar = load_avatar(write(tmp_path, "face.glb", face(spelling).builder.glb()))
    p = face_primitive(avatar)
    assert avatar.format == "gltf" and avatar.name == "face" and avatar.source.endswith("face.glb")
    assert set(avatar.shapes) == {"EyeBlinkLeft", "EyeBlinkRight", "JawOpen", "MouthSmileLeft", "EyeLookInLeft",
                                  "BrowInnerUp"}
    assert avatar.shapes["EyeBlinkLeft"] == ((p, 0),) and avatar.shapes["BrowInnerUp"] == ((p, 5),)
    assert avatar.primitives[p].targets[0].name != "EyeBlinkLeft" or spelling == "pascal"  # the file's own name kept
    caps = avatar.capabilities
    assert (caps.eyes, caps.blink, caps.mouth) == ("bones", "arkit shapes", "arkit jawOpen")
    assert "smile: no MouthSmileRight" in caps.missing and any(m.startswith("brows: no BrowDownLeft")
                                                               for m in caps.missing)


def test_the_skeleton_is_the_node_tree_parents_first_with_the_face_bones_found_by_name(tmp_path: Path) -> None:
    avatar = load_avatar(write(tmp_path, "face.glb", face("camel").builder.glb()))
    sk = avatar.skeleton
    assert sk.names == ("Armature", "Neck", "Head", "LeftEye", "RightEye", "Jaw", "FaceMesh")
    assert sk.parents.tolist() == [-1, 0, 1, 2, 2, 2, 0]
    assert all(p < j for j, p in enumerate(sk.parents.tolist()))
    assert sk.humanoid == {"neck": 1, "head": 2, "leftEye": 3, "rightEye": 4, "jaw": 5}
    assert sk.rest[1][:3, 3].tolist() == pytest.approx([0.0, 1.4, 0.0])
    assert sk.inverse_bind[2][:3, 3].tolist() == pytest.approx([0.0, -1.5, 0.0])  # the head's bind
    assert np.allclose(sk.inverse_bind[0], np.eye(4))  # no skin joint: identity
    assert not sk.rest.flags.writeable


def test_primitives_carry_positions_normals_uvs_indices_skin_and_material(tmp_path: Path) -> None:
    avatar = load_avatar(write(tmp_path, "face.glb", face("camel").builder.glb()))
    prim = avatar.primitives[face_primitive(avatar)]
    assert np.allclose(prim.positions, FACE_POSITIONS)
    assert np.allclose(prim.normals, [[0, 0, 1]] * 4)  # computed: the quad faces +Z (counter-clockwise)
    assert prim.indices.dtype == np.uint32 and prim.indices.tolist() == [0, 1, 2, 0, 2, 3]
    assert prim.uvs is not None and prim.uvs.shape == (4, 2)
    assert prim.joints is not None and prim.weights is not None
    assert prim.joints[:, 0].tolist() == [2] * 4  # skin joint 1 (the head) is skeleton joint 2
    assert np.allclose(prim.weights.sum(axis=1), 1.0)
    assert prim.targets[2].positions[0].tolist() == pytest.approx([0.0, 0.003, 0.0])
    eyes = [q for q in avatar.primitives if q.joints is None]
    assert [q.node for q in eyes] == [3, 4]  # rigid on the eye joints
    material = avatar.materials[prim.material]
    assert material.name == "skin" and material.base_color == pytest.approx((1.0, 0.9, 0.8, 1.0))
    assert material.texture is not None and material.texture.rgba.shape == (4, 4, 4)
    assert material.texture.rgba[0, 0].tolist() == [200, 150, 120, 255] and material.roughness == pytest.approx(0.7)


def test_a_gltf_with_its_buffer_and_image_beside_it_loads_like_the_glb(tmp_path: Path) -> None:
    f = face("pascal")
    doc = f.builder.document()
    (tmp_path / "my buffer.bin").write_bytes(bytes(f.builder.blob))
    doc["buffers"] = [{"uri": "my%20buffer.bin", "byteLength": len(f.builder.blob)}]
    (tmp_path / "tex").mkdir()
    (tmp_path / "tex" / "skin.png").write_bytes(png_bytes(color=(10, 20, 30, 255)))
    doc["images"] = [{"uri": "tex/skin.png"}]
    path = tmp_path / "face.gltf"
    path.write_text(json.dumps(doc))
    avatar = load_avatar(path)
    assert set(avatar.shapes) >= {"EyeBlinkLeft", "JawOpen"}
    texture = avatar.materials[avatar.primitives[face_primitive(avatar)].material].texture
    assert texture is not None and texture.rgba[0, 0].tolist() == [10, 20, 30, 255]


def test_a_gltf_with_data_uris_loads(tmp_path: Path) -> None:
    f = face("raw")
    doc = f.builder.document()
    payload = base64.b64encode(bytes(f.builder.blob)).decode()
    doc["buffers"] = [{"uri": "data:application/octet-stream;base64," + payload, "byteLength": len(f.builder.blob)}]
    path = tmp_path / "inline.gltf"
    path.write_text(json.dumps(doc))
    avatar = load_avatar(path)
    assert "EyeBlinkRight" in avatar.shapes


def test_a_vrm1_loads_its_humanoid_expressions_overrides_lookat_and_mtoon(tmp_path: Path) -> None:
    f = face(None)
    avatar = load_doc(tmp_path, vrm1_document(f), bytes(f.builder.blob), "model.vrm")
    p = face_primitive(avatar)
    assert avatar.format == "vrm1" and avatar.name == "Test VRM 1"
    assert avatar.skeleton.humanoid["head"] == 2 and avatar.skeleton.humanoid["leftEye"] == 3
    assert avatar.skeleton.humanoid["jaw"] == 5  # not in the VRM's map: found by name
    ex = avatar.expressions
    assert list(ex) == ["happy", "angry", "sad", "aa", "blink", "lookLeft", "lookRight", "smirk"]
    assert ex["happy"].override_blink is Override.BLOCK and ex["happy"].override_mouth is Override.BLEND
    assert ex["angry"].override_blink is Override.BLEND and ex["sad"].is_binary
    assert ex["blink"].binds[1].target == 1 and ex["sad"].binds[0].weight == pytest.approx(0.5)
    # unnamed targets take the name of the expression binding them most strongly
    assert avatar.shapes["blink"] == ((p, 0), (p, 1)) and avatar.shapes["angry"] == ((p, 5),)
    look = avatar.look_at
    assert look is not None and look.type is LookAtType.BONE and look.offset == pytest.approx((0.0, 0.07, 0.01))
    assert (look.horizontal_inner.input_max_deg, look.horizontal_inner.output_scale) == (40.0, 8.0)
    assert (look.vertical_up.input_max_deg, look.vertical_up.output_scale) == (30.0, 5.0)
    caps = avatar.capabilities
    assert (caps.eyes, caps.blink, caps.mouth) == ("bones", "vrm blink", "vrm vowels")
    assert "emotions: no VRM relaxed, surprised" in caps.missing
    skin = avatar.materials[avatar.primitives[p].material]
    assert skin.toon and skin.shade_color == pytest.approx((0.3, 0.2, 0.25))


def test_a_vrm1_expression_lookat_drives_the_eyes_by_expressions(tmp_path: Path) -> None:
    f = face(None)
    avatar = load_doc(tmp_path, vrm1_document(f, "expression"), bytes(f.builder.blob), "model.vrm")
    assert avatar.look_at is not None and avatar.look_at.type is LookAtType.EXPRESSION
    assert avatar.capabilities.eyes == "vrm lookAt"
    assert "eyes: no VRM lookUp, lookDown" in avatar.capabilities.missing


def test_a_vrm0_is_turned_to_face_plus_z_with_its_presets_under_vrm1_names(tmp_path: Path) -> None:
    f = face(None, vrm0=True)
    avatar = load_doc(tmp_path, vrm0_document(f), bytes(f.builder.blob), "model.vrm")
    p = face_primitive(avatar)
    assert avatar.format == "vrm0" and avatar.name == "Test VRM 0"
    # stored facing -Z (x and z negated): turned, the face is where a +Z model has it
    assert np.allclose(avatar.primitives[p].positions, FACE_POSITIONS)
    assert avatar.primitives[p].targets[1].positions[0].tolist() == pytest.approx([0.0, 0.002, 0.0])
    left_eye = avatar.skeleton.humanoid["leftEye"]
    assert avatar.skeleton.rest[left_eye][:3, 3].tolist() == pytest.approx([0.03, 0.05, 0.08])  # +X: its left
    ex = avatar.expressions
    assert list(ex) == ["happy", "aa", "blink", "blinkLeft", "lookLeft", "lookRight", "Smirk"]
    assert ex["happy"].binds[0].weight == pytest.approx(0.8)  # 0.x weights are 0..100
    assert all(e.override_blink is Override.NONE for e in ex.values())  # 0.x has no overrides
    look = avatar.look_at
    assert look is not None and look.type is LookAtType.BONE
    assert (look.horizontal_outer.input_max_deg, look.horizontal_outer.output_scale) == (50.0, 12.0)
    assert look.offset == pytest.approx((-0.01, 0.06, 0.02))
    skin = avatar.materials[avatar.primitives[p].material]
    assert skin.toon and skin.double_sided and skin.alpha_mode is AlphaMode.MASK
    assert skin.base_color[:3] == pytest.approx((0.5**2.2,) * 3) and skin.shade_color[0] == pytest.approx(0.5**2.2)
    assert skin.texture is not None


def test_a_vrm0_blendshape_lookat_is_of_expression_type(tmp_path: Path) -> None:
    f = face(None, vrm0=True)
    avatar = load_doc(tmp_path, vrm0_document(f, "BlendShape"), bytes(f.builder.blob), "model.vrm")
    assert avatar.look_at is not None and avatar.look_at.type is LookAtType.EXPRESSION
    assert avatar.look_at.horizontal_outer.output_scale == pytest.approx(1.0)
    assert avatar.capabilities.eyes == "vrm lookAt"


def test_a_perfect_sync_vrm_names_its_targets_after_its_arkit_expressions(tmp_path: Path) -> None:
    f = face(None)
    doc = vrm1_document(f)
    node = f.nodes["face"]
    doc["extensions"]["VRMC_vrm"]["expressions"]["custom"] = {
        name: {"morphTargetBinds": [{"node": node, "index": k, "weight": 1.0}]}
        for k, name in enumerate(["eyeBlinkLeft", "EyeBlinkRight", "jawOpen"])}
    avatar = load_doc(tmp_path, doc, bytes(f.builder.blob), "model.vrm")
    p = face_primitive(avatar)
    assert avatar.shapes["JawOpen"] == ((p, 2),) and avatar.shapes["EyeBlinkLeft"] == ((p, 0),)
    assert (avatar.capabilities.blink, avatar.capabilities.mouth) == ("arkit shapes", "arkit jawOpen")


def test_visemes_are_named_in_their_gltf_spelling_and_open_the_mouth(tmp_path: Path) -> None:
    names = ["eyeBlinkLeft", "eyeBlinkRight", "viseme_AA", "viseme_ou", "viseme_I", "Viseme_PP"]
    avatar = load_avatar(write(tmp_path, "rpm.glb", face(names=names, jaw=False).builder.glb()))
    assert {"viseme_aa", "viseme_U", "viseme_I", "viseme_PP"} <= set(avatar.shapes)
    assert avatar.capabilities.mouth == "visemes"
    assert any(m.startswith("visemes: no viseme_sil") for m in avatar.capabilities.missing)


def test_what_a_face_lacks_is_said_once_as_a_warning(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    with caplog.at_level(logging.WARNING, logger="avatar"):
        load_avatar(write(tmp_path, "face.glb", face("camel").builder.glb()))
    lines = [r for r in caplog.records if r.name == "avatar"]
    assert len(lines) == 1 and "face.glb" in lines[0].getMessage() and "frown" in lines[0].getMessage()


def test_a_face_without_eyes_blink_or_mouth_is_refused_naming_all_three(tmp_path: Path) -> None:
    f = face(names=["smile", "frown"], eyes=False, jaw=False)
    with pytest.raises(AvatarError) as caught:
        load_avatar(write(tmp_path, "blank.glb", f.builder.glb()))
    message = str(caught.value)
    assert message.startswith(str(tmp_path / "blank.glb") + ": cannot be driven as a face")
    assert "eyes that turn" in message and "eyes that blink" in message and "a mouth that opens" in message


def test_eyelook_shapes_and_a_jaw_joint_are_enough(tmp_path: Path) -> None:
    names = ["eyeLookInLeft", "eyeLookOutLeft", "eyeLookInRight", "eyeLookOutRight", "eyeBlinkLeft", "eyeBlinkRight"]
    avatar = load_avatar(write(tmp_path, "f.glb", face(names=names, eyes=False).builder.glb()))
    caps = avatar.capabilities
    assert (caps.eyes, caps.blink, caps.mouth) == ("arkit shapes", "arkit shapes", "jaw bone")
    assert any(m.startswith("eyes up and down") for m in caps.missing)


# --- the geometry glTF allows ---------------------------------------------------------------------------------------


def one_triangle(b: Builder, attributes: gl.Attributes, **kwargs: object) -> int:
    """Adds a mesh of one primitive on a new root node; returns the mesh's index."""
    b.gltf.meshes.append(gl.Mesh(primitives=[gl.Primitive(attributes=attributes, **kwargs)]))  # type: ignore[arg-type]
    b.node("Extra", mesh=len(b.gltf.meshes) - 1)
    return len(b.gltf.meshes) - 1


def extra_primitive(avatar: Avatar, mesh: int) -> int:
    return next(p for p, prim in enumerate(avatar.primitives) if prim.mesh == mesh)


def base() -> Builder:
    """The test face (which a model needs to load), to add geometry to."""
    return face("pascal", texture=False).builder


TRI = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype=np.float32)


def test_interleaved_attributes_are_read_through_the_byte_stride(tmp_path: Path) -> None:
    b = base()
    normals = np.array([[0, 0, 1]] * 3, dtype=np.float32)
    interleaved = np.hstack([TRI, normals]).astype(np.float32)
    view = b.view(interleaved.tobytes(), stride=24)
    for offset in (0, 12):
        b.gltf.accessors.append(gl.Accessor(bufferView=view, byteOffset=offset, componentType=gl.FLOAT, count=3,
                                            type=gl.VEC3))
    mesh = one_triangle(b, gl.Attributes(POSITION=len(b.gltf.accessors) - 2, NORMAL=len(b.gltf.accessors) - 1))
    avatar = load_avatar(write(tmp_path, "m.glb", b.glb()))
    prim = avatar.primitives[extra_primitive(avatar, mesh)]
    assert np.allclose(prim.positions, TRI) and np.allclose(prim.normals, normals)
    assert prim.indices.tolist() == [0, 1, 2]  # generated for non-indexed geometry


def test_normalised_uvs_sparse_targets_and_strips_are_read(tmp_path: Path) -> None:
    b = base()
    quad = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], dtype=np.float32)
    position = b.accessor(quad, gl.VEC3)
    uv = b.accessor(np.array([[0, 0], [65535, 0], [0, 65535], [65535, 65535]], dtype=np.uint16), gl.VEC2,
                    gl.UNSIGNED_SHORT, normalized=True)
    sparse_index = b.view(np.array([2], dtype=np.uint8).tobytes())
    sparse_value = b.view(np.array([[0, 0, 0.5]], dtype=np.float32).tobytes())
    b.gltf.accessors.append(gl.Accessor(componentType=gl.FLOAT, count=4, type=gl.VEC3, sparse=gl.Sparse(
        count=1, indices=gl.AccessorSparseIndices(bufferView=sparse_index, componentType=gl.UNSIGNED_BYTE),
        values=gl.AccessorSparseValues(bufferView=sparse_value))))
    target = len(b.gltf.accessors) - 1
    strip = b.accessor(np.array([0, 1, 2, 3], dtype=np.uint8), gl.SCALAR, gl.UNSIGNED_BYTE)
    mesh = one_triangle(b, gl.Attributes(POSITION=position, TEXCOORD_0=uv), indices=strip, mode=gl.TRIANGLE_STRIP,
                        targets=[{"POSITION": target}], extras={"targetNames": ["eye_blink_left"]})
    avatar = load_avatar(write(tmp_path, "m.glb", b.glb()))
    p = extra_primitive(avatar, mesh)
    prim = avatar.primitives[p]
    assert prim.uvs is not None and np.allclose(prim.uvs, [[0, 0], [1, 0], [0, 1], [1, 1]])
    assert prim.indices.tolist() == [0, 1, 2, 1, 3, 2]  # the strip's second triangle turned back (glTF 3.7.2.1)
    assert np.allclose(prim.normals, [[0, 0, 1]] * 4)
    assert prim.targets[0].positions.tolist() == [[0, 0, 0], [0, 0, 0], [0, 0, 0.5], [0, 0, 0]]
    assert (p, 0) in avatar.shapes["EyeBlinkLeft"]  # the primitive's own targetNames, in a fourth spelling


def test_a_node_matrix_is_read_column_major(tmp_path: Path) -> None:
    f = face("camel")
    doc = f.builder.document()
    neck = doc["nodes"][f.nodes["neck"]]
    del neck["translation"]
    neck["matrix"] = [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0.5, 1.4, 0, 1]
    avatar = load_doc(tmp_path, doc, bytes(f.builder.blob))
    assert avatar.skeleton.rest[1][:3, 3].tolist() == pytest.approx([0.5, 1.4, 0.0])


def test_a_second_skin_bound_elsewhere_is_rebound_onto_the_first(tmp_path: Path) -> None:
    f = face("camel")
    b = f.builder
    moved = np.stack([np.eye(4), np.eye(4)])
    moved[:, :3, 3] = [[0.0, -1.4, 0.0], [0.0, -1.5, 0.0]]
    moved[:, 1, 3] += 0.25  # skin 1: the first skin's binds after a lift by 0.25, so it draws the mesh 0.25 higher
    acc = b.accessor(moved.transpose(0, 2, 1).reshape(2, 16).astype(np.float32), gl.MAT4)
    doc = b.document()
    doc["skins"].append({"joints": doc["skins"][0]["joints"], "inverseBindMatrices": acc})
    doc["nodes"].append({"name": "Face2", "mesh": f.mesh, "skin": 1})
    doc["scenes"][0]["nodes"].append(len(doc["nodes"]) - 1)
    avatar = load_doc(tmp_path, doc, bytes(b.blob))
    skinned = [prim for prim in avatar.primitives if prim.joints is not None]
    assert len(skinned) == 2
    assert np.allclose(skinned[1].positions, skinned[0].positions + [0.0, 0.25, 0.0], atol=1e-6)
