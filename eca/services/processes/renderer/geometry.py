"""Procedural geometry of the cartoon face: the static parts (head, hair, nose, eyeballs, lids, blush) as one
vertex set riding on rigid bones, and the constants every other part of the face is placed by.

Frame: the head's own frame. x points to the viewer's right in a front view, which is the AGENT's
LEFT (the face looks at the camera); y is up; z comes out of the face toward the camera. The head is
about 2.3 units tall, centred near the origin.

Sign conventions follow agent/face/flexors.py: look_x and turn at +1 turn toward the agent's right,
i.e. toward -x here, the viewer's left. The agent's left-side flexors (blink_l, lids_l, brow_l,
smile_l, sneer_l) act on the +x side of the face.

The face is split in two vertex sets:
- static (here): head, hair, nose, eyeballs and lids. They never change shape; flexors move them with
  rigid "bones" (jaw, eyes, lids) blended per vertex in the vertex shader, so a frame uploads only a
  few matrices; their outlines: outline.py;
- dynamic (curves.py): brows and mouth (lips, cavity, teeth, tongue), whose shapes depend on several flexors
  at once in non-linear ways. poser.py turns a flexor vector into the bones and those curves.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

# Vertex layout shared with the shaders: position(3) normal(3) aux(3) info(4) as float32, where
# info = (material, bone0, bone1, weight of bone1) and aux is a rest-frame direction or position a
# material uses for its pattern (the iris of an eye, the blush of a cheek).
VERTEX_FLOATS = 13

BONE_HEAD, BONE_JAW, BONE_EYE_L, BONE_EYE_R = 0, 1, 2, 3
BONE_ULID_L, BONE_ULID_R, BONE_LLID_L, BONE_LLID_R = 4, 5, 6, 7
N_BONES = 8

MATERIALS: tuple[str, ...] = (
    "skin",
    "hair",
    "brow",
    "lip",
    "mouth",
    "teeth",
    "tongue",
    "eye",
    "lid",
    "blush",
)
MAT = {name: i for i, name in enumerate(MATERIALS)}

# Head shape: a superellipsoid |x/(a t(y))|^n + |y/b|^n + |z/c|^n = 1 whose width tapers toward the chin.
HEAD_A, HEAD_B, HEAD_C, HEAD_N = 0.92, 1.1, 0.95, 2.4
HEAD_TAPER = 0.24
NECK_PIVOT = np.array([0.0, -0.75, -0.1])  # head turn, nod and tilt rotate about this point
JAW_PIVOT = np.array([0.0, 0.05, -0.3])

EYE_X, EYE_Y, EYE_RADIUS, EYE_BULGE = 0.33, 0.10, 0.19, 0.14
IRIS_ANGLE, PUPIL_ANGLE = 0.52, 0.24  # angular radii (rad) of iris and pupil on the eyeball

MOUTH_Y, MOUTH_HALF_WIDTH = -0.5, 0.22
BROW_INNER, BROW_OUTER, BROW_Y = 0.11, 0.53, 0.43

# Lid rim elevations in degrees (0 = level with the eye centre, + up).
UPPER_RIM_REST, LOWER_RIM_REST = 24.0, -44.0
UPPER_RIM_WIDE, UPPER_RIM_NARROW = 56.0, -2.0  # lids = +1 / -1
LIDS_CLOSED = -14.0  # where the lids meet in a blink
UPPER_FOLLOWS_PITCH, LOWER_FOLLOWS_PITCH = 0.65, 0.3  # the lids track the eye's pitch this much
JAW_MAX_DEG = 17.0

# Vertex rows with this added to their material are the outline's extruded copies (see Silhouette).
EXTRUDED = 16.0


def cross3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross products of broadcast rows of 3-vectors (faster than np.cross on small arrays)."""
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[..., 0] = a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1]
    out[..., 1] = a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2]
    out[..., 2] = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
    return out


def unit(v: np.ndarray) -> np.ndarray:
    """Rows scaled to length 1 (a zero row stays near zero)."""
    return v / np.maximum(np.sqrt((v * v).sum(-1, keepdims=True)), 1e-12)


def smooth01(t: np.ndarray) -> np.ndarray:
    """The smoothstep of t clipped to [0, 1]."""
    t = np.clip(t, 0.0, 1.0)
    return t * t * (3 - 2 * t)




def _superellipsoid_f(p: np.ndarray) -> np.ndarray:
    x, y, z = p[..., 0], p[..., 1], p[..., 2]
    taper = 1.0 - HEAD_TAPER * np.clip(-y / HEAD_B, 0.0, 1.0) ** 2
    return np.abs(x / (HEAD_A * taper)) ** HEAD_N + np.abs(y / HEAD_B) ** HEAD_N + np.abs(z / HEAD_C) ** HEAD_N


def head_surface_z(x: np.ndarray | float, y: np.ndarray | float) -> np.ndarray:
    """The z of the front of the head at (x, y); 0 where (x, y) lies outside the head's outline."""
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    taper = 1.0 - HEAD_TAPER * np.clip(-y / HEAD_B, 0.0, 1.0) ** 2
    rest = 1.0 - np.abs(x / (HEAD_A * taper)) ** HEAD_N - np.abs(y / HEAD_B) ** HEAD_N
    return HEAD_C * np.clip(rest, 0.0, None) ** (1.0 / HEAD_N)


def head_normal(p: np.ndarray) -> np.ndarray:
    """Outward unit normals of the head surface at points p (..., 3): the implicit function's gradient."""
    x, y, z = p[..., 0], p[..., 1], p[..., 2]
    n = HEAD_N
    u = np.clip(-y / HEAD_B, 0.0, 1.0)
    taper = 1.0 - HEAD_TAPER * u * u
    ax = np.abs(x / (HEAD_A * taper))
    gx = ax ** (n - 1) * np.sign(x) / (HEAD_A * taper)
    # d/dy of |x/(a t)|^n through the taper t(y): dt/dy = 2 k u / b where the taper acts.
    dt_dy = np.where((u > 0) & (u < 1), 2.0 * HEAD_TAPER * u / HEAD_B, 0.0)
    gy = np.abs(y / HEAD_B) ** (n - 1) * np.sign(y) / HEAD_B - ax**n / taper * dt_dy
    gz = np.abs(z / HEAD_C) ** (n - 1) * np.sign(z) / HEAD_C
    return _normalize(np.stack([gx, gy, gz], -1))


def _normalize(v: np.ndarray) -> np.ndarray:
    length = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.maximum(length, 1e-12)


def _head_radius(directions: np.ndarray) -> np.ndarray:
    """Distance from the origin to the head surface along unit directions (bisection on the implicit form)."""
    lo = np.zeros(directions.shape[:-1])
    hi = np.full(directions.shape[:-1], 2.0)
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        inside = _superellipsoid_f(directions * mid[..., None]) < 1.0
        lo = np.where(inside, mid, lo)
        hi = np.where(inside, hi, mid)
    return 0.5 * (lo + hi)


@dataclass
class Part:
    """One piece of geometry: vertices (V, 13) and triangles (T, 3) indexing them."""

    vertices: np.ndarray
    triangles: np.ndarray


def _pack(
    pos: np.ndarray,
    normal: np.ndarray,
    material: str,
    bone0: int = BONE_HEAD,
    bone1: int = BONE_HEAD,
    weight: np.ndarray | float = 0.0,
    aux: np.ndarray | None = None,
) -> np.ndarray:
    n = pos.shape[0]
    out = np.empty((n, VERTEX_FLOATS), dtype=np.float32)
    out[:, 0:3] = pos
    out[:, 3:6] = normal
    out[:, 6:9] = (-1.0, 0.0, 0.0) if aux is None else aux  # aux.x < 0: no hair pattern
    out[:, 9] = MAT[material]
    out[:, 10] = bone0
    out[:, 11] = bone1
    out[:, 12] = weight
    return out


def grid_triangles(nu: int, nv: int, wrap_u: bool, wrap_v: bool) -> np.ndarray:
    """Two triangles per quad of an nu x nv vertex grid (row-major), optionally closed in u and/or v."""
    iu = np.arange(nu if wrap_u else nu - 1)
    iv = np.arange(nv if wrap_v else nv - 1)
    i, j = np.meshgrid(iu, iv, indexing="ij")
    a = i * nv + j
    b = ((i + 1) % nu) * nv + j
    c = ((i + 1) % nu) * nv + (j + 1) % nv
    d = i * nv + (j + 1) % nv
    tris = np.concatenate([np.stack([a, b, c], -1), np.stack([a, c, d], -1)], axis=0)
    return tris.reshape(-1, 3).astype(np.int64)


def orient_triangles(positions: np.ndarray, normals: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """Reorder each triangle so it winds counter-clockwise seen from its vertices' normal side.

    Back-face culling and the inverted-hull outlines rely on this; doing it here lets every builder
    ignore winding.
    """
    p0, p1, p2 = positions[tris[:, 0]], positions[tris[:, 1]], positions[tris[:, 2]]
    face = np.cross(p1 - p0, p2 - p0)
    avg = normals[tris[:, 0]] + normals[tris[:, 1]] + normals[tris[:, 2]]
    flip = np.einsum("ij,ij->i", face, avg) < 0
    out = tris.copy()
    out[flip, 1], out[flip, 2] = tris[flip, 2], tris[flip, 1]
    return out


def _sphere_grid(n_lon: int, n_lat: int) -> np.ndarray:
    """Unit directions on a lat/lon grid with its poles on the +-y axis: shape (n_lon, n_lat, 3)."""
    lon = np.linspace(0.0, 2 * np.pi, n_lon, endpoint=False)
    lat = np.linspace(-np.pi / 2, np.pi / 2, n_lat)
    lo, la = np.meshgrid(lon, lat, indexing="ij")
    return np.stack([np.cos(la) * np.sin(lo), np.sin(la), np.cos(la) * np.cos(lo)], axis=-1)


def _ellipsoid(centre: np.ndarray, semi: np.ndarray, material: str, n_lon: int, n_lat: int) -> Part:
    d = _sphere_grid(n_lon, n_lat).reshape(-1, 3)
    pos = centre + d * semi
    normal = _normalize(d / semi)
    tris = grid_triangles(n_lon, n_lat, wrap_u=True, wrap_v=False)
    return Part(_pack(pos, normal, material), orient_triangles(pos, normal, tris))


def hairline(x: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Height of the hairline above rest point (x, z) of the head; the face shader uses the same formula."""
    front = np.clip((z / HEAD_C - 0.1) / 0.7, 0.0, 1.0)
    fringe = 0.8 - 0.08 * x + 0.035 * np.cos(15.0 * x) - 0.3 * np.abs(x)
    return -0.55 + (fringe + 0.55) * front


def _hairline_latitude(lon: np.ndarray) -> np.ndarray:
    """Per longitude, the latitude (rad) at which the head surface crosses the hairline (bisection)."""
    lo = np.full(lon.shape, -np.pi / 2 + 1e-3)
    hi = np.full(lon.shape, np.pi / 2 - 1e-3)
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        d = np.stack([np.cos(mid) * np.sin(lon), np.sin(mid), np.cos(mid) * np.cos(lon)], -1)
        p = d * _head_radius(d)[:, None]
        above = p[:, 1] > hairline(p[:, 0], p[:, 2])
        hi = np.where(above, mid, hi)
        lo = np.where(above, lo, mid)
    return 0.5 * (lo + hi)


def build_head(n_lon: int = 24, n_lat: int = 15) -> Part:
    """The head shell with its hair, bulging a little where the hair is; its chin rides on the jaw bone.

    One row of the lat/lon grid runs exactly along the hairline, so hair and skin are separate
    triangles with flat colours: a crisp hairline that costs nothing per pixel.
    """
    lon = np.linspace(0.0, 2 * np.pi, n_lon, endpoint=False)
    row_h = max(2, round(0.62 * (n_lat - 1)))  # rows below the hairline get the face's detail
    lat_h = _hairline_latitude(lon)
    below = np.linspace(0.0, 1.0, row_h + 1)[:, None]
    above = np.linspace(0.0, 1.0, n_lat - row_h)[1:, None]
    lat = np.concatenate([-np.pi / 2 + below * (lat_h + np.pi / 2), lat_h + above * (np.pi / 2 - lat_h)])
    lo = np.broadcast_to(lon, lat.shape)
    d = np.stack([np.cos(lat) * np.sin(lo), np.sin(lat), np.cos(lat) * np.cos(lo)], -1).transpose(1, 0, 2)
    d = d.reshape(-1, 3)  # (n_lon * n_lat, 3), row-major by longitude like _sphere_grid
    pos = d * _head_radius(d)[:, None]
    normal = head_normal(pos)
    row = np.tile(np.arange(n_lat), n_lon)
    hair = row > row_h
    pos = pos * (1.0 + 0.035 * hair)[:, None]  # the hair stands a little proud of the skin
    # The chin follows the jaw; the blend starts just below the mouth corners so the cheeks stay put.
    jaw_w = smooth01((MOUTH_Y + 0.1 - pos[:, 1]) / 0.3) * np.clip((pos[:, 2] + 0.2) / 0.4, 0.0, 1.0)
    tris = orient_triangles(pos, normal, grid_triangles(n_lon, n_lat, wrap_u=True, wrap_v=False))
    # Flat colours come from each triangle's last (provoking) vertex: make it one off the hairline row,
    # rotating the triangle's indices (which keeps its winding).
    on_row = row[tris] == row_h
    for _ in range(2):
        shift = on_row[:, 2]
        tris[shift] = np.roll(tris[shift], 1, axis=1)
        on_row[shift] = np.roll(on_row[shift], 1, axis=1)
    verts = _pack(pos, normal, "skin", BONE_HEAD, BONE_JAW, jaw_w)
    verts[hair, 9] = MAT["hair"]
    return Part(verts, tris)


def build_blush(side: int, n: int = 14) -> Part:
    """A flat oval of blush lying on one cheek (a cartoon decal, drawn without outline)."""
    ang = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    x = np.concatenate([[0.0], 0.12 * np.cos(ang)]) + side * 0.5
    y = np.concatenate([[0.0], 0.075 * np.sin(ang)]) - 0.27
    p = np.stack([x, y, head_surface_z(x, y)], -1)
    nrm = head_normal(p)
    p = p + nrm * 0.006
    tris = np.stack([np.zeros(n, dtype=np.int64), 1 + np.arange(n), 1 + (np.arange(n) + 1) % n], -1)
    return Part(_pack(p, nrm, "blush"), orient_triangles(p, nrm, tris))


def eye_centre(side: int) -> np.ndarray:
    """Rest centre of the agent's left (side=+1, at +x) or right (side=-1, at -x) eye."""
    x = side * EYE_X
    return np.array([x, EYE_Y, float(head_surface_z(x, EYE_Y)) + EYE_BULGE - EYE_RADIUS])


def build_eye(side: int, n_lon: int = 18, n_lat: int = 8) -> Part:
    """The front cap of an eyeball, pole forward (+z); aux carries the rest direction for iris and pupil.

    The back of the ball is always inside the head, so the cap stops at 115 degrees from the pole.
    """
    lon = np.linspace(0.0, 2 * np.pi, n_lon, endpoint=False)
    polar = np.linspace(0.0, np.radians(115.0), n_lat)
    lo, po = np.meshgrid(lon, polar, indexing="ij")
    d = np.stack([np.sin(po) * np.cos(lo), np.sin(po) * np.sin(lo), np.cos(po)], -1).reshape(-1, 3)
    pos = eye_centre(side) + d * EYE_RADIUS
    tris = grid_triangles(n_lon, n_lat, wrap_u=True, wrap_v=False)
    bone = BONE_EYE_L if side > 0 else BONE_EYE_R
    return Part(_pack(pos, d, "eye", bone, bone, 0.0, aux=d), orient_triangles(pos, d, tris))


def build_lid(side: int, upper: bool, n_az: int = 11) -> Part:
    """A thick lune-shaped lid around the eye, pinned at the eye corners, with its rim level at rest.

    Its rim is a great circle through the eye's horizontal axis, so turning the lid's bone about that
    axis opens and closes it like a real eyelid. Upper lids sit just outside lower ones, so a closed
    eye shows the upper lid over the lower.
    """
    r_in, r_out = (1.09, 1.2) if upper else (1.02, 1.08)
    r_in, r_out = r_in * EYE_RADIUS, r_out * EYE_RADIUS
    r_mid, half = 0.5 * (r_in + r_out), 0.5 * (r_out - r_in)
    back = 115.0  # degrees; further back the lid is inside the head anyway
    # Cross-section loop in (theta, r, normal-in-(theta, r)-plane) around the lid's thickness. Only the
    # rim and the outer sheet are ever seen, so the inner sheet gets just its two ends.
    loop_t: list[float] = []
    loop_r: list[float] = []
    loop_kind: list[tuple[float, float]] = []  # (radial, tangential) normal components
    for th in np.radians([0.0, 28.0, 62.0, back]):
        loop_t.append(th)
        loop_r.append(r_out)
        loop_kind.append((1.0, 0.0))
    for th in np.radians([back, 30.0]):
        loop_t.append(th)
        loop_r.append(r_in)
        loop_kind.append((-1.0, 0.0))
    for beta in (0.0, np.pi / 3, 2 * np.pi / 3):
        # rounded rim from the inner sheet (b = pi) back to the outer sheet (b = 0)
        b = np.pi - beta
        loop_t.append(-half * math.sin(b) / r_mid * 1.4)
        loop_r.append(r_mid + half * math.cos(b))
        loop_kind.append((math.cos(b), -math.sin(b)))
    # The back edge (hidden in the head) faces backward, so its quad has a well-defined side.
    loop_kind[3] = loop_kind[4] = (0.0, 1.0)
    th = np.array(loop_t)
    rr = np.array(loop_r)
    kind = np.array(loop_kind)
    az = np.linspace(-np.pi / 2, np.pi / 2, n_az)
    a, k = np.meshgrid(az, np.arange(th.size), indexing="ij")
    s, c = np.sin(a), np.cos(a)
    t = th[k]
    base = np.stack([s, c * np.sin(t), c * np.cos(t)], -1)  # unit direction on the eye sphere
    tangent = np.stack([np.zeros_like(s), np.cos(t), -np.sin(t)], -1)  # toward increasing theta
    pos = base * rr[k][..., None]
    normal = _normalize(kind[k][..., 0:1] * base + kind[k][..., 1:2] * tangent)
    # At the eye corners every ring collapses onto the horizontal axis; there the normal points outward.
    if not upper:
        pos[..., 1] *= -1
        normal[..., 1] *= -1
    centre = eye_centre(side)
    pos = pos.reshape(-1, 3) + centre
    normal = normal.reshape(-1, 3)
    tris = grid_triangles(n_az, th.size, wrap_u=False, wrap_v=True)
    if upper:
        bone = BONE_ULID_L if side > 0 else BONE_ULID_R
    else:
        bone = BONE_LLID_L if side > 0 else BONE_LLID_R
    verts = _pack(pos, normal, "lid", bone, bone, 0.0)
    return Part(verts, orient_triangles(pos, normal, tris))


def _merge(parts: list[Part]) -> tuple[np.ndarray, np.ndarray]:
    verts, tris, offset = [], [], 0
    for part in parts:
        verts.append(part.vertices)
        tris.append(part.triangles + offset)
        offset += part.vertices.shape[0]
    return np.concatenate(verts), np.concatenate(tris)


@dataclass
class StaticMesh:
    """Vertices never change; `ranges` names index ranges (first index, count) for drawing subsets."""

    vertices: np.ndarray  # (V, 13) float32
    indices: np.ndarray  # (I,) uint32, triangles in draw order
    ranges: dict[str, tuple[int, int]]


def build_static_mesh(detail: float = 1.0) -> StaticMesh:
    """The static vertices and triangles; `detail` scales the tessellation (1 = the real-time mesh).

    Software GL pays per triangle and per pixel of triangle edge, so the live mesh is low-poly; stills
    (eca snapshot) can afford a smoother one.
    """
    if not 0.5 <= detail <= 4.0:
        raise ValueError(f"mesh detail must lie in [0.5, 4], got {detail}")

    def n(base: int) -> int:
        return max(4, round(base * detail))

    head = build_head(n(24), n(15))
    nose_y = -0.17
    nose = _ellipsoid(
        np.array([0.0, nose_y, float(head_surface_z(0.0, nose_y)) + 0.0]),
        np.array([0.095, 0.08, 0.1]),
        "skin",
        n(10),
        n(6),
    )
    eyes = [build_eye(1, n(14), n(6)), build_eye(-1, n(14), n(6))]
    lids = [build_lid(s, up, n(9)) for s in (1, -1) for up in (True, False)]
    blush = [build_blush(1), build_blush(-1)]
    # Head triangles ordered by how much they face forward (rest normal z, descending): a near-frontal
    # head then fills the depth buffer roughly front to back.
    tri_nz = head.vertices[head.triangles, 5].mean(1)
    order = np.argsort(-tri_nz, kind="stable")
    head = Part(head.vertices, head.triangles[order])
    # The nose has a group of its own because it gets no outline: it rises out of the cheek, and the
    # line would show where it meets the skin; its shading alone shapes it.
    groups = {"decals": blush, "nose": [nose], "face": [head], "eyes": eyes, "lids": lids}
    verts_all, idx_all, ranges = [], [], {}
    offset_v, offset_i = 0, 0
    for name, parts in groups.items():
        v, t = _merge(parts)
        # The grids' collapsed rows (the poles of the head, eyes and nose; the lids' corners) make
        # triangles of no area: they draw nothing, yet software GL shades and sets up each of them.
        corner = np.round(v[t, 0:3].astype(np.float64) * 1e6)
        flat_area = np.all(corner[:, 0] == corner[:, 1], 1) | np.all(corner[:, 1] == corner[:, 2], 1)
        t = t[~(flat_area | np.all(corner[:, 2] == corner[:, 0], 1))]
        verts_all.append(v)
        flat = (t + offset_v).reshape(-1)
        idx_all.append(flat)
        ranges[name] = (offset_i, flat.size)
        offset_v += v.shape[0]
        offset_i += flat.size
    return StaticMesh(np.concatenate(verts_all), np.concatenate(idx_all).astype(np.uint32), ranges)
