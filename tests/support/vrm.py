"""The default head as VRM files (a VRM 1.0 and a VRM 0.x written from eca/assets/default_head.glb, with its ARKit
targets bound to VRM expressions): what tests/test_head_vrm.py draws through the server's drawer, and what
tests/test_web_browser_vrm.py has a page draw with three-vrm. See tests/test_head_vrm.py's docstring for what each
file holds."""

from __future__ import annotations

import copy
import json
import struct
from pathlib import Path
from typing import Any

import numpy as np
import pygltflib as gl

from eca.agent.face.settings import load_flexor_units
from eca.services.processes.avatar.loader import DEFAULT_HEAD

EYE_RANGE = load_flexor_units().look_x_deg  # eca's eyes turn at most this far; the lookAt maps pass it unchanged
FLIP = np.array([-1.0, 1.0, -1.0], dtype=np.float32)  # half a turn about +Y: +Z-facing <-> -Z-facing

PRESETS_1: dict[str, tuple[str, ...]] = {  # VRM 1.0 preset -> the head's ARKit targets it binds
    "happy": ("MouthSmileLeft", "MouthSmileRight", "CheekSquintLeft", "CheekSquintRight"),
    "angry": ("BrowDownLeft", "BrowDownRight", "NoseSneerLeft", "NoseSneerRight"),
    "sad": ("BrowInnerUp", "MouthFrownLeft", "MouthFrownRight"),
    "surprised": ("EyeWideLeft", "EyeWideRight", "BrowInnerUp", "JawOpen"),
    "aa": ("JawOpen",),
    "oh": ("JawOpen", "MouthFunnel"),
    "ou": ("MouthPucker",),
    "ee": ("MouthStretchLeft", "MouthStretchRight"),
    "ih": ("MouthSmileLeft", "MouthSmileRight"),
    "blink": ("EyeBlinkLeft", "EyeBlinkRight"),
    "blinkLeft": ("EyeBlinkLeft",),
    "blinkRight": ("EyeBlinkRight",),
}
LOOKS = {  # VRM look expression -> the EyeLook targets (lookLeft/Right: the model's own left and right)
    "lookUp": ("EyeLookUpLeft", "EyeLookUpRight"),
    "lookDown": ("EyeLookDownLeft", "EyeLookDownRight"),
    "lookLeft": ("EyeLookOutLeft", "EyeLookInRight"),
    "lookRight": ("EyeLookInLeft", "EyeLookOutRight"),
}
PRESETS_0 = {"happy": "joy", "angry": "angry", "sad": "sorrow", "aa": "a", "ih": "i", "ou": "u", "ee": "e",
             "oh": "o", "blink": "blink", "blinkLeft": "blink_l", "blinkRight": "blink_r", "lookUp": "lookup",
             "lookDown": "lookdown", "lookLeft": "lookleft", "lookRight": "lookright"}


# -- writing the files ---------------------------------------------------------------------------------------


def head_document() -> tuple[gl.GLTF2, bytearray, dict[str, int], list[str]]:
    """The default head's document, its binary buffer (a copy to change), node name -> index, target names."""
    doc = gl.GLTF2().load(str(DEFAULT_HEAD))
    blob = bytearray(doc.binary_blob())
    nodes = {n.name: i for i, n in enumerate(doc.nodes)}
    return doc, blob, nodes, list(doc.meshes[0].extras["targetNames"])


def _glb(document: dict[str, Any], blob: bytes) -> bytes:
    """A GLB of a JSON document and a BIN chunk, each padded to 4 bytes as glTF says."""
    text = json.dumps(document, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 4)
    blob = bytes(blob) + b"\x00" * (-len(blob) % 4)
    chunks = struct.pack("<II", len(text), 0x4E4F534A) + text + struct.pack("<II", len(blob), 0x004E4942) + blob
    return struct.pack("<4sII", b"glTF", 2, 12 + len(chunks)) + chunks


def _json(doc: gl.GLTF2, blob: bytes) -> dict[str, Any]:
    doc = copy.deepcopy(doc)
    doc.buffers = [gl.Buffer(byteLength=len(blob))]
    out: dict[str, Any] = json.loads(doc.gltf_to_json())
    return out


def _flip_region(blob: bytearray, view: gl.BufferView, offset: int, count: int, done: set[tuple[int, int]]) -> None:
    """Negate x and z of `count` tightly packed float VEC3s in a buffer view, once per region."""
    start = (view.byteOffset or 0) + offset
    if (start, count) in done:
        return
    done.add((start, count))
    assert view.byteStride in (None, 12), "the default head's vertex data is tightly packed"
    values = np.frombuffer(bytes(blob[start:start + 12 * count]), dtype="<f4").reshape(count, 3) * FLIP
    blob[start:start + 12 * count] = values.astype("<f4").tobytes()


def _flip_accessor(doc: gl.GLTF2, blob: bytearray, index: int, done: set[tuple[int, int]]) -> None:
    """Turn a VEC3 float accessor (positions, normals, morph deltas) half a turn about +Y, min/max too."""
    a = doc.accessors[index]
    assert a.type == gl.VEC3 and a.componentType == gl.FLOAT
    if a.bufferView is not None:
        _flip_region(blob, doc.bufferViews[a.bufferView], a.byteOffset or 0, a.count, done)
    if a.sparse is not None:
        values = a.sparse.values
        _flip_region(blob, doc.bufferViews[values.bufferView], values.byteOffset or 0, a.sparse.count, done)
    if a.min and a.max:
        lo, hi = np.array(a.min) * FLIP, np.array(a.max) * FLIP
        a.min, a.max = np.minimum(lo, hi).tolist(), np.maximum(lo, hi).tolist()


def _face_minus_z(doc: gl.GLTF2, blob: bytearray) -> None:
    """The head turned to face -Z, as a VRM 0.x stores its model: vertices, normals and morph deltas, node
    translations and rotations, and inverse binds (R @ M @ R for R = diag(-1, 1, -1))."""
    flipped: set[int] = set()
    done: set[tuple[int, int]] = set()
    for mesh in doc.meshes:
        for prim in mesh.primitives:
            assert prim.attributes.TANGENT is None  # a tangent would turn too
            found = [prim.attributes.POSITION, prim.attributes.NORMAL]
            found += [t.get(k) for t in prim.targets or [] for k in ("POSITION", "NORMAL")]
            for index in found:
                if index is not None and index not in flipped:
                    flipped.add(index)
                    _flip_accessor(doc, blob, index, done)
    for node in doc.nodes:
        assert node.matrix is None
        if node.translation is not None:
            node.translation = (np.array(node.translation) * FLIP).tolist()
        if node.rotation is not None:
            x, y, z, w = node.rotation
            node.rotation = [-x, y, -z, w]
    r = np.diag([-1.0, 1.0, -1.0, 1.0])
    for skin in doc.skins:
        a = doc.accessors[skin.inverseBindMatrices]
        view = doc.bufferViews[a.bufferView]
        start = (view.byteOffset or 0) + (a.byteOffset or 0)
        size = 64 * a.count
        mats = np.frombuffer(bytes(blob[start:start + size]), dtype="<f4").reshape(a.count, 4, 4).transpose(0, 2, 1)
        mats = (r @ mats @ r).transpose(0, 2, 1)
        blob[start:start + size] = mats.astype("<f4").tobytes()


def vrm1_file(tmp: Path) -> Path:
    """The default head as a VRM 1.0 with a bone lookAt (see the module docstring)."""
    doc, blob, nodes, names = head_document()
    face_node = nodes["HeadMesh"]

    def binds(*targets: str) -> list[dict[str, Any]]:
        return [{"node": face_node, "index": names.index(t), "weight": 1.0} for t in targets]

    bones = {"neck": "Neck", "head": "Head", "jaw": "Jaw", "leftEye": "LeftEye", "rightEye": "RightEye"}
    identity = {"inputMaxValue": EYE_RANGE, "outputScale": EYE_RANGE}  # an eye's angle, unchanged
    document = _json(doc, blob)
    document["extensionsUsed"] = [*document.get("extensionsUsed", []), "VRMC_vrm"]
    document.setdefault("extensions", {})["VRMC_vrm"] = {
        "specVersion": "1.0",
        "meta": {"name": "eca default head (VRM 1.0)", "authors": ["eca tests"], "licenseUrl": "https://vrm.dev/"},
        "humanoid": {"humanBones": {bone: {"node": nodes[name]} for bone, name in bones.items()}},
        "expressions": {"preset": {name: {"morphTargetBinds": binds(*targets)} for name, targets in PRESETS_1.items()}},
        "lookAt": {"type": "bone", "offsetFromHeadBone": [0.0, 0.03, 0.1], "rangeMapHorizontalInner": identity,
                   "rangeMapHorizontalOuter": identity, "rangeMapVerticalDown": identity,
                   "rangeMapVerticalUp": identity},
    }
    path = tmp / "head1.vrm"
    path.write_bytes(_glb(document, blob))
    return path


def vrm0_file(tmp: Path) -> Path:
    """The default head as a VRM 0.x facing -Z with a BlendShape lookAt (see the module docstring)."""
    doc, blob, nodes, names = head_document()
    _face_minus_z(doc, blob)
    mesh = doc.nodes[nodes["HeadMesh"]].mesh

    def binds(*targets: str) -> list[dict[str, Any]]:
        return [{"mesh": mesh, "index": names.index(t), "weight": 100.0} for t in targets]

    groups = [{"name": PRESETS_0[name], "presetName": PRESETS_0[name], "binds": binds(*targets)}
              for name, targets in (*PRESETS_1.items(), *LOOKS.items()) if name in PRESETS_0]
    groups.append({"name": "Neutral", "presetName": "neutral", "binds": []})
    full = {"curve": [0, 0, 0, 1, 1, 1, 1, 0], "xRange": EYE_RANGE, "yRange": 1.0}  # weight 1 at the eye's range
    document = _json(doc, blob)
    document["extensionsUsed"] = [*document.get("extensionsUsed", []), "VRM"]
    document.setdefault("extensions", {})["VRM"] = {
        "specVersion": "0.0",
        "meta": {"title": "eca default head (VRM 0.x)", "author": "eca tests"},
        "humanoid": {"humanBones": [{"bone": bone, "node": nodes[name], "useDefaultValues": True}
                                    for bone, name in (("neck", "Neck"), ("head", "Head"), ("jaw", "Jaw"),
                                                       ("leftEye", "LeftEye"), ("rightEye", "RightEye"))]},
        "blendShapeMaster": {"blendShapeGroups": groups},
        "firstPerson": {"firstPersonBone": nodes["Head"], "firstPersonBoneOffset": {"x": 0.0, "y": 0.03, "z": 0.1},
                        "lookAtTypeName": "BlendShape", "lookAtHorizontalInner": full, "lookAtHorizontalOuter": full,
                        "lookAtVerticalDown": full, "lookAtVerticalUp": full},
    }
    path = tmp / "head0.vrm"
    path.write_bytes(_glb(document, blob))
    return path


def many_primitives_file(tmp: Path, copies: int) -> Path:
    """The default head (a plain glTF, .glb) with its mesh's primitives repeated `copies` times, each copy with its
    own morph targets' weights to drive: an avatar whose face frames are `copies` times the head's morph weights
    (a stand-in for an avatar with hundreds of morph targets)."""
    if not 1 <= copies <= 64:
        raise ValueError("1..64 copies")
    doc, blob, _, _ = head_document()
    mesh = doc.meshes[0]
    mesh.primitives = [copy.deepcopy(p) for _ in range(copies) for p in mesh.primitives]
    path = tmp / f"head_x{copies}.glb"
    path.write_bytes(_glb(_json(doc, blob), blob))
    return path
