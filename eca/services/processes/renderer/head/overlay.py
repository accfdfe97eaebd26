"""Marks drawn over the head, as the 2D face draws them: a cross on each pupil's centre and each pupil's recent
path (the gaze trail), a fixed number of pixels wide. Geometry here, in NDC; the drawer draws it."""

from __future__ import annotations

import numpy as np

from eca.services.processes.avatar.drive import agent_rotation

FLOATS = 5  # x, y, r, g, b per vertex
REFERENCE_HEIGHT = 480.0  # widths are in pixels at this height, as renderer.py's


def project(points: np.ndarray, view_proj: np.ndarray) -> np.ndarray:
    """NDC (x, y) of (N, 3) points."""
    h = np.concatenate([points, np.ones((len(points), 1))], axis=1) @ view_proj.T
    return h[:, :2] / h[:, 3:4]


def polyline(ndc: np.ndarray, half_width: float, aspect: float, color: tuple[float, float, float]) -> np.ndarray:
    """Two triangles per segment of a polyline in NDC, `half_width` NDC units (of height) to each side."""
    a, b = ndc[:-1], ndc[1:]
    d = (b - a) * np.array([aspect, 1.0])
    length = np.linalg.norm(d, axis=1, keepdims=True)
    normal = np.stack([-d[:, 1], d[:, 0]], 1) / np.maximum(length, 1e-9) * half_width
    normal[:, 0] /= aspect
    quads = np.stack([a - normal, a + normal, b + normal, a - normal, b + normal, b - normal], 1).reshape(-1, 2)
    out = np.empty((len(quads), FLOATS))
    out[:, :2] = quads
    out[:, 2:] = color
    return out


def cross(p: np.ndarray, arm: float, half_width: float, aspect: float, color: tuple[float, float, float]) -> np.ndarray:
    ax, ay = np.array([arm / aspect, 0.0]), np.array([0.0, arm])
    return np.concatenate([polyline(np.stack([p - ax, p + ax]), half_width, aspect, color),
                           polyline(np.stack([p - ay, p + ay]), half_width, aspect, color)])


def pupil_paths(centres: np.ndarray, head_rotation: np.ndarray, radius: float, angles_deg: np.ndarray) -> np.ndarray:
    """(2, N, 3) model-frame pupil centres of both eyes for N rows of (yaw, pitch) in degrees, in the head turned
    by `head_rotation` (3x3, from its rest) with the eyes' centres at `centres` (2, 3)."""
    angles = np.asarray(angles_deg, dtype=np.float64).reshape(-1, 2)
    fronts: np.ndarray = agent_rotation(angles[:, 0], angles[:, 1]) @ np.array([0.0, 0.0, radius])
    fronts = fronts @ head_rotation.T
    return centres[:, None, :] + fronts[None, :, :]
