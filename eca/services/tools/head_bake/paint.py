"""The head's textures, painted: colour conversions, rasterising in UV space, the skin, eyes, hair, brows,
lashes and mouth."""

from __future__ import annotations

import io
import math

import numpy as np

from eca.services.tools.head_bake.constants import (
    BROW_SRGB,
    HAIR_SRGB,
    LASH_ROWS,
    LASH_SRGB,
    LIP_SRGB,
    MOUTH_SRGB,
    SEED,
    SKIN_SRGB,
    TEETH_SRGB,
    TONGUE_SRGB,
)
from eca.services.tools.head_bake.geometry import _smoothstep


def srgb_from_linear(c: np.ndarray) -> np.ndarray:
    c = np.clip(c, 0.0, 1.0)
    return np.where(c <= 0.0031308, 12.92 * c, 1.055 * np.power(c, 1 / 2.4) - 0.055)


def linear_from_srgb(c: np.ndarray | tuple[float, ...]) -> np.ndarray:
    c = np.asarray(c, dtype=np.float64)
    return np.where(c <= 0.04045, c / 12.92, np.power((c + 0.055) / 1.055, 2.4))


def to_bytes8(c: np.ndarray) -> np.ndarray:
    return np.round(np.clip(c, 0.0, 1.0) * 255.0).astype(np.uint8)


def decode_mask(data: bytes) -> np.ndarray:
    """A grey region mask of MPFB2 (2048 px JPEG in the base mesh's uv layout) as floats 0..1, rows top down."""
    from PIL import Image

    with Image.open(io.BytesIO(data)) as image:
        return np.asarray(image.convert("L"), dtype=np.float64) / 255.0


def sample_image(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear samples of an (H, W[, C]) image at OBJ uvs (v up), clamped at the edges."""
    height, width = image.shape[:2]
    x = np.clip(uv[:, 0] * width - 0.5, 0, width - 1)
    y = np.clip((1.0 - uv[:, 1]) * height - 0.5, 0, height - 1)
    x0 = np.minimum(x.astype(np.int64), width - 2)
    y0 = np.minimum(y.astype(np.int64), height - 2)
    fx = x - x0
    fy = y - y0
    if image.ndim == 3:
        fx = fx[:, None]
        fy = fy[:, None]
    top = image[y0, x0] * (1 - fx) + image[y0, x0 + 1] * fx
    bottom = image[y0 + 1, x0] * (1 - fx) + image[y0 + 1, x0 + 1] * fx
    return top * (1 - fy) + bottom * fy


def rasterise(uv_px: np.ndarray, triangles: np.ndarray, attributes: np.ndarray,
              height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """Per-texel attributes interpolated over triangles drawn in texture space (pixel coordinates, x right, y
    down): the (H, W, C) image and the (H, W) mask of covered texels. A texel belongs to the last triangle that
    covers its centre (triangles are drawn in order)."""
    image = np.zeros((height, width, attributes.shape[1]))
    covered = np.zeros((height, width), dtype=bool)
    corners = uv_px[triangles]
    for t in range(len(triangles)):
        (x0, y0), (x1, y1), (x2, y2) = corners[t]
        area = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)
        if abs(area) < 1e-12:
            continue
        lo_x = max(int(math.floor(min(x0, x1, x2) - 0.5)), 0)
        hi_x = min(int(math.ceil(max(x0, x1, x2) + 0.5)), width - 1)
        lo_y = max(int(math.floor(min(y0, y1, y2) - 0.5)), 0)
        hi_y = min(int(math.ceil(max(y0, y1, y2) + 0.5)), height - 1)
        if hi_x < lo_x or hi_y < lo_y:
            continue
        px, py = np.meshgrid(np.arange(lo_x, hi_x + 1) + 0.5, np.arange(lo_y, hi_y + 1) + 0.5)
        w0 = ((x1 - px) * (y2 - py) - (x2 - px) * (y1 - py)) / area
        w1 = ((x2 - px) * (y0 - py) - (x0 - px) * (y2 - py)) / area
        w2 = 1.0 - w0 - w1
        inside = (w0 >= -1e-9) & (w1 >= -1e-9) & (w2 >= -1e-9)
        if not inside.any():
            continue
        a = attributes[triangles[t]]
        values = w0[..., None] * a[0] + w1[..., None] * a[1] + w2[..., None] * a[2]
        rows, cols = np.nonzero(inside)
        image[lo_y + rows, lo_x + cols] = values[rows, cols]
        covered[lo_y + rows, lo_x + cols] = True
    return image, covered


def dilate(image: np.ndarray, covered: np.ndarray, steps: int) -> np.ndarray:
    """Grow the covered texels outward by `steps` texels (each empty texel takes the mean of its covered
    4-neighbours), so filtering and mipmaps near an island's edge never fetch the empty background."""
    image = image.copy()
    covered = covered.copy()
    for _ in range(steps):
        total = np.zeros_like(image)
        count = np.zeros(covered.shape)
        for axis, shift in ((0, 1), (0, -1), (1, 1), (1, -1)):
            total += np.roll(image * covered[..., None], shift, axis=axis)
            count += np.roll(covered, shift, axis=axis)
        grow = (~covered) & (count > 0)
        image[grow] = total[grow] / count[grow, None]
        covered |= grow
    return image


def value_noise(shape: tuple[int, int], cells: int, rng: np.random.Generator) -> np.ndarray:
    """Smooth noise in [0, 1] over an image: random values on a `cells` x `cells` lattice, bicubically blended."""
    lattice = rng.random((cells + 3, cells + 3))
    ys = np.linspace(0, cells, shape[0], endpoint=False) + 1
    xs = np.linspace(0, cells, shape[1], endpoint=False) + 1
    iy = ys.astype(np.int64)
    ix = xs.astype(np.int64)
    fy = _smoothstep(0.0, 1.0, ys - iy)[:, None]
    fx = _smoothstep(0.0, 1.0, xs - ix)[None, :]
    a = lattice[np.ix_(iy, ix)]
    b = lattice[np.ix_(iy, ix + 1)]
    c = lattice[np.ix_(iy + 1, ix)]
    d = lattice[np.ix_(iy + 1, ix + 1)]
    return (a * (1 - fx) + b * fx) * (1 - fy) + (c * (1 - fx) + d * fx) * fy


# -- painting ---------------------------------------------------------------------------------------------------


def above_hairline(p: np.ndarray) -> np.ndarray:
    """How far points of the model frame (metres, origin between the eyes) lie above the hairline, in metres
    (negative below): the line's height per angle around a vertical axis 8.5 cm behind the eyes (the head's
    middle), across the forehead, in at the temples, down the sideburns in front of the ears (which sit at
    68-94 degrees), over them and down to the nape. Linear in height, so a cut where it is 0 runs straight
    across the faces it crosses."""
    angle = np.degrees(np.arctan2(np.abs(p[:, 0]), p[:, 2] + 0.085))  # 0 front, 180 back
    knots_a = np.array([0.0, 15.0, 28.0, 38.0, 48.0, 56.0, 61.0, 65.0, 68.0, 80.0, 96.0, 108.0, 125.0, 150.0, 180.0])
    knots_y = np.array([0.061, 0.060, 0.056, 0.047, 0.040, 0.028, 0.005, -0.018, -0.005, 0.016, 0.012, -0.010,
                        -0.040, -0.058, -0.066])
    return p[:, 1] - np.interp(angle, knots_a, knots_y)


def hair_amount(p: np.ndarray, lower: float = 0.0, soft: float = 0.0035) -> np.ndarray:
    """Where the hair grows, 0..1, fading over 2 `soft` metres across the hairline (above_hairline) moved
    `lower` metres down."""
    return _smoothstep(-soft, soft, above_hairline(p) + lower)


def brow_amount(p: np.ndarray) -> np.ndarray:
    """The eyebrows' coverage 0..1 on points of the model frame (both sides by |x|): an arch over each eye where
    the Face Units' brow targets move the skin, full at the inner end and tapering to the tail."""
    x = np.abs(p[:, 0])
    s = np.clip((x - 0.011) / (0.058 - 0.011), -0.2, 1.2)  # 0 inner end .. 1 tail
    centre = _brow_centre(s)
    half = 0.0045 * (1 - s) + 0.0017 * s
    across = 1.0 - _smoothstep(0.45, 1.0, np.abs(p[:, 1] - centre) / np.maximum(half, 1e-4))
    along = _smoothstep(-0.12, 0.06, s) * (1.0 - _smoothstep(0.9, 1.05, s))
    front = _smoothstep(-0.02, 0.0, p[:, 2])
    return across * along * front


def _brow_centre(s: np.ndarray | float) -> np.ndarray:
    """The brow's middle line: its height (metres above the eyes) along it, s = 0 inner end .. 1 tail."""
    s = np.asarray(s, dtype=np.float64)
    return 0.0175 + 0.0095 * np.sin(np.clip(s, 0, 1) * math.pi * 0.78) - 0.004 * np.clip(s - 0.8, 0, None)


def paint_skin(position: np.ndarray, ao: np.ndarray, masks: dict[str, np.ndarray],
               noise: np.ndarray) -> np.ndarray:
    """Linear RGB of skin texels from what each texel is: its point on the head (metres), its occlusion and the
    MPFB2 region masks there; the warm base tone, redder lips, cheeks, nose and ears, a darker inside of the
    mouth, the hair's colour fading out just below the cap's edge, a faint blotchiness, the occlusion over all."""
    n = len(position)
    colour = np.tile(linear_from_srgb(SKIN_SRGB), (n, 1))
    colour *= (0.94 + 0.12 * noise)[:, None]
    blush = linear_from_srgb((0.86, 0.55, 0.48))

    def glow(cx: float, cy: float, cz: float, r: float) -> np.ndarray:
        d2 = (np.abs(position[:, 0]) - cx) ** 2 + (position[:, 1] - cy) ** 2 + (position[:, 2] - cz) ** 2
        return np.exp(-d2 / (r * r))

    flush = 0.22 * glow(0.040, -0.030, 0.010, 0.020) + 0.15 * glow(0.0, -0.038, 0.040, 0.010)
    flush = flush + 0.25 * masks["ears"]
    colour += (blush - colour) * np.clip(flush, 0, 1)[:, None]
    colour *= (1.0 - 0.10 * masks["lids"])[:, None]
    colour += (linear_from_srgb(LIP_SRGB) - colour) * (0.85 * masks["lips"])[:, None]
    colour += (linear_from_srgb(MOUTH_SRGB) - colour) * masks["mouth"][:, None]
    hair = hair_amount(position, lower=0.004) * (1.0 - masks["ears"])
    colour += (linear_from_srgb(HAIR_SRGB) - colour) * (0.85 * hair)[:, None]
    return colour * (0.2 + 0.8 * np.power(np.clip(ao, 0, 1), 1.3))[:, None]


def paint_eye(size: int) -> np.ndarray:
    """The eyeball's sRGB texture: a disc (see eye_uv) with the pupil in the middle, a hazel iris of radial
    fibres with a lighter collarette and a dark limbal ring, and the sclera around it, greying toward the back."""
    rng = np.random.default_rng(SEED + 1)
    y, x = np.mgrid[0:size, 0:size]
    u = (x + 0.5) / size - 0.5
    v = (y + 0.5) / size - 0.5
    r = np.sqrt(u * u + v * v) * 2.0  # 0 centre .. 1 rim
    angle = np.arctan2(v, u)
    fibres = np.zeros_like(r)
    for k in range(24):
        freq = int(rng.integers(18, 90))
        phase = rng.random() * 2 * math.pi
        fibres += np.sin(freq * angle + phase + 3.0 * rng.random() * r) / (1 + k * 0.15)
    fibres = 0.5 + 0.5 * np.tanh(fibres / 3.0)
    t = r / IRIS_DISC  # 0 pupil centre .. 1 limbus
    inner = linear_from_srgb((0.62, 0.47, 0.22))
    outer = linear_from_srgb((0.33, 0.20, 0.10))
    mix = _smoothstep(0.25, 0.75, t)[..., None]
    iris = inner * (1 - mix) + outer * mix
    iris = iris * (0.55 + 0.75 * fibres)[..., None]
    iris *= (1.0 + 0.35 * np.exp(-((t - 0.42) / 0.06) ** 2))[..., None]  # the collarette
    iris *= (1.0 - 0.65 * _smoothstep(0.80, 0.98, t))[..., None]  # the limbal ring
    pupil = _smoothstep(PUPIL_FRACTION - 0.03, PUPIL_FRACTION + 0.02, t)[..., None]
    iris = iris * pupil + np.array([0.004, 0.004, 0.005]) * (1 - pupil)
    sclera = linear_from_srgb((0.93, 0.90, 0.87)) * (1.0 - 0.25 * _smoothstep(0.55, 1.0, r))[..., None]
    pink = 0.25 * _smoothstep(IRIS_DISC + 0.1, 0.7, r)[..., None]
    sclera += (linear_from_srgb((0.85, 0.60, 0.58)) - sclera) * pink
    edge = _smoothstep(IRIS_DISC - 0.012, IRIS_DISC + 0.012, r)[..., None]
    return to_bytes8(srgb_from_linear(iris * (1 - edge) + sclera * edge))


def paint_hair(size: int) -> np.ndarray:
    """The hair cap's sRGB texture: a disc (the cap's uvs, centred on the crown) of strands radiating from the
    crown, lighter and darker ones over the dark brown, with a sheen that comes and goes along them. Each
    strand frequency fades in only where the circle is long enough to carry it, so the crown shows no moire;
    drawn at twice the size and averaged down."""
    rng = np.random.default_rng(SEED + 2)
    big = 2 * size
    y, x = np.mgrid[0:big, 0:big]
    u = (x + 0.5) / big - 0.5
    v = (y + 0.5) / big - 0.5
    r = np.sqrt(u * u + v * v) * 2.0
    angle = np.arctan2(v, u)
    circumference = math.pi * r * big  # pixels around the circle through each pixel
    strands = np.zeros_like(r)
    for k in range(32):
        freq = int(rng.integers(40, 260))
        phase = rng.random() * 2 * math.pi
        bend = rng.random() * 2.0
        carried = _smoothstep(2.0 * freq, 4.0 * freq, circumference)
        strands += carried * np.sin(freq * (angle + 0.15 * np.sin(bend * r * 3.0)) + phase) / (1 + 0.1 * k)
    strands = 0.5 + 0.5 * np.tanh(strands / 2.5)
    colour = linear_from_srgb(HAIR_SRGB) * (0.55 + 0.9 * strands)[..., None]
    colour *= (0.9 + 0.2 * np.sin(r * 22.0 + 2.0 * strands))[..., None]
    return to_bytes8(srgb_from_linear(colour.reshape(size, 2, size, 2, 3).mean(axis=(1, 3))))


def _strokes(px: np.ndarray, py: np.ndarray, strokes: list[tuple[float, float, float, float, float, float]]
             ) -> np.ndarray:
    """Coverage 0..1 of soft straight strokes (x, y, angle, length, width, opacity) over a grid of points, each
    stroke fading from its root to its tip; strokes overlap as layers of paint do: 1 - prod(1 - each)."""
    clear = np.ones_like(px)
    for x0, y0, angle, length, width, opacity in strokes:
        dx, dy = math.cos(angle), math.sin(angle)
        rx, ry = px - x0, py - y0
        along = np.clip(rx * dx + ry * dy, 0.0, length)
        dist = np.sqrt((rx - along * dx) ** 2 + (ry - along * dy) ** 2)
        taper = width * (1.0 - 0.6 * along / length)
        clear *= 1.0 - np.clip(1.0 - dist / taper, 0.0, 1.0) * opacity * (1.0 - 0.5 * along / length)
    return 1.0 - clear


def paint_brows(height: int, width: int) -> np.ndarray:
    """The brows' sRGB + alpha texture in the decal's uvs (u: |x| 0..BROW_X, v: y from BROW_TOP down BROW_H):
    a soft base of the brow's shape and some nine hundred hairs over it, short soft strokes that lean up at the
    inner end and out along the arch toward the tail."""
    rng = np.random.default_rng(SEED + 3)
    y, x = np.mgrid[0:height, 0:width]
    px = (x + 0.5) / width * BROW_X  # metres, |x|
    py = BROW_TOP - (y + 0.5) / height * BROW_H  # metres, y
    coverage = brow_amount(np.stack([px.ravel(), py.ravel(), np.zeros(px.size)], axis=1)).reshape(height, width)
    strokes = []
    for _ in range(900):
        s = float(rng.random())
        half = 0.0045 * (1 - s) + 0.0017 * s
        hy = float(_brow_centre(s)) + float(rng.random() * 2 - 1) * half * 0.9
        lean = math.radians(80 - 70 * s + float(rng.normal()) * 8)  # up at the inner end, along the arch later
        strokes.append((0.011 + s * 0.047, hy - 0.001 * math.sin(lean), lean, 0.0035 + 0.002 * float(rng.random()),
                        0.00022, 0.6))
    hairs = _strokes(px, py, strokes)
    alpha = np.clip(0.45 * coverage + hairs * (0.4 + 0.6 * coverage), 0.0, 1.0)
    colour = np.tile(linear_from_srgb(BROW_SRGB), (height, width, 1))
    return np.concatenate([to_bytes8(srgb_from_linear(colour)), to_bytes8(alpha)[..., None]], axis=2)


def paint_lashes(height: int, width: int) -> np.ndarray:
    """The lashes' sRGB + alpha texture: the upper lid's strip on rows LASH_ROWS[0], the lower's on LASH_ROWS[1]
    (u along the lid, v from root to tip, see strip_uvs), clear between them so filtering at one strip's tip
    fetches nothing of the other; curved hairs rooted along the lid, dense above, sparse and short below, and
    a thin dark line at the root."""
    rng = np.random.default_rng(SEED + 4)
    y, x = np.mgrid[0:height, 0:width]
    px = (x + 0.5) / width
    py = (y + 0.5) / height
    aspect = height / width  # strokes are drawn in pixel-square units
    strokes = []
    root = np.zeros_like(px)
    ends = _smoothstep(0.0, 0.15, px) * (1.0 - _smoothstep(0.85, 1.0, px))  # no root line past the hairs
    for (top, bottom), count, length, opacity in ((LASH_ROWS[0], 240, 0.9, 0.95), (LASH_ROWS[1], 80, 0.6, 0.6)):
        span = bottom - top
        for _ in range(count):
            u = 0.08 + 0.84 * float(rng.random())  # none at the strip's very ends, where they would be dots
            lean = math.pi / 2 + (u - 0.5) * 0.9 + float(rng.normal()) * 0.12
            middle = 1.0 - abs(u - 0.5)
            reach = span * length * (0.6 + 0.4 * float(rng.random())) * middle
            strokes.append((u, (top + 0.02 * span) * aspect, lean, reach * aspect, 0.008,
                            opacity * min(1.0, 2.5 * middle - 0.4)))
        root += np.exp(-((py - top - 0.04 * span) / (0.06 * span)) ** 2) * ends * opacity
    alpha = _strokes(px, py * aspect, strokes)
    alpha = np.clip(np.maximum(alpha, root), 0.0, 1.0)
    colour = np.tile(linear_from_srgb(LASH_SRGB), (height, width, 1))
    return np.concatenate([to_bytes8(srgb_from_linear(colour)), to_bytes8(alpha)[..., None]], axis=2)


def paint_mouth(part_of_texel: np.ndarray, ao: np.ndarray) -> np.ndarray:
    """Linear RGB of the teeth's and tongue's texels (part 0, 1: teeth, 2: tongue), darkened by their occlusion
    with the jaw open, so the back teeth and the root of the tongue sink into the mouth's shadow."""
    teeth = linear_from_srgb(TEETH_SRGB)
    tongue = linear_from_srgb(TONGUE_SRGB)
    colour = np.where((part_of_texel >= 1.5)[:, None], tongue, teeth)
    return colour * (0.2 + 0.8 * np.clip(ao, 0, 1))[:, None]


BROW_X = 0.066  # the brow texture's extent: |x| 0 .. 6.6 cm
BROW_TOP = 0.040  # y of its top row
BROW_H = 0.034  # its height
IRIS_DISC = 0.5  # the iris' radius on the eye texture's disc (0..1)
IRIS_DEG = 28.0  # the iris' angular radius on the eyeball (a real eye's limbus: asin(5.9 / 12 mm), 29 degrees)
PUPIL_FRACTION = 0.36  # the pupil's radius as a fraction of the iris'
CORNEA_DEG = 34.0  # the cornea's angular radius
CORNEA_BULGE = 0.0006  # metres the cornea stands out from the eyeball at its centre


def eye_uv(theta_deg: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """Eye texture uvs of a point on the eyeball at `theta_deg` from the gaze axis (+Z), `phi` around it: a
    disc, the iris (theta < IRIS_DEG) on radius < IRIS_DISC, the sclera all the way to the back on the rest."""
    disc = np.where(theta_deg <= IRIS_DEG, theta_deg / IRIS_DEG * IRIS_DISC,
                    IRIS_DISC + (theta_deg - IRIS_DEG) / (180.0 - IRIS_DEG) * (1 - IRIS_DISC)) * 0.5
    return np.stack([0.5 + disc * np.cos(phi), 0.5 - disc * np.sin(phi)], axis=1)
