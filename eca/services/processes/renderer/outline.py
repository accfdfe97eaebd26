"""Outlines of the static parts: which triangles face the camera (RigidFacing) and the quads along the
silhouette edges between them (Silhouette), found on the CPU each frame (the per-frame test is compiled:
kernels.py)."""

from __future__ import annotations

import numpy as np

from eca.services.processes.renderer.geometry import EXTRUDED, cross3

# ---------------------------------------------------------------------------------------------------
# Outlines of the static parts. Software GL pays for every triangle it rasterises and for every pixel
# a triangle touches, visible or not. An inverted hull (every back face, pushed outward) makes the
# rasteriser walk the hidden back of the head to draw a thin line around it; quads along the
# silhouette edges, found on the CPU each frame, draw the same line from a few hundred thin triangles.



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
        normal = cross3(pos[tri[:, 1]] - p0, pos[tri[:, 2]] - p0)
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
