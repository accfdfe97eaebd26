"""A look at a head .glb without GL: decoded with pygltflib and numpy, posed and drawn by a small software
rasteriser to PNG (`eca bake-head --preview DIR`, and the tests' checks of what the bake wrote).

It reads what the bake writes (sparse morph targets, a skin of translation-only joints, rigid meshes on nodes,
embedded PNG textures), not every glTF: the live drawer (eca/services/processes/renderer/head/) and the loader
(eca/services/processes/avatar/) are the real ones. The picture is for a person checking the bake: Lambert and
a Blinn highlight under a key, a fill and a rim light, textures sampled bilinearly, BLEND materials over the
opaque ones, 2x supersampled.
"""

from __future__ import annotations

import io
import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from pygltflib import GLTF2

_COMPONENTS = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16, 5125: np.uint32, 5126: np.float32}
_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}


@dataclass(eq=False)
class DecodedPrimitive:
    """One primitive's arrays, as stored (before any pose)."""

    name: str
    mesh: int
    material: int
    positions: np.ndarray
    normals: np.ndarray
    indices: np.ndarray  # (T, 3)
    uvs: np.ndarray | None
    joints: np.ndarray | None
    weights: np.ndarray | None
    targets: list[tuple[np.ndarray, np.ndarray | None]]  # per target: position and normal deltas
    node: int  # the node the mesh hangs on


@dataclass(eq=False)
class DecodedHead:
    """What the preview needs of a head .glb."""

    node_names: list[str]
    parents: np.ndarray  # (N,) -1 for a root
    translations: np.ndarray  # (N, 3)
    skin_joints: list[int]
    inverse_bind: np.ndarray  # (J, 4, 4), row-major
    primitives: list[DecodedPrimitive]
    target_names: list[str]
    materials: list[dict]
    images: list[np.ndarray]  # RGBA uint8


def read_accessor(document: GLTF2, blob: bytes, index: int) -> np.ndarray:
    """An accessor's data as a (count, width) array (or (count,) for SCALAR), sparse entries applied."""
    accessor = document.accessors[index]
    dtype = np.dtype(_COMPONENTS[accessor.componentType]).newbyteorder("<")
    width = _WIDTH[accessor.type]
    if accessor.bufferView is not None:
        view = document.bufferViews[accessor.bufferView]
        start = (view.byteOffset or 0) + (accessor.byteOffset or 0)
        stride = view.byteStride or dtype.itemsize * width
        if stride != dtype.itemsize * width:
            raise ValueError(f"accessor {index}: interleaved buffer views are not read here")
        data = np.frombuffer(blob, dtype=dtype, count=accessor.count * width, offset=start).copy()
        data = data.reshape(accessor.count, width)
    else:
        data = np.zeros((accessor.count, width), dtype=dtype)
    if accessor.sparse is not None:
        sparse = accessor.sparse
        iv = document.bufferViews[sparse.indices.bufferView]
        vv = document.bufferViews[sparse.values.bufferView]
        idx = np.frombuffer(blob, dtype=np.dtype(_COMPONENTS[sparse.indices.componentType]).newbyteorder("<"),
                            count=sparse.count, offset=(iv.byteOffset or 0) + (sparse.indices.byteOffset or 0))
        values = np.frombuffer(blob, dtype=dtype, count=sparse.count * width,
                               offset=(vv.byteOffset or 0) + (sparse.values.byteOffset or 0))
        data[idx.astype(np.int64)] = values.reshape(sparse.count, width)
    return data[:, 0] if width == 1 else data


def decode(glb: bytes) -> DecodedHead:
    """The nodes, skin, primitives, materials and textures of a head .glb."""
    import pygltflib
    from PIL import Image

    document = pygltflib.GLTF2.load_from_bytes(glb)
    blob = document.binary_blob()
    parents = np.full(len(document.nodes), -1)
    for i, node in enumerate(document.nodes):
        for child in node.children or []:
            parents[child] = i
    translations = np.array([node.translation or [0.0, 0.0, 0.0] for node in document.nodes], dtype=np.float64)
    skin = document.skins[0]
    inverse_bind = read_accessor(document, blob, skin.inverseBindMatrices).reshape(-1, 4, 4).transpose(0, 2, 1)
    primitives = []
    for node_index, node in enumerate(document.nodes):
        if node.mesh is None:
            continue
        for p in document.meshes[node.mesh].primitives:
            a = p.attributes

            def get(index: int | None) -> np.ndarray | None:
                return None if index is None else read_accessor(document, blob, index).astype(np.float64)

            targets = []
            for t in p.targets or []:  # pygltflib reads targets back as dicts
                entry = t if isinstance(t, dict) else {"POSITION": t.POSITION, "NORMAL": t.NORMAL}
                targets.append((read_accessor(document, blob, entry["POSITION"]).astype(np.float64),
                                get(entry.get("NORMAL"))))
            primitives.append(DecodedPrimitive(
                name=(p.extras or {}).get("name", f"mesh{node.mesh}"), mesh=node.mesh, material=p.material,
                positions=get(a.POSITION), normals=get(a.NORMAL),
                indices=read_accessor(document, blob, p.indices).astype(np.int64).reshape(-1, 3),
                uvs=get(a.TEXCOORD_0), joints=None if a.JOINTS_0 is None else read_accessor(
                    document, blob, a.JOINTS_0).astype(np.int64),
                weights=get(a.WEIGHTS_0), targets=targets, node=node_index))
    images = []
    for image in document.images:
        view = document.bufferViews[image.bufferView]
        data = blob[view.byteOffset or 0:(view.byteOffset or 0) + view.byteLength]
        with Image.open(io.BytesIO(data)) as decoded:
            images.append(np.asarray(decoded.convert("RGBA")))
    materials = []
    for m in document.materials:
        pbr = m.pbrMetallicRoughness
        texture = None
        if pbr.baseColorTexture is not None:
            texture = document.textures[pbr.baseColorTexture.index].source
        materials.append({"name": m.name, "color": np.array(pbr.baseColorFactor, dtype=np.float64),
                          "roughness": pbr.roughnessFactor, "texture": texture, "blend": m.alphaMode == "BLEND",
                          "double_sided": bool(m.doubleSided)})
    return DecodedHead([n.name for n in document.nodes], parents, translations, list(skin.joints), inverse_bind,
                       primitives, list(document.meshes[0].extras.get("targetNames", [])), materials, images)


def _rotation(yaw: float, pitch: float, roll: float) -> np.ndarray:
    """A rotation of yaw about +Y (toward the face's left... see pose), pitch about +X, roll about +Z (degrees)."""
    y, p, r = (math.radians(v) for v in (yaw, pitch, roll))
    ry = np.array([[math.cos(y), 0, math.sin(y)], [0, 1, 0], [-math.sin(y), 0, math.cos(y)]])
    rx = np.array([[1, 0, 0], [0, math.cos(p), -math.sin(p)], [0, math.sin(p), math.cos(p)]])
    rz = np.array([[math.cos(r), -math.sin(r), 0], [math.sin(r), math.cos(r), 0], [0, 0, 1]])
    return ry @ rx @ rz


def posed(head: DecodedHead, weights: dict[str, float] | None = None,
          rotations: dict[str, tuple[float, float, float]] | None = None) -> list[tuple[np.ndarray, np.ndarray]]:
    """World positions and normals of every primitive with morph `weights` (by target name) and joint
    `rotations` (node name -> yaw about +Y, pitch about -X so + is up/chin up, roll, degrees) applied."""
    weights = weights or {}
    rotations = rotations or {}
    n = len(head.node_names)
    world = np.zeros((n, 4, 4))
    for i in range(n):  # parents come first in the bake's node order
        local = np.eye(4)
        local[:3, 3] = head.translations[i]
        if head.node_names[i] in rotations:
            yaw, pitch, roll = rotations[head.node_names[i]]
            local[:3, :3] = _rotation(yaw, -pitch, roll)
        world[i] = local if head.parents[i] < 0 else world[head.parents[i]] @ local
    out = []
    for p in head.primitives:
        pos = p.positions.copy()
        nrm = p.normals.copy()
        for k, (dp, dn) in enumerate(p.targets):
            w = weights.get(head.target_names[k], 0.0)
            if w:
                pos += w * dp
                if dn is not None:
                    nrm += w * dn
        if p.joints is not None and p.weights is not None:
            mats = np.stack([world[j] @ head.inverse_bind[k] for k, j in enumerate(head.skin_joints)])
            blend = np.einsum("vk,vkab->vab", p.weights, mats[p.joints])
            pos = np.einsum("vab,vb->va", blend[:, :3, :3], pos) + blend[:, :3, 3]
            nrm = np.einsum("vab,vb->va", blend[:, :3, :3], nrm)
        else:
            m = world[p.node]
            pos = pos @ m[:3, :3].T + m[:3, 3]
            nrm = nrm @ m[:3, :3].T
        nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-12)
        out.append((pos, nrm))
    return out


def _srgb_to_linear(c: np.ndarray) -> np.ndarray:
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def _linear_to_srgb(c: np.ndarray) -> np.ndarray:
    c = np.clip(c, 0, 1)
    return np.where(c <= 0.0031308, 12.92 * c, 1.055 * c ** (1 / 2.4) - 0.055)


def render(head: DecodedHead, weights: dict[str, float] | None = None,
           rotations: dict[str, tuple[float, float, float]] | None = None, view_yaw: float = 0.0,
           size: int = 480, distance: float = 0.62, target: tuple[float, float, float] = (0.0, -0.035, 0.0),
           background: tuple[float, float, float] = (0.16, 0.17, 0.19)) -> np.ndarray:
    """An sRGB (size, size, 3) uint8 picture of the posed head from a camera `distance` m from `target`, turned
    `view_yaw` degrees about +Y from the front (positive: the camera moves to the face's left)."""
    ss = 2
    res = size * ss
    geometry = posed(head, weights, rotations)
    yaw = math.radians(view_yaw)
    eye = np.array(target) + distance * np.array([math.sin(yaw), 0.0, math.cos(yaw)])
    forward = (np.array(target) - eye) / distance
    right = np.cross(forward, [0.0, 1.0, 0.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    focal = res / (2 * math.tan(math.radians(13.0)))
    colour = np.tile(np.array(background), (res, res, 1))
    depth = np.full((res, res), np.inf)
    lights = [(np.array(d) / np.linalg.norm(d), s) for d, s in  # key (above, to the face's left), fill, rim
              (((0.55, 0.55, 0.65), 1.35), ((-0.7, 0.1, 0.5), 0.35), ((0.0, 0.6, -0.8), 0.45))]
    order = sorted(range(len(head.primitives)),
                   key=lambda i: (head.materials[head.primitives[i].material]["blend"],
                                  head.materials[head.primitives[i].material]["name"] == "cornea"))
    for i in order:
        p = head.primitives[i]
        material = head.materials[p.material]
        pos, nrm = geometry[i]
        rel = pos - eye
        cx, cy, cz = rel @ right, rel @ up, rel @ forward
        sx = res / 2 + focal * cx / cz
        sy = res / 2 - focal * cy / cz
        layer_depth = np.full((res, res), np.inf)
        layer_tri = np.full((res, res), -1)
        layer_b = np.zeros((res, res, 3))
        for t, (a, b, c) in enumerate(p.indices):
            xs, ys = sx[[a, b, c]], sy[[a, b, c]]
            area = (xs[1] - xs[0]) * (ys[2] - ys[0]) - (xs[2] - xs[0]) * (ys[1] - ys[0])
            if abs(area) < 1e-9 or (area > 0 and not material["double_sided"]):
                continue  # degenerate, or facing away (screen y points down: front faces have area < 0)
            x0, x1 = max(int(xs.min()), 0), min(int(xs.max()) + 1, res - 1)
            y0, y1 = max(int(ys.min()), 0), min(int(ys.max()) + 1, res - 1)
            if x1 < x0 or y1 < y0:
                continue
            gx, gy = np.meshgrid(np.arange(x0, x1 + 1) + 0.5, np.arange(y0, y1 + 1) + 0.5)
            w0 = ((xs[1] - gx) * (ys[2] - gy) - (xs[2] - gx) * (ys[1] - gy)) / area
            w1 = ((xs[2] - gx) * (ys[0] - gy) - (xs[0] - gx) * (ys[2] - gy)) / area
            w2 = 1 - w0 - w1
            inside = (w0 >= 0) & (w1 >= 0) & (w2 >= 0)
            if not inside.any():
                continue
            inv = w0 / cz[a] + w1 / cz[b] + w2 / cz[c]  # perspective-correct: interpolate 1/z
            z = 1 / np.where(inside, inv, 1)
            region = (slice(y0, y1 + 1), slice(x0, x1 + 1))
            closer = inside & (z < layer_depth[region]) & (z < depth[region] - 1e-5)
            layer_depth[region] = np.where(closer, z, layer_depth[region])
            layer_tri[region] = np.where(closer, t, layer_tri[region])
            bary = np.stack([w0 / cz[a], w1 / cz[b], w2 / cz[c]], axis=-1) * z[..., None]
            layer_b[region] = np.where(closer[..., None], bary, layer_b[region])
        hit = layer_tri >= 0
        if not hit.any():
            continue
        tri = p.indices[layer_tri[hit]]
        bary = layer_b[hit]
        n = (nrm[tri] * bary[..., None]).sum(axis=1)
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
        point = (pos[tri] * bary[..., None]).sum(axis=1)
        view = eye - point
        view /= np.linalg.norm(view, axis=1, keepdims=True)
        flip = (n * view).sum(axis=1) < 0
        n[flip] *= -1
        base = np.tile(material["color"][:3], (len(n), 1))
        alpha = np.full(len(n), material["color"][3])
        if material["texture"] is not None and p.uvs is not None:
            uv = (p.uvs[tri] * bary[..., None]).sum(axis=1)
            image = head.images[material["texture"]]
            h, w = image.shape[:2]
            u = np.clip(uv[:, 0] * w - 0.5, 0, w - 1.001)
            v = np.clip(uv[:, 1] * h - 0.5, 0, h - 1.001)
            iu, iv = u.astype(int), v.astype(int)
            fu, fv = (u - iu)[:, None], (v - iv)[:, None]
            texel = (image[iv, iu] * (1 - fu) * (1 - fv) + image[iv, iu + 1] * fu * (1 - fv)
                     + image[iv + 1, iu] * (1 - fu) * fv + image[iv + 1, iu + 1] * fu * fv) / 255.0
            base = base * _srgb_to_linear(texel[:, :3])
            alpha = alpha * texel[:, 3]
        shininess = 2.0 / max(material["roughness"], 0.03) ** 4
        light = np.full((len(n), 3), 0.22) * np.array([0.9, 0.95, 1.05])  # ambient, a little cool
        spec = np.zeros(len(n))
        for direction, strength in lights:
            lambert = np.clip(n @ direction, 0, None)
            light += strength * lambert[:, None]
            half = direction + view
            half /= np.linalg.norm(half, axis=1, keepdims=True)
            spec += strength * 0.04 * (shininess + 8) / 8 * np.clip((n * half).sum(axis=1), 0, None) ** shininess * (
                lambert > 0)
        shaded = base * light + spec[:, None]
        if material["blend"]:
            if material["roughness"] < 0.2:  # glass: the highlight shows whatever the coverage
                alpha = np.clip(alpha + spec * 0.5, 0, 1)
            colour[hit] = colour[hit] * (1 - alpha[:, None]) + shaded * alpha[:, None]
        else:
            colour[hit] = shaded
            depth[hit] = layer_depth[hit]
    small = colour.reshape(size, ss, size, ss, 3).mean(axis=(1, 3))
    return np.round(_linear_to_srgb(small) * 255).astype(np.uint8)


# (file name, title, morph weights, joint rotations) of the preview sheet
POSES: tuple[tuple[str, str, dict[str, float], dict[str, tuple[float, float, float]]], ...] = (
    ("neutral", "neutral", {}, {}),
    ("jaw_open", "JawOpen 1", {"JawOpen": 1.0}, {}),
    ("smile", "MouthSmileLeft+Right 1", {"MouthSmileLeft": 1.0, "MouthSmileRight": 1.0}, {}),
    ("blink_left", "EyeBlinkLeft 1", {"EyeBlinkLeft": 1.0}, {}),
    ("brows_tongue", "BrowInnerUp, BrowOuterUp L+R, TongueOut, JawOpen .4",
     {"BrowInnerUp": 1.0, "BrowOuterUpLeft": 1.0, "BrowOuterUpRight": 1.0, "TongueOut": 1.0, "JawOpen": 0.4}, {}),
    ("turned", "turned 20 to its left (Neck 8, Head 12), chin up 10; eyes 20 to its right",
     {}, {"Neck": (8.0, 4.0, 0.0), "Head": (12.0, 6.0, 0.0), "LeftEye": (-20.0, 0.0, 0.0),
          "RightEye": (-20.0, 0.0, 0.0)}),
)


def preview_sheet(glb: bytes, out_dir: Path, size: int = 360) -> list[Path]:
    """PNGs of the head in each of POSES, front and three-quarter (35 degrees to the face's left), side by
    side, and one contact sheet of them all (sheet.png). Returns the paths written."""
    from PIL import Image, ImageDraw

    head = decode(glb)
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    tiles = []
    for name, title, weights, rotations in POSES:
        pair = np.concatenate([render(head, weights, rotations, 0.0, size),
                               render(head, weights, rotations, 35.0, size)], axis=1)
        image = Image.fromarray(pair)
        ImageDraw.Draw(image).text((6, 4), title, fill=(235, 235, 235))
        path = out_dir / f"head_{name}.png"
        image.save(path)
        written.append(path)
        tiles.append(np.asarray(image))
    rows = [np.concatenate(tiles[i:i + 2], axis=1) for i in range(0, len(tiles), 2)]
    sheet = out_dir / "sheet.png"
    Image.fromarray(np.concatenate(rows, axis=0)).save(sheet)
    written.append(sheet)
    return written
