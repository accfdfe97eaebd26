"""Small glTF and VRM files built with pygltflib for the avatar tests (test_avatar_*.py), and a check that they are
what they say: a face of a few triangles with morph targets, head, neck, jaw and eye nodes, a skin and a texture;
VRM 0.x and 1.0 variants with expressions of each override kind and lookAt of each type.

The face: a skinned quad (the "face", 4 vertices, 2 triangles) bound to the head, whose morph targets carry the
shapes; two rigid "eye" quads on the eye nodes. Node tree: root -> neck -> head -> (leftEye, rightEye, jaw).
In glTF's frame the face looks toward +Z (VRM 0.x: toward -Z, as that version stores it), its left is +X.
"""

from __future__ import annotations

import io
import json
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pygltflib as gl
from PIL import Image

ARKIT_SPELLINGS = {
    "pascal": {"blinkL": "EyeBlinkLeft", "blinkR": "EyeBlinkRight", "jaw": "JawOpen", "smileL": "MouthSmileLeft",
               "lookInL": "EyeLookInLeft", "browUp": "BrowInnerUp"},
    "camel": {"blinkL": "eyeBlinkLeft", "blinkR": "eyeBlinkRight", "jaw": "jawOpen", "smileL": "mouthSmileLeft",
              "lookInL": "eyeLookInLeft", "browUp": "browInnerUp"},
    "raw": {"blinkL": "eyeBlink_L", "blinkR": "eyeBlink_R", "jaw": "jawOpen", "smileL": "mouthSmile_L",
            "lookInL": "eyeLookIn_L", "browUp": "browInnerUp"},
}
FACE_POSITIONS = np.array([[-0.1, 1.5, 0.1], [0.1, 1.5, 0.1], [0.1, 1.7, 0.1], [-0.1, 1.7, 0.1]], dtype=np.float32)
FACE_INDICES = np.array([0, 1, 2, 0, 2, 3], dtype=np.uint16)
FACE_UVS = np.array([[0, 1], [1, 1], [1, 0], [0, 0]], dtype=np.float32)


def png_bytes(width: int = 4, height: int = 4, color: tuple[int, int, int, int] = (200, 150, 120, 255)) -> bytes:
    out = io.BytesIO()
    Image.new("RGBA", (width, height), color).save(out, format="PNG")
    return out.getvalue()


@dataclass
class Builder:
    """A glTF document and its one binary buffer, grown piece by piece."""

    gltf: gl.GLTF2 = field(default_factory=lambda: gl.GLTF2(asset=gl.Asset(version="2.0"), scenes=[gl.Scene(nodes=[])],
                                                            scene=0))
    blob: bytearray = field(default_factory=bytearray)

    def view(self, data: bytes, stride: int | None = None) -> int:
        self.blob.extend(b"\x00" * (-len(self.blob) % 4))
        self.gltf.bufferViews.append(gl.BufferView(buffer=0, byteOffset=len(self.blob), byteLength=len(data),
                                                   byteStride=stride))
        self.blob.extend(data)
        return len(self.gltf.bufferViews) - 1

    def accessor(self, array: np.ndarray, kind: str, component: int = gl.FLOAT, normalized: bool = False) -> int:
        array = np.ascontiguousarray(array)
        view = self.view(array.tobytes())
        count = array.shape[0]
        accessor = gl.Accessor(bufferView=view, componentType=component, count=count, type=kind,
                               normalized=normalized)
        if kind == gl.VEC3 and component == gl.FLOAT:
            accessor.min = array.min(axis=0).tolist()
            accessor.max = array.max(axis=0).tolist()
        self.gltf.accessors.append(accessor)
        return len(self.gltf.accessors) - 1

    def node(self, name: str, parent: int | None = None, **kwargs: Any) -> int:
        self.gltf.nodes.append(gl.Node(name=name, **kwargs))
        index = len(self.gltf.nodes) - 1
        if parent is None:
            self.gltf.scenes[0].nodes.append(index)
        else:
            self.gltf.nodes[parent].children.append(index)
        return index

    def image(self, data: bytes, mime: str = "image/png") -> int:
        self.gltf.images.append(gl.Image(bufferView=self.view(data), mimeType=mime))
        self.gltf.textures.append(gl.Texture(source=len(self.gltf.images) - 1))
        return len(self.gltf.textures) - 1

    def material(self, name: str, texture: int | None = None, **kwargs: Any) -> int:
        pbr = gl.PbrMetallicRoughness(baseColorFactor=[1.0, 0.9, 0.8, 1.0], roughnessFactor=0.7,
                                      baseColorTexture=gl.TextureInfo(index=texture) if texture is not None else None)
        self.gltf.materials.append(gl.Material(name=name, pbrMetallicRoughness=pbr, **kwargs))
        return len(self.gltf.materials) - 1

    def document(self) -> dict[str, Any]:
        """The glTF JSON as pygltflib writes it, with the one buffer."""
        self.gltf.buffers = [gl.Buffer(byteLength=len(self.blob))]
        return json.loads(self.gltf.gltf_to_json())

    def glb(self, document: dict[str, Any] | None = None) -> bytes:
        """The GLB of `document` (default: this builder's) and this builder's buffer."""
        return glb_bytes(document if document is not None else self.document(), bytes(self.blob))


def glb_bytes(document: dict[str, Any], blob: bytes) -> bytes:
    """A GLB of a JSON document and a BIN chunk, each padded to 4 bytes as glTF says."""
    text = json.dumps(document, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 4)
    blob = blob + b"\x00" * (-len(blob) % 4)
    chunks = struct.pack("<II", len(text), 0x4E4F534A) + text
    if blob:
        chunks += struct.pack("<II", len(blob), 0x004E4942) + blob
    return struct.pack("<4sII", b"glTF", 2, 12 + len(chunks)) + chunks


def _delta(dx: float = 0.0, dy: float = 0.0, dz: float = 0.0) -> np.ndarray:
    return np.tile(np.array([dx, dy, dz], dtype=np.float32), (4, 1))


@dataclass
class Face:
    """A built face: its builder, and the indices tests point at."""

    builder: Builder
    nodes: dict[str, int]
    mesh: int
    target_names: list[str]


def face(spelling: str | None = "camel", names: list[str] | None = None, vrm0: bool = False, eyes: bool = True,
         jaw: bool = True, texture: bool = True, head_rotation: list[float] | None = None) -> Face:
    """The test face: `names` are its morph targets' names (default: six ARKit shapes in `spelling`; with
    `spelling` None the six targets are unnamed); `vrm0` stores it facing -Z (x and z negated)."""
    b = Builder()
    flip = np.array([-1.0, 1.0, -1.0], dtype=np.float32) if vrm0 else np.ones(3, dtype=np.float32)
    root = b.node("Armature")
    neck = b.node("Neck", root, translation=[0.0, 1.4, 0.0])
    head = b.node("Head", neck, translation=[0.0, 0.1, 0.0], rotation=head_rotation)
    nodes = {"root": root, "neck": neck, "head": head}
    if eyes:
        for side, x in (("Left", 0.03), ("Right", -0.03)):
            nodes[f"{side.lower()}Eye"] = b.node(f"{side}Eye", head, translation=[float(x * flip[0]), 0.05,
                                                                                   float(0.08 * flip[2])])
    if jaw:
        nodes["jaw"] = b.node("Jaw", head, translation=[0.0, -0.02, float(0.02 * flip[2])])

    if names is None:
        names = list(ARKIT_SPELLINGS[spelling].values()) if spelling is not None else [f"target{k}" for k in range(6)]
    positions = FACE_POSITIONS * flip
    attributes = gl.Attributes(POSITION=b.accessor(positions, gl.VEC3), TEXCOORD_0=b.accessor(FACE_UVS, gl.VEC2))
    # skin: every vertex on the head (joint 1 of [neck, head])
    attributes.JOINTS_0 = b.accessor(np.tile(np.array([1, 0, 0, 0], dtype=np.uint8), (4, 1)), gl.VEC4,
                                     gl.UNSIGNED_BYTE)
    attributes.WEIGHTS_0 = b.accessor(np.tile(np.array([1, 0, 0, 0], dtype=np.float32), (4, 1)), gl.VEC4)
    targets = []
    for k in range(len(names)):
        targets.append({"POSITION": b.accessor(_delta(dy=0.001 * (k + 1)) * flip, gl.VEC3)})
    material = b.material("skin", b.image(png_bytes()) if texture else None)
    prim = gl.Primitive(attributes=attributes, indices=b.accessor(FACE_INDICES, gl.SCALAR, gl.UNSIGNED_SHORT),
                        material=material, targets=targets)  # type: ignore[arg-type]
    extras = {"targetNames": names} if spelling is not None else {}  # VRM faces: unnamed, bound by expressions
    b.gltf.meshes.append(gl.Mesh(name="Face", primitives=[prim], extras=extras))
    face_mesh = len(b.gltf.meshes) - 1
    # inverse binds: joint space from model space (translations only)
    world = {neck: np.array([0.0, 1.4, 0.0]), head: np.array([0.0, 1.5, 0.0])}
    binds = np.stack([_translation(-world[neck]), _translation(-world[head])]).transpose(0, 2, 1)
    b.gltf.skins.append(gl.Skin(joints=[neck, head], inverseBindMatrices=b.accessor(
        binds.reshape(2, 16).astype(np.float32), gl.MAT4)))
    nodes["face"] = b.node("FaceMesh", root, mesh=face_mesh, skin=0)
    if eyes:
        eye_mesh = gl.Mesh(name="Eye", primitives=[gl.Primitive(
            attributes=gl.Attributes(POSITION=b.accessor(FACE_POSITIONS[:3] * 0.05, gl.VEC3)),
            material=b.material("eye"))])
        b.gltf.meshes.append(eye_mesh)
        for side in ("leftEye", "rightEye"):
            b.gltf.nodes[nodes[side]].mesh = len(b.gltf.meshes) - 1
    return Face(b, nodes, face_mesh, names)


def _translation(t: np.ndarray) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = t
    return m


def vrm1_document(f: Face, look_at_type: str = "bone") -> dict[str, Any]:
    """`f` (built with unnamed targets 0..5) as a VRM 1.0: blink binds t0+t1, happy t3 (overrideBlink block,
    overrideMouth blend), angry t5 (overrideBlink blend), sad isBinary on t5 (overrideMouth block), aa t2, lookLeft
    t4 and lookRight t5; lookAt of `look_at_type` with distinct range maps; an MToon material."""
    doc = f.builder.document()
    face_node = f.nodes["face"]

    def bind(*targets: int, weight: float = 1.0) -> list[dict[str, Any]]:
        return [{"node": face_node, "index": t, "weight": weight} for t in targets]

    doc["extensionsUsed"] = ["VRMC_vrm", "VRMC_materials_mtoon"]
    doc["extensions"] = {"VRMC_vrm": {
        "specVersion": "1.0",
        "meta": {"name": "Test VRM 1"},
        "humanoid": {"humanBones": {"hips": {"node": f.nodes["root"]}, "neck": {"node": f.nodes["neck"]},
                                    "head": {"node": f.nodes["head"]}, "leftEye": {"node": f.nodes["leftEye"]},
                                    "rightEye": {"node": f.nodes["rightEye"]}}},
        "expressions": {
            "preset": {
                "blink": {"morphTargetBinds": bind(0, 1)},
                "happy": {"morphTargetBinds": bind(3), "overrideBlink": "block", "overrideMouth": "blend"},
                "angry": {"morphTargetBinds": bind(5), "overrideBlink": "blend"},
                "sad": {"morphTargetBinds": bind(5, weight=0.5), "isBinary": True, "overrideMouth": "block"},
                "aa": {"morphTargetBinds": bind(2)},
                "lookLeft": {"morphTargetBinds": bind(4)},
                "lookRight": {"morphTargetBinds": bind(5)},
            },
            "custom": {"smirk": {"morphTargetBinds": bind(3, weight=0.5)}},
        },
        "lookAt": {
            "type": look_at_type,
            "offsetFromHeadBone": [0.0, 0.07, 0.01],
            "rangeMapHorizontalInner": {"inputMaxValue": 40.0, "outputScale": 8.0},
            "rangeMapHorizontalOuter": {"inputMaxValue": 40.0, "outputScale": 10.0 if look_at_type == "bone"
                                        else 1.0},
            "rangeMapVerticalDown": {"inputMaxValue": 30.0, "outputScale": 6.0},
            "rangeMapVerticalUp": {"inputMaxValue": 30.0, "outputScale": 5.0},
        },
    }}
    doc["materials"][0].setdefault("extensions", {})["VRMC_materials_mtoon"] = {
        "specVersion": "1.0", "shadeColorFactor": [0.3, 0.2, 0.25]}
    return doc


def vrm0_document(f: Face, look_at_type: str = "Bone") -> dict[str, Any]:
    """`f` (built with `vrm0=True`, unnamed targets 0..5) as a VRM 0.x: Blink on t0+t1 (weight 100), Joy t3 (weight 80),
    A t2, Blink_L t0, LookLeft t4, a custom "Smirk"; firstPerson lookAt of `look_at_type` with degree maps;
    MToon material properties."""
    doc = f.builder.document()
    mesh = f.mesh

    def bind(*targets: int, weight: float = 100.0) -> list[dict[str, Any]]:
        return [{"mesh": mesh, "index": t, "weight": weight} for t in targets]

    doc["extensionsUsed"] = ["VRM"]
    doc["extensions"] = {"VRM": {
        "specVersion": "0.0",
        "meta": {"title": "Test VRM 0"},
        "humanoid": {"humanBones": [{"bone": "hips", "node": f.nodes["root"]},
                                    {"bone": "neck", "node": f.nodes["neck"]},
                                    {"bone": "head", "node": f.nodes["head"]},
                                    {"bone": "leftEye", "node": f.nodes["leftEye"]},
                                    {"bone": "rightEye", "node": f.nodes["rightEye"]}]},
        "blendShapeMaster": {"blendShapeGroups": [
            {"name": "Blink", "presetName": "blink", "binds": bind(0, 1)},
            {"name": "Joy", "presetName": "joy", "binds": bind(3, weight=80.0)},
            {"name": "A", "presetName": "a", "binds": bind(2)},
            {"name": "Blink_L", "presetName": "blink_l", "binds": bind(0)},
            {"name": "LookLeft", "presetName": "lookleft", "binds": bind(4)},
            {"name": "LookRight", "presetName": "lookright", "binds": bind(5)},
            {"name": "Smirk", "presetName": "unknown", "binds": bind(3, weight=50.0)},
        ]},
        "firstPerson": {
            "firstPersonBone": f.nodes["head"],
            "firstPersonBoneOffset": {"x": 0.01, "y": 0.06, "z": 0.02},
            "lookAtTypeName": look_at_type,
            "lookAtHorizontalInner": {"curve": [0, 0, 0, 1, 1, 1, 1, 0], "xRange": 50.0, "yRange": 9.0},
            "lookAtHorizontalOuter": {"curve": [0, 0, 0, 1, 1, 1, 1, 0], "xRange": 50.0,
                                      "yRange": 12.0 if look_at_type == "Bone" else 1.0},
            "lookAtVerticalDown": {"xRange": 40.0, "yRange": 7.0},
            "lookAtVerticalUp": {"xRange": 40.0, "yRange": 6.0},
        },
        "materialProperties": [
            {"name": "skin", "shader": "VRM/MToon",
             "vectorProperties": {"_Color": [0.5, 0.5, 0.5, 1.0], "_ShadeColor": [0.5, 0.25, 0.25, 1.0]},
             "floatProperties": {"_CullMode": 0.0}, "textureProperties": {"_MainTex": 0},
             "keywordMap": {"_ALPHATEST_ON": True}},
        ],
    }}
    return doc


def write(tmp: Path, name: str, data: bytes) -> Path:
    path = tmp / name
    path.write_bytes(data)
    return path


def test_the_built_face_reads_back_with_pygltflib() -> None:
    f = face("camel")
    loaded = gl.GLTF2.load_from_bytes(f.builder.glb())
    assert [n.name for n in loaded.nodes][:4] == ["Armature", "Neck", "Head", "LeftEye"]
    assert loaded.meshes[f.mesh].extras["targetNames"][0] == "eyeBlinkLeft"
    assert len(loaded.meshes[f.mesh].primitives[0].targets) == 6
