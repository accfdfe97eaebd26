"""The head's parts as written: primitives, materials and their colours, the eyes, the hair cap and the brow decal."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from eca.services.tools.head_bake.geometry import Surface, _smoothstep, clip_triangles, compact, vertex_normals
from eca.services.tools.head_bake.paint import (
    BROW_H,
    BROW_TOP,
    BROW_X,
    CORNEA_BULGE,
    CORNEA_DEG,
    above_hairline,
    brow_amount,
    eye_uv,
)

# -- the head's parts -------------------------------------------------------------------------------------------


@dataclass(eq=False)
class Part:
    """One primitive as written: positions in metres in the model frame (the eyes': in the eye joint's frame),
    its skin weights on SKIN_JOINTS (None: it hangs rigidly on a node) and its targets' deltas."""

    name: str
    material: str
    positions: np.ndarray  # (V, 3) float64
    normals: np.ndarray  # (V, 3)
    triangles: np.ndarray  # (T, 3) int64
    uvs: np.ndarray | None = None  # (V, 2), glTF's (v down)
    weights: np.ndarray | None = None  # (V, 3) on SKIN_JOINTS
    deltas: np.ndarray | None = None  # (52, V, 3) position deltas, metres
    normal_deltas: np.ndarray | None = None  # (52, V, 3)


@dataclass(frozen=True)
class MaterialSpec:
    """A glTF metallic-roughness material (metallic 0) as the bake writes it."""

    name: str
    base_color: tuple[float, float, float, float]  # linear RGBA factor
    roughness: float
    texture: str | None = None  # key into the baked images
    alpha_mode: str = "OPAQUE"
    double_sided: bool = False


@dataclass(eq=False)
class Baked:
    """Everything the writer needs: the head mesh's parts, the eye's parts, joints, materials and images."""

    head_parts: list[Part]
    eye_parts: list[Part]
    joint_positions: dict[str, np.ndarray]  # metres, model frame
    materials: list[MaterialSpec]
    images: dict[str, np.ndarray]  # name -> (H, W, C) uint8
    provenance: dict[str, object] = field(default_factory=dict)


MATERIALS = (
    MaterialSpec("skin", (1.0, 1.0, 1.0, 1.0), 0.55, texture="skin"),
    MaterialSpec("hair", (1.0, 1.0, 1.0, 1.0), 0.6, texture="hair"),
    MaterialSpec("brows", (1.0, 1.0, 1.0, 1.0), 0.8, texture="brows", alpha_mode="BLEND"),
    MaterialSpec("lashes", (1.0, 1.0, 1.0, 1.0), 0.6, texture="lashes", alpha_mode="BLEND", double_sided=True),
    MaterialSpec("teeth", (1.0, 1.0, 1.0, 1.0), 0.3, texture="mouth"),
    MaterialSpec("tongue", (1.0, 1.0, 1.0, 1.0), 0.4, texture="mouth"),
    MaterialSpec("eye", (1.0, 1.0, 1.0, 1.0), 0.35, texture="eye"),
    MaterialSpec("cornea", (1.0, 1.0, 1.0, 0.08), 0.03, alpha_mode="BLEND"),
)
TEXTURES = ("skin", "hair", "brows", "lashes", "mouth", "eye")  # in the file's order


def eye_parts(radius: float) -> list[Part]:
    """The eyeball (gaze along +Z, centred on the eye joint) and its cornea, a clear shell over the iris that
    stands out a little, for the highlight; rings are denser around the limbus so the iris stays round."""
    segments = 48
    phis = np.arange(segments) * (2 * math.pi / segments)

    def sphere(theta_list: np.ndarray, lift: Callable[[np.ndarray], np.ndarray],
               back_pole: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        th = np.radians(np.repeat(theta_list, segments))
        ph = np.tile(phis, len(theta_list))
        rr = radius + lift(np.degrees(th))
        pos = np.stack([rr * np.sin(th) * np.cos(ph), rr * np.sin(th) * np.sin(ph), rr * np.cos(th)], axis=1)
        pos = np.concatenate([[[0.0, 0.0, radius + lift(np.zeros(1))[0]]], pos])
        uv = np.concatenate([[[0.5, 0.5]], eye_uv(np.degrees(th), ph)])
        tris = [[0, 1 + s, 1 + (s + 1) % segments] for s in range(segments)]
        for ring in range(len(theta_list) - 1):
            a, b = 1 + ring * segments, 1 + (ring + 1) * segments
            for s in range(segments):
                s1 = (s + 1) % segments
                tris += [[a + s, b + s, b + s1], [a + s, b + s1, a + s1]]
        if back_pole:
            pole = len(pos)
            pos = np.concatenate([pos, [[0.0, 0.0, -radius]]])
            uv = np.concatenate([uv, [[0.5, 0.0]]])
            last = 1 + (len(theta_list) - 1) * segments
            tris += [[last + s, pole, last + (s + 1) % segments] for s in range(segments)]
        triangles = np.array(tris, dtype=np.int64)
        return pos, uv, triangles, vertex_normals(pos, triangles)

    thetas = np.concatenate([np.linspace(0, 40, 21)[1:], np.linspace(44, 176, 17)])
    pos, uv, tris, nrm = sphere(thetas, lambda t: np.zeros_like(t), True)
    eyeball = Part("eyeball", "eye", pos, nrm, tris, uvs=uv)

    def bulge(t: np.ndarray) -> np.ndarray:
        return 0.00025 + CORNEA_BULGE * np.cos(np.clip(t / CORNEA_DEG, 0, 1) * math.pi / 2) ** 2

    pos, uv, tris, nrm = sphere(np.linspace(0, CORNEA_DEG, 11)[1:], bulge, False)
    return [eyeball, Part("cornea", "cornea", pos, nrm, tris)]


# -- the bake ---------------------------------------------------------------------------------------------------


def _camel(name: str) -> str:
    return name[0].lower() + name[1:]


def _part(name: str, material: str, surface: Surface, triangles: np.ndarray, uvs: np.ndarray | None) -> Part:
    """A Part of a built surface."""
    return Part(name, material, surface["position"], surface["normal"], triangles, uvs=uvs,
                weights=surface["weights"], deltas=surface["deltas"].transpose(1, 0, 2),
                normal_deltas=surface["normal_deltas"].transpose(1, 0, 2))


def _hair_cap(skin: Surface, triangles: np.ndarray) -> Part:
    """A cap of hair over the scalp: the skin above the hairline (above_hairline), cut along it, lifted up to
    1.2 cm on the crown and down to half a millimetre at its edge, which meets the skin's painted hairline; its
    uvs are the crown's azimuthal projection, a disc with no seam (see paint_hair). The hairline passes above
    the ears, so they stay out of it."""
    surface = dict(skin)
    surface["amount"] = above_hairline(skin["position"])
    cap, tris = clip_triangles(surface, triangles, surface["amount"], 0.0)
    p = cap["position"]
    inward = _smoothstep(0.0, 0.015, cap["amount"])
    height = 0.003 + 0.009 * _smoothstep(0.0, 0.11, p[:, 1])
    cap["position"] = p + cap["normal"] * (0.0005 + height * inward)[:, None]
    crown = np.array([0.0, 0.13, -0.085])  # above the head, on its vertical axis
    axis = np.array([0.0, 1.0, 0.25]) / math.sqrt(1 + 0.25 * 0.25)  # leaning back a little
    r = cap["position"] - (crown - axis * 0.2)
    along = r[:, 0] * axis[0] + r[:, 1] * axis[1] + r[:, 2] * axis[2]
    across = r - along[:, None] * axis
    polar = np.arctan2(np.sqrt((across * across).sum(axis=1)), along)
    e2 = np.cross(axis, np.array([1.0, 0.0, 0.0]))
    azimuth = np.arctan2(across[:, 0] * e2[0] + across[:, 1] * e2[1] + across[:, 2] * e2[2], across[:, 0])
    disc = np.clip(polar / math.radians(125.0), 0.0, 1.0) * 0.48
    uvs = np.stack([0.5 + disc * np.cos(azimuth), 0.5 - disc * np.sin(azimuth)], axis=1)
    return _part("hair", "hair", cap, tris, uvs)


def _brow_decal(skin: Surface, triangles: np.ndarray) -> Part:
    """The brows: the skin's triangles under them, lifted 0.3 mm, with uvs that lay the brow texture on both
    sides at once (u by |x|, v by height; see paint_brows)."""
    near = (brow_amount(skin["position"])[triangles] > 0.0).any(axis=1)
    decal, tris = compact(skin, triangles[near])
    p = decal["position"]
    decal["position"] = p + decal["normal"] * 0.0003
    uvs = np.stack([np.abs(p[:, 0]) / BROW_X, (BROW_TOP - p[:, 1]) / BROW_H], axis=1)
    return _part("brows", "brows", decal, tris, uvs)


# -- writing ----------------------------------------------------------------------------------------------------

NORMAL_DELTA_MIN = 0.02  # a target's normal change below this (about a degree) is left out of its sparse list
