"""Many faces at one instant in one pass: what a sender of every agent's face at each frame slot composes (the web
service's face frames for pages that draw them, the rig service's frames).

`FaceBatch.compose(scenes, t_ns)` gives the flexors each scene's `LiveScene.compose(t_ns)` gives, as one (N, 21)
array, with the eyes' and head's angles as ComposedFace.from_frame has them. The layers that cost most a face and are
alike for all (the settled layers' closed form, the idle noise on top, the clipping) are evaluated for all faces at
once, element for element the same arithmetic; the layers between them still run face by face, as they hold each
face's own moves. With a layer stack or idle noise other than one shared shape, each face is composed alone.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from eca.agent.face.compositor import DEFAULT_LAYERS
from eca.agent.face.flexors import FLEXOR_INDEX, N_FLEXORS
from eca.agent.face.frame import FLEXOR_MAX, FLEXOR_MIN
from eca.agent.face.idle import IdleNoise, IdleNoiseBatch
from eca.agent.face.model import FaceModel
from eca.agent.face.scene import LiveScene
from eca.agent.face.settling import Settler, settled_many

_LOOK = [FLEXOR_INDEX["look_x"], FLEXOR_INDEX["look_y"]]
_HEAD = [FLEXOR_INDEX["turn"], FLEXOR_INDEX["nod"], FLEXOR_INDEX["tilt"]]


class FaceBatch:
    """Composes many scenes at one instant; keeps what stays between calls (the settled layers' transitions,
    stacked until one of them changes; the idle noise's gradients)."""

    def __init__(self) -> None:
        self._settlers: list[Settler] = []
        self._versions: list[int] = []
        self._transitions: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None
        self._idle = IdleNoiseBatch()
        self.voiced: list[bool] = []  # row by row, of the last compose: whether an utterance was heard then

    def compose(self, scenes: Sequence[LiveScene], t_ns: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(flexors (N, 21) in [-1, 1], eyes (N, 4) [left yaw, left pitch, right yaw, right pitch] and head (N, 3)
        [yaw, pitch, roll] in degrees) of `scenes` at display time t_ns: row i is scenes[i].compose(t_ns)'s face."""
        t = int(t_ns)
        self.voiced = [scene.pose_model(t) for scene in scenes]  # each scene's inputs at t set on its model
        models = [scene.model for scene in scenes]
        values = self._flexors(models, t)
        n = len(models)
        scale = np.array([(m.units.turn_deg, m.units.nod_deg, m.units.tilt_deg, m.units.look_x_deg,
                           m.units.look_y_deg) for m in models]).reshape(n, 5)
        head = values[:, _HEAD] * scale[:, :3]
        look = values[:, _LOOK] * scale[:, 3:]
        # the gaze as set, unclipped, else the look flexors' angles (ComposedFace.from_frame); both eyes alike
        gaze = np.array([look[i] if m.eyes_deg is None else m.eyes_deg for i, m in enumerate(models)]).reshape(n, 2)
        eyes = np.hstack([gaze, gaze])
        return values, eyes, head

    def _flexors(self, models: list[FaceModel], t_ns: int) -> np.ndarray:
        if not models:
            return np.zeros((0, N_FLEXORS))
        noises = self._shared_idle(models)
        if noises is None:  # not one shape: each face alone
            return np.stack([m.compositor.compose(t_ns) for m in models])
        settlers = [m.compositor.settler for m in models]
        versions = [s.version for s in settlers]
        if (self._transitions is None or versions != self._versions or len(settlers) != len(self._settlers)
                or any(a is not b for a, b in zip(settlers, self._settlers, strict=True))):
            parts = [s.transitions() for s in settlers]
            self._transitions = (np.stack([p[0] for p in parts]), np.stack([p[1] for p in parts]),
                                 np.stack([p[2] for p in parts]), np.stack([p[3] for p in parts]))
            self._settlers, self._versions = settlers, versions
        values = settled_many(self._transitions, t_ns)
        for i, model in enumerate(models):
            model.compositor.apply_trajectories(values[i], t_ns, below_top=True)
        if noises:
            cared = self._idle.sparse_at(noises, t_ns)
            if cared is not None:
                index, noise = cared
                values[:, index] += noise
        np.maximum(values, FLEXOR_MIN, out=values)
        return np.minimum(values, FLEXOR_MAX, out=values)

    def _shared_idle(self, models: list[FaceModel]) -> list[IdleNoise] | None:
        """The faces' idle noises when every face has the default layer stack with idle noise of one shape on top
        ([] when none has idle noise), else None."""
        noises: list[IdleNoise] = []
        for model in models:
            compositor = model.compositor
            if compositor.layers is not DEFAULT_LAYERS:  # (the stack a FaceModel makes; another: each face alone)
                return None
            action = compositor.top_action
            if action is not None:
                if not isinstance(action, IdleNoise):
                    return None
                noises.append(action)
        if noises and (len(noises) != len(models) or not self._idle.fits(noises)):
            return None
        return noises
