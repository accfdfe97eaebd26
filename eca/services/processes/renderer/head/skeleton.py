"""Joint transforms: an avatar's rest pose, a few joints moved per frame, and the skinning palette.

glTF gives each joint a local rest transform (parent from child) and each skin joint an inverse bind matrix. The
face moves only a few joints (neck, head, jaw, eyes: eca/services/processes/avatar/drive.py gives their local
transforms each frame, each the rest turned in the model's axes about the joint's pivot); everything else keeps
its rest pose. Per frame only the moved joints and what hangs below them are recomputed (`Posed`): a full VRM
body has hundreds of joints, of which a face moves a handful.
"""

from __future__ import annotations

import numpy as np

from eca.services.processes.avatar.model import Skeleton


def global_transforms(parents: np.ndarray, local: np.ndarray) -> np.ndarray:
    """(J, 4, 4) model-from-joint transforms of (J, 4, 4) local ones (parents come before their children)."""
    out = np.empty_like(local)
    for j, p in enumerate(parents.tolist()):
        out[j] = local[j] if p < 0 else out[p] @ local[j]
    return out


class Posed:
    """The skeleton's joint transforms with a few joints moved; see the module docstring.

    pose(local) -> (J, 4, 4) model-from-joint transforms; `palette` then has each joint's skinning matrix
    (model from bind pose: global @ inverse bind) in float32, ready to upload."""

    def __init__(self, skeleton: Skeleton) -> None:
        self.skeleton = skeleton
        self.parents = np.asarray(skeleton.parents, dtype=np.int64)
        self.rest_local = np.asarray(skeleton.rest, dtype=np.float64)
        self.rest_global = global_transforms(self.parents, self.rest_local)
        self.inverse_bind = np.asarray(skeleton.inverse_bind, dtype=np.float64)
        self.globals = self.rest_global.copy()
        self.palette = (self.rest_global @ self.inverse_bind).astype(np.float32)
        self._children: list[list[int]] = [[] for _ in range(len(self.parents))]
        for j, p in enumerate(self.parents.tolist()):
            if p >= 0:
                self._children[p].append(j)
        self._dirty: list[int] = []  # the joints the last pose moved (their subtrees), in parent-first order
        self.changed: frozenset[int] = frozenset(range(len(self.parents)))  # joints the last pose() recomputed

    @property
    def n_joints(self) -> int:
        return len(self.parents)

    def subtree(self, roots: list[int]) -> list[int]:
        """The roots and every joint below them, parents before children (index order)."""
        seen: set[int] = set()
        stack = list(roots)
        while stack:
            j = stack.pop()
            if j not in seen:
                seen.add(j)
                stack.extend(self._children[j])
        return sorted(seen)

    def pose(self, local: dict[int, np.ndarray]) -> np.ndarray:
        """Joint transforms with each joint of `local` given that (4, 4) local transform (its rest otherwise);
        updates `globals` and `palette` in place and returns `globals`."""
        # Joints moved last frame but not now go back to rest: recompute the union of both frames' subtrees.
        moved = self.subtree(list(local)) if local else []
        todo = sorted(set(moved) | set(self._dirty))
        g = self.globals
        parents = self.parents
        for j in todo:
            m = local.get(j)
            if m is None:
                m = self.rest_local[j]
            p = parents[j]
            g[j] = m if p < 0 else g[p] @ m
        if todo:
            self.palette[todo] = (g[todo] @ self.inverse_bind[todo]).astype(np.float32)
        self._dirty = moved
        self.changed = frozenset(todo)
        return g
