"""A procedural avatar: a small stylised head built in memory, for the drawer's tests, its benchmark and a look
at the drawer before any model file exists.

It holds what a face avatar file holds, in glTF's frame (metres, +y up, facing +z, its left +x):

- a skeleton root -> neck -> head -> (jaw, leftEye, rightEye), with VRM humanoid names;
- the head: an ellipsoid (a UV sphere, about 4.6k vertices) skinned to head and jaw, with a mouth slit whose lower
  lip hangs on the jaw (so the jaw bone opens the mouth), a nose bump, a painted sRGB texture (hair, brows, lips)
  and 51 ARKit morph targets in PascalCase (brows, cheeks, nose, lips and mouth corners; JawOpen is the jaw
  bone's, EyeBlink/Wide/Squint the lids'), each a smooth local push of the skin;
- a neck, skinned to root, neck and head;
- two eyes, each a sphere textured in its front view (sclera, iris, pupil at +z) rigid on its eye joint, under a
  glossy cornea (BLEND: drawn after the opaque parts);
- upper and lower lids, shells around the eyes rigid on the head, with EyeBlink, EyeWide, EyeSquint and the lids'
  follow of the gaze (EyeLookUp/Down) as morph targets that move their edges; a dark lash line along the upper;
- a dark mouth cavity inside the head, seen through the open mouth.

`sample_avatar(toon=True)` gives the same head with MToon-like materials.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

from eca.agent.rig.names import ARKIT_NAMES
from eca.services.processes.avatar.model import (
    AlphaMode,
    Avatar,
    Capabilities,
    Material,
    MorphTarget,
    Primitive,
    Skeleton,
    Texture,
)

# Head frame (metres, relative to the head ellipsoid's centre).
HEAD_CENTRE = np.array([0.0, 1.65, 0.012])
HEAD_JOINT, NECK_JOINT = np.array([0.0, 1.55, 0.0]), np.array([0.0, 1.45, -0.005])
HEAD_AXES = np.array([0.078, 0.112, 0.095])  # semi-axes x, y, z
EYE_X, EYE_Y, EYE_RADIUS = 0.032, 0.022, 0.0125
MOUTH_Y, MOUTH_HALF_WIDTH = -0.052, 0.024
BROW_Y = 0.045
NOSE = (0.0, -0.012, 0.012, 0.016)  # x, y, height, radius of the nose bump
JOINTS = ("root", "neck", "head", "jaw", "leftEye", "rightEye")
ROOT, NECK, HEAD, JAW, LEFT_EYE, RIGHT_EYE = range(6)
IRIS_ANGLE, PUPIL_ANGLE = 0.52, 0.24  # radians from the eye's front
# Where each lid's edge is (degrees of elevation about the eye's centre) at rest and at each of its targets.
LID_EDGES_DEG = {
    "upper": {"rest": 24.0, "EyeBlink": -10.0, "EyeWide": 40.0, "EyeSquint": 12.0, "EyeLookDown": 10.0,
              "EyeLookUp": 32.0},
    "lower": {"rest": -42.0, "EyeBlink": -10.0, "EyeWide": -48.0, "EyeSquint": -26.0, "EyeLookDown": -50.0,
              "EyeLookUp": -36.0},
}

# sRGB colours of the painted parts.
SKIN = (0.93, 0.75, 0.63)
HAIR = (0.33, 0.21, 0.14)
BROW = (0.24, 0.15, 0.10)
LIP = (0.80, 0.45, 0.44)
SCLERA = (0.96, 0.95, 0.93)
IRIS = (0.20, 0.45, 0.62)
PUPIL = (0.03, 0.03, 0.04)


def srgb_to_linear(c: tuple[float, ...] | np.ndarray) -> np.ndarray:
    c = np.asarray(c, dtype=np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def _lin(c: tuple[float, float, float], alpha: float = 1.0) -> tuple[float, float, float, float]:
    r, g, b = (float(v) for v in srgb_to_linear(c))
    return (r, g, b, alpha)


def _smoothstep(e0: float, e1: float, x: np.ndarray) -> np.ndarray:
    t = np.clip((x - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def _translation(x: float, y: float, z: float) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = (x, y, z)
    return m


def _skeleton() -> Skeleton:
    """Joints with their rest transforms: plain translations, as a VRM 1.0 humanoid has."""
    jaw = HEAD_CENTRE + (0.0, -0.018, -0.018)
    eye_l = HEAD_CENTRE + (EYE_X, EYE_Y, _eye_depth())
    eye_r = HEAD_CENTRE + (-EYE_X, EYE_Y, _eye_depth())
    globals_ = [np.zeros(3), NECK_JOINT, HEAD_JOINT, jaw, eye_l, eye_r]
    parents = np.array([-1, ROOT, NECK, HEAD, HEAD, HEAD], dtype=np.int32)
    rest = np.stack([_translation(*(g - (globals_[p] if p >= 0 else 0.0)))
                     for g, p in zip(globals_, parents, strict=True)])
    inverse_bind = np.stack([_translation(*(-g)) for g in globals_])
    for a in (rest, inverse_bind):
        a.flags.writeable = False
    humanoid = {"hips": ROOT, "neck": NECK, "head": HEAD, "jaw": JAW, "leftEye": LEFT_EYE, "rightEye": RIGHT_EYE}
    return Skeleton(JOINTS, parents, rest, inverse_bind, humanoid)


def _surface_z(x: float, y: float) -> float:
    a, b, c = HEAD_AXES
    return float(c * math.sqrt(max(1.0 - (x / a) ** 2 - (y / b) ** 2, 0.0)))


def _eye_depth() -> float:
    """The eye centre's z in the head frame: 0.6 radii behind the skin, so about the front 50 degrees show."""
    return _surface_z(EYE_X, EYE_Y) - 0.6 * EYE_RADIUS


def _uv_sphere(n_theta: int, n_phi: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Grid angles (theta from the +y pole, phi from the front +z toward +x) and UVs, (n_theta+1)*(n_phi+1)."""
    theta = np.linspace(0.0, math.pi, n_theta + 1)
    phi = np.linspace(-math.pi, math.pi, n_phi + 1)  # the seam at the back
    th, ph = np.meshgrid(theta, phi, indexing="ij")
    uv = np.stack([(ph + math.pi) / (2 * math.pi), th / math.pi], -1)
    return th.reshape(-1), ph.reshape(-1), uv.reshape(-1, 2)


def _grid_indices(n_rows: int, n_cols: int) -> np.ndarray:
    """Two counter-clockwise (seen from outside) triangles per quad of a (n_rows+1) x (n_cols+1) vertex grid whose
    rows go down and columns go to the model's left (+x) seen from the front."""
    r, c = np.meshgrid(np.arange(n_rows), np.arange(n_cols), indexing="ij")
    a = r * (n_cols + 1) + c
    b = a + 1
    d = a + (n_cols + 1)
    e = d + 1
    return np.stack([a, d, b, b, d, e], -1).reshape(-1, 3)


def _ellipsoid(th: np.ndarray, ph: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a, b, c = HEAD_AXES
    s = np.sin(th)
    p = np.stack([a * s * np.sin(ph), b * np.cos(th), c * s * np.cos(ph)], -1)
    n = p / (HEAD_AXES**2)
    return p, n / np.linalg.norm(n, axis=1, keepdims=True)


def _bump(p: np.ndarray, cx: float, cy: float, radius: float, front: float = 0.0) -> np.ndarray:
    """A smooth falloff around (cx, cy) on the face (x, y in the head frame), zero on the back half."""
    d2 = (p[:, 0] - cx) ** 2 + (p[:, 1] - cy) ** 2
    return np.exp(-d2 / (2.0 * radius**2)) * _smoothstep(front, front + 0.03, p[:, 2])


def _head_shapes(p: np.ndarray, n: np.ndarray, lower: np.ndarray) -> dict[str, np.ndarray]:
    """ARKit shapes as local pushes of the head's skin (head frame, metres); "Left" is the face's left, +x."""
    upper = ~lower
    mouth = np.where(np.abs(p[:, 1] - MOUTH_Y) < 0.03, 1.0, 0.0) * _smoothstep(0.05, 0.07, p[:, 2])
    shapes: dict[str, np.ndarray] = {}

    def add(name: str, weight: np.ndarray, delta: tuple[float, float, float]) -> None:
        shapes[name] = shapes.get(name, np.zeros_like(p)) + weight[:, None] * np.asarray(delta)

    for side, sx in (("Left", 1.0), ("Right", -1.0)):
        # Brows: inner and outer ends, and the whole brow down and in.
        add(f"BrowDown{side}", _bump(p, sx * 0.03, BROW_Y, 0.014), (-sx * 0.002, -0.006, 0.0))
        add(f"BrowOuterUp{side}", _bump(p, sx * 0.05, BROW_Y - 0.004, 0.011), (sx * 0.001, 0.008, 0.0))
        add(f"CheekSquint{side}", _bump(p, sx * 0.04, -0.008, 0.012), (0.0, 0.004, 0.002))
        add(f"NoseSneer{side}", _bump(p, sx * 0.011, -0.008, 0.008), (0.0, 0.004, 0.0))
        add(f"EyeSquint{side}", _bump(p, sx * EYE_X, EYE_Y - 0.02, 0.008), (0.0, 0.003, 0.001))
        add(f"EyeWide{side}", _bump(p, sx * EYE_X, EYE_Y + 0.02, 0.008), (0.0, 0.002, 0.0))
        add(f"EyeBlink{side}", _bump(p, sx * EYE_X, EYE_Y + 0.018, 0.008), (0.0, -0.001, 0.0))
        for look, delta in (("Up", (0.0, 0.002, 0.0)), ("Down", (0.0, -0.002, 0.0)),
                            ("In", (-sx * 0.0015, 0.0, 0.0)), ("Out", (sx * 0.0015, 0.0, 0.0))):
            add(f"EyeLook{look}{side}", _bump(p, sx * EYE_X, EYE_Y + 0.02, 0.01), delta)
        corner = _bump(p, sx * MOUTH_HALF_WIDTH, MOUTH_Y, 0.011)
        add(f"MouthSmile{side}", corner, (sx * 0.004, 0.008, -0.003))
        add(f"MouthFrown{side}", corner, (sx * 0.001, -0.007, 0.0))
        add(f"MouthDimple{side}", corner, (sx * 0.002, 0.0, -0.005))
        add(f"MouthStretch{side}", corner, (sx * 0.007, -0.002, -0.002))
        add(f"MouthPress{side}", _bump(p, sx * 0.012, MOUTH_Y, 0.01) * mouth,
            (0.0, 0.0, -0.002))
        add(f"MouthPress{side}", _bump(p, sx * 0.012, MOUTH_Y - 0.004, 0.008) * lower, (0.0, 0.002, 0.0))
        add(f"MouthLowerDown{side}", _bump(p, sx * 0.011, MOUTH_Y - 0.004, 0.01) * lower, (0.0, -0.006, 0.001))
        add(f"MouthUpperUp{side}", _bump(p, sx * 0.011, MOUTH_Y + 0.004, 0.01) * upper, (0.0, 0.005, 0.001))
    # CheekPuff pushes along the skin's normal.
    cheeks = _bump(p, 0.048, -0.035, 0.018) + _bump(p, -0.048, -0.035, 0.018)
    shapes["CheekPuff"] = cheeks[:, None] * n * 0.01
    lips = _bump(p, 0.0, MOUTH_Y, 0.016)
    add("BrowInnerUp", _bump(p, 0.012, BROW_Y - 0.002, 0.01) + _bump(p, -0.012, BROW_Y - 0.002, 0.01),
        (0.0, 0.008, 0.0))
    shapes["MouthPucker"] = lips[:, None] * np.stack([-p[:, 0] * 0.35, np.zeros(len(p)), np.full(len(p), 0.009)], -1)
    shapes["MouthFunnel"] = lips[:, None] * np.stack(
        [-p[:, 0] * 0.2, np.where(lower, -0.004, 0.003), np.full(len(p), 0.007)], -1)
    add("MouthLeft", lips, (0.008, 0.0, 0.0))
    add("MouthRight", lips, (-0.008, 0.0, 0.0))
    add("MouthRollLower", _bump(p, 0.0, MOUTH_Y - 0.005, 0.012) * lower, (0.0, 0.001, -0.004))
    add("MouthRollUpper", _bump(p, 0.0, MOUTH_Y + 0.005, 0.012) * upper, (0.0, -0.001, -0.004))
    add("MouthShrugLower", _bump(p, 0.0, MOUTH_Y - 0.012, 0.014) * lower, (0.0, 0.004, 0.003))
    add("MouthShrugUpper", _bump(p, 0.0, MOUTH_Y + 0.008, 0.014) * upper, (0.0, 0.002, 0.003))
    add("MouthClose", _bump(p, 0.0, MOUTH_Y - 0.004, 0.014) * lower, (0.0, 0.008, 0.0))
    chin = _bump(p, 0.0, MOUTH_Y - 0.035, 0.025) * lower
    add("JawForward", chin, (0.0, 0.0, 0.008))
    add("JawLeft", chin, (0.008, 0.0, 0.0))
    add("JawRight", chin, (-0.008, 0.0, 0.0))
    add("TongueOut", _bump(p, 0.0, MOUTH_Y - 0.006, 0.008) * lower, (0.0, -0.002, 0.0))
    return shapes


@lru_cache(maxsize=2)
def _head_texture() -> Texture:
    """The head's skin with hair, brows and lips painted at the places the mesh puts them (the mesh's UVs are
    its angles, so each texel knows its point on the ellipsoid)."""
    width, height = 1024, 512
    u = (np.arange(width) + 0.5) / width
    v = (np.arange(height) + 0.5) / height
    th, ph = np.meshgrid(v * math.pi, u * 2 * math.pi - math.pi, indexing="ij")
    p, _ = _ellipsoid(th.reshape(-1), ph.reshape(-1))
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    rgb = np.tile(np.asarray(SKIN), (len(x), 1))
    soft = 0.0006  # metres: about a texel at the front, so painted edges are smooth when magnified

    def paint(color: tuple[float, float, float], inside: np.ndarray) -> None:
        """Blend `color` in by coverage `inside` (a signed distance in metres, > 0 inside)."""
        a = _smoothstep(-soft, soft, inside)[:, None]
        rgb[:] = rgb * (1.0 - a) + np.asarray(color) * a

    # Hair: a cap over the top and the back, with a hairline across the forehead.
    hairline = 0.068 + 0.012 * (x / HEAD_AXES[0]) ** 2
    cap = np.maximum.reduce([y - hairline, np.minimum(-0.02 - z, y + 0.03),
                             np.minimum.reduce([0.02 - z, y - 0.02, np.abs(x) - 0.06])])
    paint(HAIR, cap)
    # Brows: arcs above the eyes, thicker toward the nose.
    for sx in (1.0, -1.0):
        t = (sx * x - 0.012) / 0.05  # 0 at the inner end, 1 at the outer
        arc = BROW_Y + 0.004 * np.sin(np.clip(t, 0, 1) * math.pi) - 0.003 * t
        thick = 0.0032 * (1.2 - 0.5 * np.clip(t, 0, 1))
        ends = np.minimum(t, 1.0 - t) * 0.05
        paint(BROW, np.minimum.reduce([thick - np.abs(y - arc), ends, z]))
    # Lips: a rosy band about the mouth line, fuller below.
    w = np.clip(1 - (x / (MOUTH_HALF_WIDTH * 1.05)) ** 2, 0, 1)
    lip = np.minimum.reduce([MOUTH_Y + 0.0055 * w - y, y - (MOUTH_Y - 0.0075 * w), z])
    paint(LIP, np.where(w > 0, lip, -1.0))
    # Cheeks: a little colour.
    for sx in (1.0, -1.0):
        d = np.hypot(x - sx * 0.045, y + 0.022)
        blush = np.clip(1 - d / 0.02, 0, 1)[:, None] * (z > 0)[:, None] * 0.25
        rgb[:] = rgb * (1 - blush) + np.asarray((0.95, 0.6, 0.58)) * blush
    rgba = np.concatenate([rgb, np.ones((len(x), 1))], 1).reshape(height, width, 4)
    data = np.round(rgba * 255).astype(np.uint8)
    data.flags.writeable = False
    return Texture(data)


@lru_cache(maxsize=2)
def _eye_texture() -> Texture:
    """Sclera, iris and pupil as seen from the front: the eye's UVs are its front view (`_eye_uvs`), so a point
    at angle a from the eye's front lies sin(a) / 2 from the texture's centre."""
    size = 128
    c = (np.arange(size) + 0.5) / size - 0.5
    r = np.hypot(*np.meshgrid(c, c, indexing="ij"))
    iris_r, pupil_r = 0.5 * math.sin(IRIS_ANGLE), 0.5 * math.sin(PUPIL_ANGLE)
    edge = 1.0 / size

    def inside(radius: float) -> np.ndarray:
        return _smoothstep(radius + edge, radius - edge, r)[..., None]

    iris = np.asarray(IRIS) * (0.75 + 0.35 * np.clip(r / iris_r, 0, 1))[..., None]
    iris = iris * (1 - 0.55 * _smoothstep(iris_r - 3 * edge, iris_r, r))[..., None]  # a darker limbal ring
    rgb = np.asarray(SCLERA) * (1 - inside(iris_r)) + iris * inside(iris_r)
    rgb = rgb * (1 - inside(pupil_r)) + np.asarray(PUPIL) * inside(pupil_r)
    rgba = np.concatenate([rgb, np.ones((size, size, 1))], -1)
    data = np.round(rgba * 255).astype(np.uint8)
    data.flags.writeable = False
    return Texture(data)


def _eye_uvs(normals: np.ndarray) -> np.ndarray:
    """An eye's front view as UVs (x to the right of the texture, y down it; the back folds onto the front)."""
    return np.stack([0.5 + 0.5 * normals[:, 0], 0.5 - 0.5 * normals[:, 1]], -1).astype(np.float32)


@lru_cache(maxsize=2)
def _lid_texture() -> Texture:
    """Skin down the lid, then a dark lash line at its edge (v = 1)."""
    v = (np.arange(64) + 0.5) / 64
    rgb = np.where((v > 0.86)[:, None], np.asarray((0.12, 0.08, 0.07)), np.asarray(SKIN) * 0.96)
    rgba = np.concatenate([rgb, np.ones((64, 1))], 1)
    data = np.round(np.repeat(rgba[:, None, :], 4, axis=1) * 255).astype(np.uint8)
    data.flags.writeable = False
    return Texture(data)


def _head(mesh: int) -> tuple[Primitive, np.ndarray]:
    """The skinned head (positions in the model's bind pose) and its vertices' head-frame positions."""
    n_theta, n_phi = 56, 80
    th, ph, uv = _uv_sphere(n_theta, n_phi)
    p, n = _ellipsoid(th, ph)
    nose = _bump(p, NOSE[0], NOSE[1], NOSE[3] * 0.5) * NOSE[2]
    p = p + n * nose[:, None]
    tris = _grid_indices(n_theta, n_phi)
    # The mouth: the grid row nearest the mouth line is split across the mouth's width; the triangles below
    # take copies of its vertices that hang on the jaw, so opening the jaw opens a slit there.
    row = int(np.argmin(np.abs(np.cos(np.linspace(0, math.pi, n_theta + 1)) * HEAD_AXES[1] - MOUTH_Y)))
    cols = n_phi + 1
    x_row = p[row * cols : (row + 1) * cols, 0]
    z_row = p[row * cols : (row + 1) * cols, 2]
    split = np.flatnonzero((np.abs(x_row) < MOUTH_HALF_WIDTH) & (z_row > 0)) + row * cols
    split = split[1:-1]  # the corners stay shared: the lips meet there
    copies = np.arange(len(p), len(p) + len(split))
    remap = np.arange(len(p))
    remap_below = remap.copy()
    remap_below[split] = copies
    below = tris.min(axis=1) >= row * cols  # triangles of the rows under the mouth line
    tris[below] = remap_below[tris[below]]
    p = np.concatenate([p, p[split]])
    n = np.concatenate([n, n[split]])
    uv = np.concatenate([uv, uv[split]])
    th = np.concatenate([th, th[split]])
    ph = np.concatenate([ph, ph[split]])
    lower = th > th[row * cols] + 1e-9
    lower[len(lower) - len(split) :] = True
    # A flattened mouth line: pull the lips in a touch so the slit reads as a mouth.
    lips = _bump(p, 0.0, MOUTH_Y, 0.01)
    p[:, 2] -= 0.002 * lips

    jaw = np.where(lower, 1.0, 0.0) * (1.0 - _smoothstep(0.55, 1.35, np.abs(ph)))
    jaw *= _smoothstep(-0.01, 0.03, p[:, 2])
    jaw[len(jaw) - len(split) :] = 1.0
    neck = _smoothstep(2.7, 3.1, th) * (1.0 - jaw)
    head = 1.0 - jaw - neck
    joints = np.tile(np.array([HEAD, JAW, NECK, ROOT], dtype=np.uint16), (len(p), 1))
    weights = np.stack([head, jaw, neck, np.zeros(len(p))], -1)

    shapes = _head_shapes(p, n, lower)
    targets = tuple(
        MorphTarget(name, shapes[name].astype(np.float32))
        for name in ARKIT_NAMES
        if name in shapes
    )
    prim = Primitive(
        positions=(p + HEAD_CENTRE).astype(np.float32),
        normals=n.astype(np.float32),
        indices=tris.reshape(-1).astype(np.uint32),
        material=0,
        uvs=uv.astype(np.float32),
        joints=joints,
        weights=weights.astype(np.float32),
        targets=targets,
        mesh=mesh,
    )
    return prim, p


def _neck(mesh: int) -> Primitive:
    around, rings = 28, 8
    a = np.linspace(-math.pi, math.pi, around + 1)
    y = np.linspace(1.34, HEAD_CENTRE[1] - 0.05, rings + 1)
    yy, aa = np.meshgrid(y, a, indexing="ij")
    radius = 0.05 + 0.01 * _smoothstep(1.42, 1.34, yy)
    x, z = radius * np.sin(aa), radius * np.cos(aa) - 0.008
    p = np.stack([x, yy, z], -1).reshape(-1, 3)
    n = np.stack([np.sin(aa), np.zeros_like(aa), np.cos(aa)], -1).reshape(-1, 3)
    t = _smoothstep(1.34, HEAD_CENTRE[1] - 0.05, p[:, 1])
    head = _smoothstep(0.6, 1.0, t)
    root = 1.0 - _smoothstep(0.0, 0.3, t)
    neck = 1.0 - head - root
    tris = _grid_indices(rings, around)[:, [0, 2, 1]]  # rows go up here: flip to keep the outside in front
    return Primitive(
        positions=p.astype(np.float32),
        normals=n.astype(np.float32),
        indices=tris.reshape(-1).astype(np.uint32),
        material=1,
        joints=np.tile(np.array([NECK, HEAD, ROOT, ROOT], dtype=np.uint16), (len(p), 1)),
        weights=np.stack([neck, head, root, np.zeros(len(p))], -1).astype(np.float32),
        mesh=mesh,
    )


def _sphere(radius: float, n_theta: int, n_phi: int, max_theta: float = math.pi) -> Primitive:
    """A sphere (or a cap of it) about the origin with its pole on +z (the front), UVs (azimuth, angle / pi)."""
    theta = np.linspace(0.0, max_theta, n_theta + 1)
    phi = np.linspace(-math.pi, math.pi, n_phi + 1)
    th, ph = np.meshgrid(theta, phi, indexing="ij")
    n = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], -1).reshape(-1, 3)
    uv = np.stack([(ph + math.pi) / (2 * math.pi), th / math.pi], -1).reshape(-1, 2)
    tris = _grid_indices(n_theta, n_phi)
    return Primitive(
        positions=(n * radius).astype(np.float32),
        normals=n.astype(np.float32),
        indices=tris.reshape(-1).astype(np.uint32),
        material=0,
        uvs=uv.astype(np.float32),
    )


def _lid_point(alpha: np.ndarray, elevation_deg: np.ndarray, radius: float) -> np.ndarray:
    e = np.radians(elevation_deg)
    return np.stack([radius * np.cos(e) * np.sin(alpha), radius * np.sin(e), radius * np.cos(e) * np.cos(alpha)], -1)


def _lid(side: str, sx: float, upper: bool, mesh: int, material: int) -> Primitive:
    """The upper or lower lid of the eye on side `side` ("Left": +x), in the head joint's frame: a shell about
    the eye from its pole to its edge, with targets that move the edge. Both lids close to meet below the eye's
    middle, each turning about a third of a right angle: a morph target moves a vertex in a straight line, and a
    lid turned further would cut through the eyeball on the way."""
    across, rows = 20, 10
    radius = EYE_RADIUS * 1.1
    alpha = np.linspace(-1.35, 1.35, across + 1)
    s = np.linspace(0.0, 1.0, rows + 1)
    ss, al = np.meshgrid(s, alpha, indexing="ij")
    pole = 90.0 if upper else -90.0
    edges = LID_EDGES_DEG["upper" if upper else "lower"]

    def at(edge_deg: float) -> np.ndarray:
        return _lid_point(al, pole - ss * (pole - edge_deg), radius).reshape(-1, 3)

    centre = HEAD_CENTRE + (sx * EYE_X, EYE_Y, _eye_depth()) - HEAD_JOINT
    rest = at(edges["rest"])
    normals = rest / np.linalg.norm(rest, axis=1, keepdims=True)
    uv = np.stack([al.reshape(-1) / 2.7 + 0.5, ss.reshape(-1)], -1)
    targets = tuple(MorphTarget(f"{shape}{side}", (at(edge) - rest).astype(np.float32))
                    for shape, edge in edges.items() if shape != "rest")
    tris = _grid_indices(rows, across)
    if not upper:
        tris = tris[:, [0, 2, 1]]  # its rows go up: turned, its outside faces out
    return Primitive(
        positions=(rest + centre).astype(np.float32),
        normals=normals.astype(np.float32),
        indices=tris.reshape(-1).astype(np.uint32),
        material=material,
        uvs=uv.astype(np.float32),
        node=HEAD,
        targets=targets,
        mesh=mesh,
    )


def sample_avatar(toon: bool = False) -> Avatar:
    """The procedural head; see the module docstring. `toon`: MToon-like two-tone materials."""
    skeleton = _skeleton()
    skin = _lin(SKIN)
    r, g, b = (float(v) for v in srgb_to_linear((0.78, 0.52, 0.48)))
    shade = (r, g, b)
    materials = (
        Material("head_skin", (1.0, 1.0, 1.0, 1.0), _head_texture(), roughness=0.62, toon=toon, shade_color=shade),
        Material("neck_skin", skin, roughness=0.62, toon=toon, shade_color=shade),
        Material("eye", (1.0, 1.0, 1.0, 1.0), _eye_texture(), roughness=0.3, toon=toon,
                 shade_color=(0.6, 0.6, 0.62)),
        Material("lid_skin", (1.0, 1.0, 1.0, 1.0), _lid_texture(), roughness=0.62, toon=toon, shade_color=shade,
                 double_sided=True),
        Material("mouth_inside", _lin((0.30, 0.08, 0.09)), roughness=0.8, toon=toon, shade_color=(0.05, 0.0, 0.0),
                 double_sided=True),
        Material("cornea", (1.0, 1.0, 1.0, 0.08), alpha_mode=AlphaMode.BLEND, roughness=0.08, toon=toon,
                 shade_color=(1.0, 1.0, 1.0)),
        Material("lower_lid_skin", skin, roughness=0.62, toon=toon, shade_color=shade, double_sided=True),
    )
    head, _ = _head(mesh=0)
    prims: list[Primitive] = [head, _neck(mesh=1)]
    for joint in (LEFT_EYE, RIGHT_EYE):
        eye = _sphere(EYE_RADIUS, 18, 24)
        prims.append(Primitive(eye.positions, eye.normals, eye.indices, 2, _eye_uvs(eye.normals), node=joint,
                               mesh=2))
        cornea = _sphere(EYE_RADIUS * 1.03, 8, 24, max_theta=0.75)
        prims.append(Primitive(cornea.positions, cornea.normals, cornea.indices, 5, cornea.uvs, node=joint, mesh=3))
    for k, (side, sx) in enumerate((("Left", 1.0), ("Right", -1.0))):
        prims.append(_lid(side, sx, True, mesh=4 + 2 * k, material=3))
        prims.append(_lid(side, sx, False, mesh=5 + 2 * k, material=6))
    cavity = _sphere(1.0, 10, 16)
    scale = np.array([0.03, 0.022, 0.022])
    centre = HEAD_CENTRE + (0.0, MOUTH_Y - 0.006, 0.045) - HEAD_JOINT
    prims.append(Primitive((cavity.positions * scale + centre).astype(np.float32), cavity.normals, cavity.indices,
                           4, node=HEAD, mesh=8))
    shapes: dict[str, list[tuple[int, int]]] = {}
    for i, prim in enumerate(prims):
        for k, target in enumerate(prim.targets):
            shapes.setdefault(target.name, []).append((i, k))
    return Avatar(
        name="sample head" + (" (toon)" if toon else ""),
        primitives=tuple(prims),
        materials=materials,
        skeleton=skeleton,
        expressions={},
        look_at=None,
        capabilities=Capabilities(eyes="bones", blink="arkit shapes", mouth="jaw bone"),
        shapes={k: tuple(v) for k, v in shapes.items()},
        source="<sample>",
    )
