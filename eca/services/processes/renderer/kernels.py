"""The renderer's per-frame arithmetic on the static mesh, compiled with numba.

Each frame the renderer decides which static triangles may face the camera and which of their edges lie
on the silhouette (outline.RigidFacing, renderer.FrameIndices). That is a few thousand multiply-adds, yet
done with numpy it took about 0.2 ms of a 4 ms software-GL frame, nearly all of it numpy's per-call
cost on small arrays; as one compiled loop it takes about 25 microseconds. The numpy code stays as the
reference the tests hold this to, operation for operation. (The per-frame posing in poser.py
and curves.py is compiled too.)

Compiled on first use and cached on disk (numba's cache=True, beside the installed package), so only the
first run of an install pays: every renderer calls ensure_compiled() before it draws, which says so in one
line when it takes a while, and `eca warm-up` (or setup) does it ahead of time.
"""

from __future__ import annotations

import sys
import threading
import time

import numba
import numpy as np

from eca.agent.face.flexors import N_FLEXORS
from eca.services.processes.renderer.curves import CURVE_POINTS, TUBE_POINTS
from eca.services.processes.renderer.geometry import N_BONES
from eca.services.processes.renderer.poser import FacePoser


@numba.njit(cache=True)
def static_frame_indices(
    bones: np.ndarray,
    eye: np.ndarray,
    normal: np.ndarray,
    offset: np.ndarray,
    bone: np.ndarray,
    mixed: np.ndarray,
    mixed_corners: np.ndarray,
    mixed_rest: np.ndarray,
    mixed_bones: np.ndarray,
    mixed_weight: np.ndarray,
    mixed_scale: np.ndarray,
    slack: float,
    triangles: np.ndarray,
    group_starts: np.ndarray,
    edge_t0: np.ndarray,
    edge_t1: np.ndarray,
    edge_quads: np.ndarray,
    edge_starts: np.ndarray,
    surface_out: np.ndarray,
    surface_counts: np.ndarray,
    quads_out: np.ndarray,
    quad_counts: np.ndarray,
    front: np.ndarray,
) -> None:
    """RigidFacing.distances then FrameIndices.update, in one pass.

    bones (B, 4, 4) and eye (3,) are the frame's; normal, offset, bone and the mixed_* arrays are
    RigidFacing.compiled_inputs(); triangles (T, 3), group_starts, edge_t0/t1, edge_quads (E, 6) and
    edge_starts are FrameIndices'. Writes the triangles that may face the camera, group after group, into
    surface_out with each group's count in surface_counts; the silhouette quads likewise into quads_out
    and quad_counts; front[t] says whether triangle t faces the camera (front[T] stays False).
    """
    n_bones = bones.shape[0]
    eye_in_bone = np.empty((n_bones, 3))
    for b in range(n_bones):  # B^-1 e for each rigid bone: R^T (e - t)
        ex, ey, ez = eye[0] - bones[b, 0, 3], eye[1] - bones[b, 1, 3], eye[2] - bones[b, 2, 3]
        for k in range(3):
            eye_in_bone[b, k] = bones[b, 0, k] * ex + bones[b, 1, k] * ey + bones[b, 2, k] * ez
    n = normal.shape[0]
    distance = np.empty(n)
    for i in range(n):
        b = bone[i]
        distance[i] = (
            normal[i, 0] * eye_in_bone[b, 0] + normal[i, 1] * eye_in_bone[b, 1] + normal[i, 2] * eye_in_bone[b, 2]
        ) - offset[i]
    # The triangles that blend two bones: skin their corners and take the plane through them.
    posed = np.empty((mixed_rest.shape[0], 3))
    for v in range(mixed_rest.shape[0]):
        b0, b1, w = mixed_bones[v, 0], mixed_bones[v, 1], mixed_weight[v]
        x, y, z = mixed_rest[v, 0], mixed_rest[v, 1], mixed_rest[v, 2]
        for k in range(3):
            a = bones[b0, k, 0] * x + bones[b0, k, 1] * y + bones[b0, k, 2] * z + bones[b0, k, 3]
            c = bones[b1, k, 0] * x + bones[b1, k, 1] * y + bones[b1, k, 2] * z + bones[b1, k, 3]
            posed[v, k] = a + (c - a) * w
    for j in range(mixed.shape[0]):
        c0, c1, c2 = mixed_corners[j, 0], mixed_corners[j, 1], mixed_corners[j, 2]
        x0, y0, z0 = posed[c0, 0], posed[c0, 1], posed[c0, 2]
        ux, uy, uz = posed[c1, 0] - x0, posed[c1, 1] - y0, posed[c1, 2] - z0
        vx, vy, vz = posed[c2, 0] - x0, posed[c2, 1] - y0, posed[c2, 2] - z0
        dx, dy, dz = eye[0] - x0, eye[1] - y0, eye[2] - z0
        cross_dot = (uy * vz - uz * vy) * dx + (uz * vx - ux * vz) * dy + (ux * vy - uy * vx) * dz
        distance[mixed[j]] = cross_dot * mixed_scale[j]
    # The surface: each group's triangles that may face the camera, in mesh order.
    kept = 0
    for g in range(group_starts.shape[0]):
        stop = group_starts[g + 1] if g + 1 < group_starts.shape[0] else n
        first = kept
        for i in range(group_starts[g], stop):
            if distance[i] > -slack:
                for k in range(3):
                    surface_out[kept, k] = triangles[i, k]
                kept += 1
        surface_counts[g] = kept - first
    # The outline: the edges between a triangle facing the camera and one not.
    for i in range(n):
        front[i] = distance[i] > 0.0
    kept = 0
    for g in range(edge_starts.shape[0]):
        stop = edge_starts[g + 1] if g + 1 < edge_starts.shape[0] else edge_t0.shape[0]
        first = kept
        for e in range(edge_starts[g], stop):
            if front[edge_t0[e]] != front[edge_t1[e]]:
                for k in range(6):
                    quads_out[kept, k] = edge_quads[e, k]
                kept += 1
        quad_counts[g] = kept - first


def warm_up() -> float:
    """Compile (or load from numba's cache) everything the renderer runs compiled, outside any frame;
    returns the seconds it took. Setup runs it once, so a renderer's first start is not the one to pay."""
    began = time.perf_counter()
    poser = FacePoser()
    pose = poser.pose(np.zeros(N_FLEXORS))  # the bones, the mouth and the numpy build's rows
    poser.build_dynamic(pose, np.zeros((CURVE_POINTS + TUBE_POINTS, 4), dtype=np.float32))
    # The facing pass on a one-triangle mesh of the real call's types.
    f8, i8, u4 = np.float64, np.int64, np.uint32
    static_frame_indices(
        np.tile(np.eye(4), (N_BONES, 1, 1)), np.zeros(3), np.zeros((1, 3)), np.zeros(1), np.zeros(1, i8),
        np.zeros(0, i8), np.zeros((0, 3), i8), np.zeros((0, 3)), np.zeros((0, 2), i8), np.zeros(0, f8),
        np.zeros(0, f8), 1e-4, np.zeros((1, 3), u4), np.zeros(1, i8), np.zeros(1, i8), np.ones(1, i8),
        np.zeros((1, 6), u4), np.zeros(1, i8), np.zeros((1, 3), u4), np.zeros(1, i8), np.zeros((1, 6), u4),
        np.zeros(1, i8), np.zeros(2, dtype=bool),
    )  # fmt: skip
    return time.perf_counter() - began



NOTICE_AFTER_S = 2.0  # loading from the cache takes under a second even on a loaded machine; compiling 5-30 s
_compiled = threading.Lock()
_done = False


def ensure_compiled(notice_after_s: float = NOTICE_AFTER_S) -> None:
    """warm_up() once per process, before the first picture. When it takes longer than `notice_after_s` (a
    compile, not a load from the cache) one line on stderr says what is happening, and another when done."""
    global _done
    with _compiled:
        if _done:
            return
        finished = threading.Event()
        noticed = threading.Event()

        def notice() -> None:
            if not finished.wait(notice_after_s):
                noticed.set()
                print("eca: compiling the face's drawing code (numba), once per install; later starts load it "
                      "from the cache ...", file=sys.stderr, flush=True)

        watcher = threading.Thread(target=notice, daemon=True, name="eca-compile-notice")
        watcher.start()
        took_s = warm_up()
        finished.set()
        watcher.join()
        if noticed.is_set():
            print(f"eca: the face's drawing code is compiled ({took_s:.1f} s)", file=sys.stderr, flush=True)
        _done = True
