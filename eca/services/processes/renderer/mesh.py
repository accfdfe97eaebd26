"""Procedural geometry of the cartoon face, and how each flexor moves it (numpy; the per-frame posing
compiled with numba).

Frame: the head's own frame. x points to the viewer's right in a front view, which is the AGENT's
LEFT (the face looks at the camera); y is up; z comes out of the face toward the camera. The head is
about 2.3 units tall, centred near the origin.

Sign conventions follow agent/face/flexors.py: look_x and turn at +1 turn toward the agent's right,
i.e. toward -x here, the viewer's left. The agent's left-side flexors (blink_l, lids_l, brow_l,
smile_l, sneer_l) act on the +x side of the face.

The face is split in two vertex sets:
- static: head, hair, nose, eyeballs and lids. They never change shape; flexors move them with
  rigid "bones" (jaw, eyes, lids) blended per vertex in the vertex shader, so a frame uploads only a
  few matrices;
- dynamic: brows and mouth (lips, cavity, teeth, tongue), whose shapes depend on several flexors at
  once in non-linear ways. They are small (about 350 vertices). Each frame build_dynamic works out
  the points they are built from (curve_block), which the renderer uploads and its vertex shader
  turns into the brow and lip tubes and the mouth's inner strips on the head's surface; without a
  curve block, build_dynamic builds the same vertices in numpy (the reference the tests use). The
  lower lip, the tongue and the lower edge of the mouth cavity also ride on the jaw bone, so the jaw
  and the lips can never disagree.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from eca.agent.face.flexors import FLEXOR_INDEX, N_FLEXORS
from eca.agent.face.settings import FlexorUnits, load_flexor_units

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
    jaw_w = _smooth01((MOUTH_Y + 0.1 - pos[:, 1]) / 0.3) * np.clip((pos[:, 2] + 0.2) / 0.4, 0.0, 1.0)
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


# ---------------------------------------------------------------------------------------------------
# Outlines of the static parts. Software GL pays for every triangle it rasterises and for every pixel
# a triangle touches, visible or not. An inverted hull (every back face, pushed outward) makes the
# rasteriser walk the hidden back of the head to draw a thin line around it; quads along the
# silhouette edges, found on the CPU each frame, draw the same line from a few hundred thin triangles.

# Vertex rows with this added to their material are the outline's extruded copies (see Silhouette).
EXTRUDED = 16.0


def extruded_copy(vertices: np.ndarray) -> np.ndarray:
    """The vertex rows followed by their copies marked EXTRUDED (an outline quad's outer corners)."""
    out = np.concatenate([vertices, vertices])
    out[vertices.shape[0] :, 9] += EXTRUDED
    return out


class RigidFacing:
    """Which triangles of the static mesh face the camera, from the bones and the eye's position.

    A triangle whose vertices all ride one bone B, with rest normal n through rest point p, faces an
    eye e (in the posed head frame) when n . (B^-1 e - p) > 0: one dot product per triangle, with n and
    n . p computed once. The few triangles whose vertices blend two bones (the chin on the jaw) can
    bend any way, so their vertices are skinned and their normals found each frame.
    """

    def __init__(self, vertices: np.ndarray, triangles: np.ndarray) -> None:
        pos = vertices[:, 0:3].astype(np.float64)
        tri = np.asarray(triangles, dtype=np.intp)
        p0 = pos[tri[:, 0]]
        normal = _cross(pos[tri[:, 1]] - p0, pos[tri[:, 2]] - p0)
        # Unit normals, so the test's value is the eye's signed distance from the triangle's plane
        # (zero-area triangles keep a zero normal: never facing).
        self._inverse_length = 1.0 / np.maximum(np.linalg.norm(normal, axis=1), 1e-300)
        self.normal = normal * self._inverse_length[:, None]
        self.offset = np.einsum("ij,ij->i", self.normal, p0)
        info = vertices[:, 10:13]
        self.bone = info[tri[:, 0], 0].astype(np.intp)
        blended = (info[:, 2] > 0) & (info[:, 0] != info[:, 1])
        self.mixed = np.nonzero(blended[tri].any(1) | (info[tri, 0] != self.bone[:, None]).any(1))[0]
        used, local = np.unique(tri[self.mixed], return_inverse=True)
        # Skinned per pair of bones (in practice one pair: head and jaw), a few array operations each; the
        # vertices are sorted by pair so that each pair's columns are a slice, not a gather.
        pairs = info[used, 0:2].astype(np.intp)
        by_pair = np.lexsort((pairs[:, 1], pairs[:, 0]))
        used, pairs = used[by_pair], pairs[by_pair]
        local = np.argsort(by_pair)[local]
        # Components in rows (3, n), so the per-frame arithmetic runs on contiguous arrays; the corners
        # of every mixed triangle, corner after corner, gathered in one take.
        self._mixed_corners = local.reshape(-1, 3).T.reshape(-1).copy()  # (3 corners * n,)
        self._mixed_rest = pos[used].T.copy()
        bounds = np.flatnonzero(np.any(np.diff(pairs, axis=0) != 0, axis=1)) + 1
        starts, stops = np.concatenate([[0], bounds]).tolist(), np.append(bounds, len(used)).tolist()
        self._pairs = [
            (int(pairs[a, 0]), int(pairs[a, 1]), slice(a, b)) for a, b in zip(starts, stops, strict=True) if b > a
        ]
        self._mixed_w = info[used, 2].astype(np.float64)
        self._mixed_scale = self._inverse_length[self.mixed]
        self._compiled_inputs = (
            np.ascontiguousarray(self.normal),
            np.ascontiguousarray(self.offset),
            self.bone.astype(np.int64),
            self.mixed.astype(np.int64),
            local.reshape(-1, 3).astype(np.int64),
            np.ascontiguousarray(pos[used]),
            pairs.astype(np.int64),
            self._mixed_w,
            np.ascontiguousarray(self._mixed_scale),
        )
        # The parts ride one bone each and lie one after another, so the rigid test is one small matrix
        # product per run of triangles on the same bone, into views made once.
        self._s = np.empty(tri.shape[0])
        starts = np.concatenate([[0], np.flatnonzero(np.diff(self.bone)) + 1])
        stops = np.append(starts[1:], tri.shape[0])
        self._runs = [
            (int(self.bone[a]), self.normal[a:b], self._s[a:b])
            for a, b in zip(starts.tolist(), stops.tolist(), strict=True)
        ]

    def compiled_inputs(self) -> tuple[np.ndarray, ...]:
        """What kernels.static_frame_indices needs of this mesh, after bones and eye: every triangle's unit
        rest normal, its offset and bone; the blended triangles, their corners (rows of the next three
        arrays), the corners' rest positions, bone pairs and weights, and the triangles' area scales."""
        return self._compiled_inputs

    def front(self, bones: np.ndarray, eye: np.ndarray) -> np.ndarray:
        """Which triangles face `eye` (the camera's position in the posed head frame)."""
        return self.distances(bones, eye) > 0.0

    def distances(self, bones: np.ndarray, eye: np.ndarray) -> np.ndarray:
        """The signed distance of `eye` (the camera's position in the posed head frame) from each posed
        triangle's plane: positive where the triangle faces it. The few triangles that blend two bones
        use their rest area to scale, which keeps the sign exact and the size close."""
        rot = bones[:, :3, :3]
        eye_in_bone = np.einsum("kji,kj->ki", rot, eye - bones[:, :3, 3])  # B^-1 e for each bone
        for bone, normal, out in self._runs:
            np.matmul(normal, eye_in_bone[bone], out=out)
        s = self._s - self.offset
        posed = np.empty_like(self._mixed_rest)
        for b0, b1, cols in self._pairs:
            p = self._mixed_rest[:, cols]
            a = rot[b0] @ p + bones[b0, :3, 3:4]
            b = rot[b1] @ p + bones[b1, :3, 3:4]
            b -= a
            b *= self._mixed_w[cols]
            np.add(a, b, out=posed[:, cols])
        n = self.mixed.size
        corners = posed[:, self._mixed_corners].reshape(3, 3, n)  # (xyz, corner, triangle)
        q0 = corners[:, 0]
        corners[:, 1:] -= q0[:, None]
        (ux, uy, uz), (vx, vy, vz) = corners[:, 1], corners[:, 2]
        dx, dy, dz = eye[:, None] - q0
        s[self.mixed] = (
            (uy * vz - uz * vy) * dx + (uz * vx - ux * vz) * dy + (ux * vy - uy * vx) * dz
        ) * self._mixed_scale
        return s


class Silhouette:
    """The edges of a triangle set where a triangle facing the camera meets one facing away, or where
    the mesh ends beside a facing one; each drawn as a quad pushed outward in the outline pass.

    Adjacency is found once on vertices welded by position, so the collapsed poles and tube ends of
    the parametric parts join up and their zero-area triangles drop out. A quad's inner corners are the
    edge's own vertex rows, its outer corners their EXTRUDED copies (n_vertices further on), which the
    vertex shader pushes out along the screen-space normal: the same band the inverted hull drew.
    """

    def __init__(self, positions: np.ndarray, triangles: np.ndarray, n_vertices: int) -> None:
        tri = np.asarray(triangles, dtype=np.intp)
        _, weld = np.unique(np.round(np.asarray(positions, dtype=np.float64) * 1e6), axis=0, return_inverse=True)
        weld = weld.reshape(-1)
        w = weld[tri]
        ok = (w[:, 0] != w[:, 1]) & (w[:, 1] != w[:, 2]) & (w[:, 2] != w[:, 0])
        ids = np.nonzero(ok)[0]
        half_a = np.concatenate([w[ids, k] for k in range(3)])
        half_b = np.concatenate([w[ids, (k + 1) % 3] for k in range(3)])
        orig_a = np.concatenate([tri[ids, k] for k in range(3)])
        orig_b = np.concatenate([tri[ids, (k + 1) % 3] for k in range(3)])
        owner = np.concatenate([ids, ids, ids])
        key = np.minimum(half_a, half_b) * (int(weld.max()) + 1) + np.maximum(half_a, half_b)
        order = np.argsort(key, kind="stable")
        key, owner, orig_a, orig_b = key[order], owner[order], orig_a[order], orig_b[order]
        first = np.concatenate([[True], key[1:] != key[:-1]])
        starts = np.nonzero(first)[0]
        counts = np.diff(np.append(starts, key.size))
        self.n_triangles = tri.shape[0]
        self.t0 = owner[starts]
        # The second triangle on the edge, or n_triangles (never facing) where the mesh ends there.
        self.t1 = np.where(counts >= 2, owner[np.minimum(starts + 1, key.size - 1)], self.n_triangles)
        a, b = orig_a[starts].astype(np.uint32), orig_b[starts].astype(np.uint32)
        n = np.uint32(n_vertices)
        self.quads = np.stack([a, b, b + n, a, b + n, a + n], 1)
        self._front = np.zeros(self.n_triangles + 1, dtype=bool)

    def quads_for(self, front: np.ndarray) -> np.ndarray:
        """Index rows (K, 6) of the silhouette quads, given which triangles face the camera."""
        f = self._front
        f[:-1] = front
        return self.quads[f[self.t0] != f[self.t1]]


# ---------------------------------------------------------------------------------------------------
# Dynamic parts: brows and mouth, rebuilt each frame from the flexors: the points they are built from
# (compiled, below), then in numpy the vertices themselves (the reference for the vertex shader's build).

SEGMENTS, RING = 13, 5  # points along each brow or lip, and around its section
TUBES: tuple[str, ...] = ("brow_l", "brow_r", "lip_u", "lip_l")
STRIPS: tuple[str, ...] = ("cavity", "teeth", "tongue")
_STRIP_MATERIAL = {"cavity": "mouth", "teeth": "teeth", "tongue": "tongue"}
_TUBE_MATERIAL = {"brow_l": "brow", "brow_r": "brow", "lip_u": "lip", "lip_l": "lip"}


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[..., 0] = a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1]
    out[..., 1] = a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2]
    out[..., 2] = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
    return out


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.sqrt((v * v).sum(-1, keepdims=True)), 1e-12)


_RING_COS = np.cos(np.linspace(0.0, 2 * np.pi, RING, endpoint=False))[:, None]
_RING_SIN = np.sin(np.linspace(0.0, 2 * np.pi, RING, endpoint=False))[:, None]


def _tubes(
    centre: np.ndarray, out: np.ndarray, half_h: np.ndarray, half_d: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Tubes of elliptic section along curves (T, S, 3) lying on a surface with unit normals `out`.

    half_h is the in-surface half-height, half_d the outward half-depth, both (T, S); they taper to 0
    at the ends to close each tube. The section lies in the plane of the surface normal and the
    in-surface perpendicular of the curve (the curves lie on the surface, so that plane is close to
    perpendicular to them). Returns positions and normals shaped (T, S, RING, 3).
    """
    tangent = np.empty_like(centre)
    tangent[:, 1:-1] = centre[:, 2:] - centre[:, :-2]
    tangent[:, 0] = centre[:, 1] - centre[:, 0]
    tangent[:, -1] = centre[:, -1] - centre[:, -2]
    side = _unit(_cross(out, tangent))[:, :, None, :]
    up = out[:, :, None, :]
    pos = (
        centre[:, :, None, :]
        + (_RING_COS * half_h[..., None, None]) * side
        + (_RING_SIN * half_d[..., None, None]) * up
    )
    # The normal of an ellipse with the tube's mean aspect ratio survives the taper to zero at the ends.
    aspect = (half_d.sum(1) / np.maximum(half_h.sum(1), 1e-9))[:, None, None, None]
    normal = _unit((_RING_COS * aspect) * side + _RING_SIN * up)
    return pos, normal


N_TUBES = len(TUBES)
TUBE_POINTS = N_TUBES * SEGMENTS  # centre-line points of all tubes, tube after tube
CURVE_ROWS = N_TUBES + 2 * len(STRIPS)  # rows of points: each tube's centre line, each strip's two edges
CURVE_POINTS = CURVE_ROWS * SEGMENTS
TUBE_CODE = 2 * EXTRUDED  # added to the material of a tube vertex the vertex shader builds (shader_template)
STRIP_CODE = 4 * EXTRUDED  # likewise for a vertex of the mouth's strips


@numba.njit(cache=True)
def curve_block(
    x: np.ndarray,
    y: np.ndarray,
    lift: np.ndarray,
    jaw_weight: np.ndarray,
    half_h: np.ndarray,
    half_d: np.ndarray,
    block: np.ndarray,
) -> None:
    """What the vertex shader needs to build the brows and the mouth (build_dynamic, _on_face, _tubes):
    per point of the CURVE_ROWS rows, (x, y, lift off the head's surface, jaw weight); then per tube
    centre-line point, (half height, half depth, section aspect, 0). `block` is (CURVE_POINTS +
    TUBE_POINTS, 4) float32."""
    for row in range(CURVE_ROWS):
        for j in range(SEGMENTS):
            k = row * SEGMENTS + j
            block[k, 0], block[k, 1], block[k, 2], block[k, 3] = x[row, j], y[row, j], lift[row, j], jaw_weight[row, j]
    for tube in range(N_TUBES):
        aspect = half_d[tube].sum() / max(half_h[tube].sum(), 1e-9)
        for j in range(SEGMENTS):
            k = CURVE_POINTS + tube * SEGMENTS + j
            block[k, 0], block[k, 1], block[k, 2], block[k, 3] = half_h[tube, j], half_d[tube, j], aspect, 0.0


def shader_template(layout: DynamicLayout) -> np.ndarray:
    """layout.template() with each vertex marked for the vertex shader, which builds them all from the
    curve_block: a tube vertex holds (its centre-line point, cosine, sine of its place around the section)
    and TUBE_CODE added to its material; a strip vertex holds (its point) and STRIP_CODE."""
    out = layout.template()
    k = np.arange(TUBE_POINTS)
    out[layout.tube_block, 0] = np.repeat(k, RING)
    out[layout.tube_block, 1] = np.tile(_RING_COS[:, 0], TUBE_POINTS)
    out[layout.tube_block, 2] = np.tile(_RING_SIN[:, 0], TUBE_POINTS)
    out[layout.tube_block, 9] += TUBE_CODE
    strips = layout.strip_block
    out[strips, 0] = np.arange(TUBE_POINTS, TUBE_POINTS + strips.stop - strips.start)
    out[strips, 1:3] = 0.0
    out[strips, 9] += STRIP_CODE
    return out


def _on_face(x: np.ndarray, y: np.ndarray, lift: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
    """Points on the front of the head at (x, y), moved `lift` along the surface normal, and that normal.

    head_surface_z and head_normal fused, with three powers instead of a dozen: this runs every frame.
    """
    n = HEAD_N
    u = np.clip(-y / HEAD_B, 0.0, 1.0)
    taper = 1.0 - HEAD_TAPER * u * u
    wx = HEAD_A * taper
    ax = np.abs(x) / wx
    ay = np.abs(y) / HEAD_B
    axn = ax**n
    ayn = ay**n
    rest = np.maximum(1.0 - axn - ayn, 1e-9)
    zc = rest ** (1.0 / n)  # z / c
    out = np.empty(x.shape + (3,))
    gx = np.sign(x) * axn / np.maximum(ax, 1e-12) / wx
    dt_dy = np.where((u > 0) & (u < 1), 2.0 * HEAD_TAPER * u / HEAD_B, 0.0)
    gy = np.sign(y) * ayn / np.maximum(ay, 1e-12) / HEAD_B - axn / taper * dt_dy
    gz = rest / zc / HEAD_C
    inv = 1.0 / np.sqrt(gx * gx + gy * gy + gz * gz)
    out[..., 0] = gx * inv
    out[..., 1] = gy * inv
    out[..., 2] = gz * inv
    p = np.empty_like(out)
    p[..., 0] = x
    p[..., 1] = y
    p[..., 2] = HEAD_C * zc
    p += out * np.asarray(lift)[..., None]
    return p, out


def _smooth01(t: np.ndarray) -> np.ndarray:
    t = np.clip(t, 0.0, 1.0)
    return t * t * (3 - 2 * t)


class DynamicLayout:
    """Fixed topology of the per-frame geometry: vertex order, index buffer, named index ranges."""

    def __init__(self) -> None:
        n_tube, n_strip = SEGMENTS * RING, 2 * SEGMENTS
        self.slices: dict[str, slice] = {}
        start = 0
        for name in TUBES:
            self.slices[name] = slice(start, start + n_tube)
            start += n_tube
        self.tube_block = slice(0, start)
        for name in STRIPS:
            self.slices[name] = slice(start, start + n_strip)
            start += n_strip
        self.strip_block = slice(self.tube_block.stop, start)
        self.n_vertices = start
        self.groups = {"brows": ("brow_l", "brow_r"), "lips": ("lip_u", "lip_l"), "inner": STRIPS}

    def template(self) -> np.ndarray:
        """Vertices with the per-frame columns zeroed and material and bones filled in."""
        zeros = np.zeros((self.n_vertices, 3))
        out = _pack(zeros, zeros, "lip", BONE_HEAD, BONE_JAW, 0.0)
        for name in TUBES:
            out[self.slices[name], 9] = MAT[_TUBE_MATERIAL[name]]
        for name in STRIPS:
            out[self.slices[name], 9] = MAT[_STRIP_MATERIAL[name]]
        out[self.strip_block, 3:6] = (0.0, 0.0, 1.0)  # the mouth's inside faces the camera
        return out

    def indices(self, vertices: np.ndarray) -> tuple[np.ndarray, dict[str, tuple[int, int]]]:
        """Index buffer oriented against a sample pose, with (first, count) ranges per group."""
        tube = grid_triangles(SEGMENTS, RING, wrap_u=False, wrap_v=True)
        strip = grid_triangles(2, SEGMENTS, wrap_u=False, wrap_v=False)
        idx, ranges, offset = [], {}, 0
        for group, names in self.groups.items():
            flat = []
            for name in names:
                t = (tube if name in TUBES else strip) + self.slices[name].start
                flat.append(orient_triangles(vertices[:, 0:3], vertices[:, 3:6], t).reshape(-1))
            joined = np.concatenate(flat)
            idx.append(joined)
            ranges[group] = (offset, joined.size)
            offset += joined.size
        return np.concatenate(idx).astype(np.uint32), ranges


def _f(flexors: np.ndarray, name: str) -> float:
    return float(flexors[FLEXOR_INDEX[name]])


def clean_flexors(flexors: np.ndarray) -> np.ndarray:
    """A float64 copy with NaN ("do not care") as relaxed 0 and every value clipped into [-1, 1]."""
    values = np.asarray(getattr(flexors, "values", flexors), dtype=np.float64)
    if values.shape != (N_FLEXORS,):
        raise ValueError(f"a flexor vector needs shape ({N_FLEXORS},), got {values.shape}")
    out = np.clip(values, -1.0, 1.0)  # a new array; infinities land on the bounds, NaN stays NaN
    out[np.isnan(out)] = 0.0
    return out


_T = np.linspace(0.0, 1.0, SEGMENTS)  # along a brow: 0 = inner end, 1 = outer end
_S = np.linspace(-1.0, 1.0, SEGMENTS)  # across the mouth: -1 = viewer's left corner
_BROW_TAPER = np.sin(np.pi * np.clip(0.02 + 0.96 * _T, 0, 1)) ** 0.45
_LIP_TAPER = np.sqrt(np.clip(1.0 - _S**2, 0.0, 1.0)) * 0.85 + 0.15 * (1 - np.abs(_S))


_BROW_SIDE = np.array([[1.0], [-1.0]])  # row 0: the agent's left brow, at +x
_BROW_ARC = np.sin(np.pi * (0.15 + 0.85 * _T))
_BROW_BASE = BROW_Y - 0.06 * _T**2


# The per-frame shapes of the brows and mouth are compiled (numba): a frame runs them once on arrays of
# 13 points, where numpy's per-call overhead, not the arithmetic, was the cost.
@numba.njit(cache=True)
def brow_curves(brow_l: float, brow_r: float, knit: float) -> tuple[np.ndarray, np.ndarray]:
    """Centre lines (x, y) of the agent's left (+x, row 0) and right (row 1) brows, each (2, SEGMENTS).

    brow raises (+) or lowers (-) a whole brow. knit (+) draws the inner ends toward the nose; with
    the brows down it also pulls the inner ends down (the anger V), with the brows up it lifts the inner
    end more than the outer (the oblique brow of worry, sadness and fear). knit (-) arches them apart.
    """
    k, arch_k = max(knit, 0.0), max(-knit, 0.0)
    inner_x = BROW_INNER - 0.05 * k + 0.03 * arch_k
    x = np.empty((2, SEGMENTS))
    y = np.empty((2, SEGMENTS))
    for row in range(2):
        brow = brow_l if row == 0 else brow_r
        up, down = max(brow, 0.0), max(-brow, 0.0)
        worry = min(up / 0.3, 1.0)
        # Per brow: arch height, inner end's lift, and the outer end's lift relative to it.
        arch = 0.045 + 0.05 * arch_k + 0.02 * up
        inner_dy = 0.15 * up - 0.08 * down + 0.1 * k * worry - 0.17 * k * (1 - worry)
        outer_dy = 0.15 * up * (1 - 0.6 * k * worry) - 0.05 * down + 0.06 * k * (1 - worry)
        for j in range(SEGMENTS):
            x[row, j] = _BROW_SIDE[row, 0] * (inner_x + (BROW_OUTER - inner_x) * _T[j])
            y[row, j] = _BROW_BASE[j] + arch * _BROW_ARC[j] + inner_dy + (outer_dy - inner_dy) * _T[j]
    return x, y


@dataclass
class MouthShape:
    """The mouth's lip-edge curves before the jaw moves them, with the jaw angle that then will."""

    x: np.ndarray  # across the mouth, viewer's left to right
    upper: np.ndarray  # y of the upper lip's lower edge
    lower: np.ndarray  # y of the lower lip's upper edge (jaw closed)
    jaw_weight: np.ndarray  # how much of the jaw's rotation each point of the lower lip takes
    protrude: np.ndarray  # forward push of the lips (rounding, pout)
    thick_u: float
    thick_l: float
    jaw_deg: float


_MOUTH_RIGHT = _S >= 0  # +x: the agent's left side
_MOUTH_A = np.abs(_S)
_MOUTH_CURVE = 0.13 * _MOUTH_A**1.8
_MOUTH_ROUND = 1.0 - _MOUTH_A**2
_MOUTH_BUMP = np.exp(-(((_MOUTH_A - 0.45) / 0.28) ** 2))


def mouth_shape(f: np.ndarray) -> MouthShape:
    """The mouth for the (clean, see clean_flexors) flexor vector f."""
    return MouthShape(*_mouth_shape(np.asarray(f, dtype=np.float64)))


_SAY_AH, _SAY_OO, _SAY_EE, _SAY_MM, _SAY_FF = (FLEXOR_INDEX["say_" + n] for n in ("ah", "oo", "ee", "mm", "ff"))
_SMILE_L, _SMILE_R, _SNEER_L, _SNEER_R = (FLEXOR_INDEX[n] for n in ("smile_l", "smile_r", "sneer_l", "sneer_r"))


@numba.njit(cache=True)
def _mouth_shape(f: np.ndarray) -> tuple:  # MouthShape's fields, in order
    ah, oo, ee = max(f[_SAY_AH], 0.0), max(f[_SAY_OO], 0.0), max(f[_SAY_EE], 0.0)
    mm, ff = max(f[_SAY_MM], 0.0), max(f[_SAY_FF], 0.0)
    smile_l, smile_r = f[_SMILE_L], f[_SMILE_R]
    sneer_l, sneer_r = max(f[_SNEER_L], 0.0), max(f[_SNEER_R], 0.0)
    # Corner half-width: spread widens, rounding narrows a lot, a smile pulls the corners out (a frown
    # pulls them in a little). The smile is one value per side, so this is too.
    pull_l = 0.22 * smile_l if smile_l > 0 else 0.05 * smile_l
    pull_r = 0.22 * smile_r if smile_r > 0 else 0.05 * smile_r
    spread = 1.0 + 0.35 * ee - 0.5 * oo - 0.12 * ff + 0.04 * mm
    press = 1.0 - 0.9 * mm
    opening = press * (0.05 * oo + 0.022 * ee + 0.018 * ff + 0.012 * ah)
    rounding = 1.0 - 0.5 * min(oo, 1.0)
    x, upper, lower = np.empty(SEGMENTS), np.empty(SEGMENTS), np.empty(SEGMENTS)
    jaw_weight, protrude = np.empty(SEGMENTS), np.empty(SEGMENTS)
    for j in range(SEGMENTS):
        right = _MOUTH_RIGHT[j]  # +x: the agent's left side
        x[j] = _S[j] * (MOUTH_HALF_WIDTH * (spread + (pull_l if right else pull_r)))
        # Corners up for a smile, down for a frown; flatter in the middle, like a real mouth.
        centre_line = MOUTH_Y + (smile_l if right else smile_r) * _MOUTH_CURVE[j]
        profile = _MOUTH_ROUND[j] ** rounding
        sneer = sneer_l if right else sneer_r
        bump = 0.09 * press * _MOUTH_BUMP[j] + 0.02 * _MOUTH_A[j]
        upper[j] = centre_line + (0.45 * opening) * profile + sneer * bump
        lower[j] = min(centre_line + (0.035 * ff - 0.55 * opening) * profile, upper[j])
        jaw_weight[j] = profile**1.2
        protrude[j] = (0.03 + 0.09 * oo - 0.01 * mm) * profile + 0.012
    thin = 1.0 - 0.45 * mm + 0.2 * oo - 0.2 * ee
    jaw_deg = JAW_MAX_DEG * press * (ah + 0.22 * oo + 0.06 * ee)
    return x, upper, lower, jaw_weight, protrude, 0.03 * thin, 0.037 * thin * (1.0 - 0.3 * ff), jaw_deg


_TEETH_H = 0.05 * (1 - _S**2) + 0.005
_TONGUE_H = 0.03 * np.sqrt(1 - _S**2)
_BROW_HALF_H = 0.048 * _BROW_TAPER * (1.0 - 0.35 * _T)
_BROW_HALF_D = 0.022 * _BROW_TAPER


def build_dynamic(
    f: np.ndarray, shape: MouthShape, layout: DynamicLayout, out: np.ndarray, curves: np.ndarray | None = None
) -> None:
    """Write brows, lips, cavity, teeth and tongue for flexors `f` into `out` (layout.template() rows).

    With `curves` ((CURVE_POINTS + TUBE_POINTS, 4) float32, see curve_block) nothing is built here: the
    points the vertex shader builds them from go into `curves`, and `out` is left as it was.
    """
    bx, by = brow_curves(_f(f, "brow_l"), _f(f, "brow_r"), _f(f, "brows_knit"))
    x, y, lift, weight, half_h, half_d = _curve_rows(
        bx, by, shape.x, shape.upper, shape.lower, shape.jaw_weight, shape.protrude, shape.thick_u, shape.thick_l
    )
    if curves is not None:
        curve_block(x, y, lift, weight, half_h, half_d, curves)
        return
    p, n = _on_face(x, y, lift)
    tb, sb = layout.tube_block, layout.strip_block
    pos, nrm = _tubes(p[: len(TUBES)], n[: len(TUBES)], half_h, half_d)
    out[tb, 0:3] = pos.reshape(-1, 3)
    out[tb, 3:6] = nrm.reshape(-1, 3)
    out[tb, 12] = np.repeat(weight[: len(TUBES)].reshape(-1), RING)
    out[sb, 0:3] = p[len(TUBES) :].reshape(-1, 3)
    out[sb, 12] = weight[len(TUBES) :].reshape(-1)


@numba.njit(cache=True)
def _curve_rows(
    bx: np.ndarray,
    by: np.ndarray,
    mouth_x: np.ndarray,
    upper: np.ndarray,
    lower: np.ndarray,
    jaw_weight: np.ndarray,
    protrude: np.ndarray,
    thick_u: float,
    thick_l: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The rows build_dynamic works from (see curve_block): x, y, lift and jaw weight per point, and the
    tubes' half height and depth. Rows: brow l, brow r, upper lip, lower lip, then the two edges of the
    cavity, the teeth and the tongue."""
    x = np.empty((CURVE_ROWS, SEGMENTS))
    y = np.empty((CURVE_ROWS, SEGMENTS))
    lift = np.empty((CURVE_ROWS, SEGMENTS))
    weight = np.zeros((CURVE_ROWS, SEGMENTS))
    half_h = np.empty((N_TUBES, SEGMENTS))
    half_d = np.empty((N_TUBES, SEGMENTS))
    for j in range(SEGMENTS):
        lip_h_u = thick_u * _LIP_TAPER[j]
        lip_h_l = thick_l * _LIP_TAPER[j]
        inset = protrude[j] * 0.5
        top = upper[j] + 0.01 * _LIP_TAPER[j]
        bottom = lower[j] - 0.01 * _LIP_TAPER[j]
        for row in range(CURVE_ROWS):
            x[row, j] = bx[row, j] if row < 2 else mouth_x[j]
        y[0, j], y[1, j] = by[0, j], by[1, j]
        y[2, j] = upper[j] + 0.85 * lip_h_u
        y[3, j] = lower[j] - 0.85 * lip_h_l
        y[4, j], y[5, j] = top, bottom  # cavity
        y[6, j], y[7, j] = top, upper[j] - _TEETH_H[j]  # teeth
        y[8, j], y[9, j] = lower[j] + _TONGUE_H[j], bottom  # tongue
        lift[0, j] = lift[1, j] = 0.006
        lift[2, j] = protrude[j] + 0.3 * lip_h_u
        lift[3, j] = protrude[j] + 0.3 * lip_h_l
        # the cavity lies behind the teeth and tongue, both behind the lips
        lift[4, j] = lift[5, j] = inset - 0.004
        lift[6, j] = lift[7, j] = inset + 0.002
        lift[8, j] = lift[9, j] = inset + 0.001
        half_h[0, j] = half_h[1, j] = _BROW_HALF_H[j]
        half_d[0, j] = half_d[1, j] = _BROW_HALF_D[j]
        half_h[2, j], half_h[3, j] = lip_h_u, lip_h_l
        half_d[2, j], half_d[3, j] = 0.6 * lip_h_u + 0.004, 0.6 * lip_h_l + 0.004
        # Jaw weights: the lower lip, the cavity's lower edge and the tongue ride on the jaw.
        weight[3, j] = weight[5, j] = weight[9, j] = jaw_weight[j]
        weight[8, j] = 0.85 * jaw_weight[j]
    return x, y, lift, weight, half_h, half_d


@dataclass
class Pose:
    """Everything a frame needs from the flexors: bone matrices, the head's model matrix, dynamic vertices."""

    bones: np.ndarray  # (N_BONES, 4, 4) float64, head frame
    model: np.ndarray  # (4, 4) head frame -> world
    dynamic: np.ndarray  # (layout.n_vertices, 13) float32; see FacePoser.pose and build_dynamic for what is current
    pupils: np.ndarray  # (2, 3) world positions of the agent's left (+x) and right pupil centres
    flexors: np.ndarray | None = None  # the cleaned flexors the pose was made from
    mouth: MouthShape | None = None


@numba.njit(cache=True)
def lid_elevations(blink: float, lids: float, pitch_deg: float) -> tuple[float, float]:
    """Upper and lower rim elevations (degrees) for one eye."""
    blink = min(max(blink, 0.0), 1.0)
    upper = UPPER_RIM_REST + (
        lids * (UPPER_RIM_WIDE - UPPER_RIM_REST) if lids > 0 else -lids * (UPPER_RIM_NARROW - UPPER_RIM_REST)
    )
    upper += UPPER_FOLLOWS_PITCH * pitch_deg
    lower = LOWER_RIM_REST + LOWER_FOLLOWS_PITCH * pitch_deg + 22.0 * max(-lids, 0.0)
    upper = upper + (LIDS_CLOSED - upper) * blink
    lower = lower + (LIDS_CLOSED - 3.0 - lower) * blink
    upper = max(upper, lower + 1.0)
    return upper, lower


# The bones are posed by compiled code (numba): a frame needs a dozen 3x3 products, where Python's and
# numpy's per-call costs, not the arithmetic, would be the cost.
_TURN, _NOD, _TILT, _LOOK_X, _LOOK_Y = (FLEXOR_INDEX[n] for n in ("turn", "nod", "tilt", "look_x", "look_y"))
_BLINK = (FLEXOR_INDEX["blink_l"], FLEXOR_INDEX["blink_r"])  # the agent's left eye (+x) first
_LIDS = (FLEXOR_INDEX["lids_l"], FLEXOR_INDEX["lids_r"])


@numba.njit(cache=True)
def _rotation(axis: int, deg: float) -> np.ndarray:
    """The 3x3 rotation by `deg` about x (axis 0), y (1) or z (2)."""
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    i, j = (1, 2) if axis == 0 else ((2, 0) if axis == 1 else (0, 1))
    r = np.eye(3)
    r[i, i] = c
    r[i, j] = -s
    r[j, i] = s
    r[j, j] = c
    return r


@numba.njit(cache=True)
def _mul3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    out = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            out[i, j] = a[i, 0] * b[0, j] + a[i, 1] * b[1, j] + a[i, 2] * b[2, j]
    return out


@numba.njit(cache=True)
def _about(pivot: np.ndarray, rotation: np.ndarray, out: np.ndarray) -> None:
    """Write into `out` the 4x4 matrix of `rotation` about `pivot` instead of the origin."""
    for k in range(3):
        for j in range(3):
            out[k, j] = rotation[k, j]
        out[k, 3] = pivot[k] - (rotation[k, 0] * pivot[0] + rotation[k, 1] * pivot[1] + rotation[k, 2] * pivot[2])
        out[3, k] = 0.0
    out[3, 3] = 1.0


@numba.njit(cache=True)
def _pose_bones(
    f: np.ndarray,
    degrees: np.ndarray,
    centres: np.ndarray,
    jaw_deg: float,
    bones: np.ndarray,
    model: np.ndarray,
    pupils: np.ndarray,
) -> None:
    """Bones (N_BONES, 4, 4), the head's model matrix and the pupils' world positions (agent's left eye
    first) for the clean flexors f; `degrees` per flexor unit: look_x, look_y, turn, nod, tilt."""
    # turn +1 = toward the agent's right (-x): a negative yaw about +y; nod +1 = chin up: a negative
    # rotation about +x; tilt +1 = toward the agent's right shoulder: the top of the head moves to -x.
    head = _mul3(_mul3(_rotation(1, -f[_TURN] * degrees[2]), _rotation(0, -f[_NOD] * degrees[3])),
                 _rotation(2, f[_TILT] * degrees[4]))  # fmt: skip
    _about(NECK_PIVOT, head, model)
    pitch = f[_LOOK_Y] * degrees[1]
    eye = _mul3(_rotation(1, -f[_LOOK_X] * degrees[0]), _rotation(0, -pitch))
    _about(NECK_PIVOT, np.eye(3), bones[BONE_HEAD])  # the identity
    # Rotating the jaw about +x by a positive angle swings the chin down and back.
    _about(JAW_PIVOT, _rotation(0, jaw_deg), bones[BONE_JAW])
    for side in range(2):
        c = centres[side]
        _about(c, eye, bones[BONE_EYE_L + side])
        up, low = lid_elevations(f[_BLINK[side]], f[_LIDS[side]], pitch)
        _about(c, _rotation(0, -up), bones[BONE_ULID_L + side])
        _about(c, _rotation(0, -low), bones[BONE_LLID_L + side])
        # The pupil: the eye's forward pole, rotated about its centre, then moved with the head.
        x, y, z = c[0] + EYE_RADIUS * eye[0, 2], c[1] + EYE_RADIUS * eye[1, 2], c[2] + EYE_RADIUS * eye[2, 2]
        for k in range(3):
            pupils[side, k] = model[k, 0] * x + model[k, 1] * y + model[k, 2] * z + model[k, 3]


class FacePoser:
    """Turns a flexor vector into a Pose; holds the reusable buffers for the dynamic vertices."""

    def __init__(self, units: FlexorUnits | None = None) -> None:
        self.units = units or load_flexor_units()
        self.layout = DynamicLayout()
        self._dynamic = self.layout.template()
        self._centres = {1: eye_centre(1), -1: eye_centre(-1)}
        self._centre_rows = np.array([self._centres[1], self._centres[-1]])  # the agent's left eye first
        u = self.units
        self._degrees = np.array([u.look_x_deg, u.look_y_deg, u.turn_deg, u.nod_deg, u.tilt_deg], dtype=np.float64)

    def pose(self, flexors: np.ndarray, dynamic: bool = True) -> Pose:
        """The pose for `flexors`. With dynamic=False the brows and mouth are left for build_dynamic(),
        which a renderer can ask for only what its vertex shader needs."""
        f = clean_flexors(flexors)
        shape = mouth_shape(f)
        bones, model, pupils = np.empty((N_BONES, 4, 4)), np.empty((4, 4)), np.empty((2, 3))
        _pose_bones(f, self._degrees, self._centre_rows, shape.jaw_deg, bones, model, pupils)
        pose = Pose(bones=bones, model=model, dynamic=self._dynamic, pupils=pupils, flexors=f, mouth=shape)
        if dynamic:
            self.build_dynamic(pose)
        return pose

    def build_dynamic(self, pose: Pose, curves: np.ndarray | None = None) -> np.ndarray:
        """Write the brows and mouth of `pose` into its dynamic vertices (pose(..., dynamic=False) skips
        it); with `curves`, only the points the vertex shader builds them from (build_dynamic)."""
        assert pose.flexors is not None and pose.mouth is not None
        build_dynamic(pose.flexors, pose.mouth, self.layout, pose.dynamic, curves)
        return pose.dynamic

    def gaze_points(self, gaze: np.ndarray, model: np.ndarray) -> np.ndarray:
        """World positions of both pupil centres for each (look_x, look_y) row: shape (2, N, 3)."""
        gaze = np.asarray(gaze, dtype=np.float64).reshape(-1, 2)
        yaw = np.radians(-np.clip(gaze[:, 0], -1, 1) * self.units.look_x_deg)
        pitch = np.radians(np.clip(gaze[:, 1], -1, 1) * self.units.look_y_deg)
        # Ry(yaw) @ Rx(-pitch) applied to +z
        d = np.stack([np.sin(yaw) * np.cos(pitch), np.sin(pitch), np.cos(yaw) * np.cos(pitch)], -1)
        out = np.empty((2, gaze.shape[0], 3))
        for k, side in enumerate((1, -1)):
            p = self._centres[side] + d * EYE_RADIUS
            out[k] = p @ model[:3, :3].T + model[:3, 3]
        return out


def skin(vertices: np.ndarray, bones: np.ndarray, model: np.ndarray) -> np.ndarray:
    """World positions of vertices under a pose: the same blend the vertex shader does, for tests."""
    pos = np.concatenate([vertices[:, 0:3].astype(np.float64), np.ones((vertices.shape[0], 1))], axis=1)
    b0 = vertices[:, 10].astype(int)
    b1 = vertices[:, 11].astype(int)
    w = vertices[:, 12:13].astype(np.float64)
    p0 = np.einsum("nij,nj->ni", bones[b0], pos)
    p1 = np.einsum("nij,nj->ni", bones[b1], pos)
    blended = p0 * (1 - w) + p1 * w
    return (blended @ model.T)[:, :3]
