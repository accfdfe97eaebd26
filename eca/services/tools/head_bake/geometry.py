"""Mesh geometry for the bake: normals, triangles, ambient occlusion, skin weights, UV islands and seams, clipping."""

from __future__ import annotations

import math

import numpy as np


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
