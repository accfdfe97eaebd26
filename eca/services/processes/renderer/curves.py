"""The dynamic parts of the face: brows and mouth (lips, cavity, teeth, tongue), rebuilt each frame from the
flexors. Each frame build_dynamic works out the points they are built from (curve_block, compiled), which
the renderer uploads and its vertex shader turns into the brow and lip tubes and the mouth's inner strips on
the head's surface; without a curve block, build_dynamic builds the same vertices in numpy (the reference the
tests use). The lower lip, the tongue and the lower edge of the mouth cavity also ride on the jaw bone, so
the jaw and the lips can never disagree."""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from eca.agent.face.flexors import FLEXOR_INDEX, N_FLEXORS
from eca.services.processes.renderer.geometry import (
    BONE_HEAD,
    BONE_JAW,
    BROW_INNER,
    BROW_OUTER,
    BROW_Y,
    EXTRUDED,
    HEAD_A,
    HEAD_B,
    HEAD_C,
    HEAD_N,
    HEAD_TAPER,
    JAW_MAX_DEG,
    MAT,
    MOUTH_HALF_WIDTH,
    MOUTH_Y,
    _pack,
    cross3,
    grid_triangles,
    orient_triangles,
    unit,
)

# ---------------------------------------------------------------------------------------------------
# Dynamic parts: brows and mouth, rebuilt each frame from the flexors: the points they are built from
# (compiled, below), then in numpy the vertices themselves (the reference for the vertex shader's build).

SEGMENTS, RING = 13, 5  # points along each brow or lip, and around its section
TUBES: tuple[str, ...] = ("brow_l", "brow_r", "lip_u", "lip_l")
STRIPS: tuple[str, ...] = ("cavity", "teeth", "tongue")
_STRIP_MATERIAL = {"cavity": "mouth", "teeth": "teeth", "tongue": "tongue"}
_TUBE_MATERIAL = {"brow_l": "brow", "brow_r": "brow", "lip_u": "lip", "lip_l": "lip"}


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
    side = unit(cross3(out, tangent))[:, :, None, :]
    up = out[:, :, None, :]
    pos = (
        centre[:, :, None, :]
        + (_RING_COS * half_h[..., None, None]) * side
        + (_RING_SIN * half_d[..., None, None]) * up
    )
    # The normal of an ellipse with the tube's mean aspect ratio survives the taper to zero at the ends.
    aspect = (half_d.sum(1) / np.maximum(half_h.sum(1), 1e-9))[:, None, None, None]
    normal = unit((_RING_COS * aspect) * side + _RING_SIN * up)
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
