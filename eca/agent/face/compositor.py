"""Layered compositing of flexor actions (Perlin, "Layered compositing of facial expression", 1997).

Layers are stacked bottom to top. Each asks for values on the flexors it cares about and writes NaN
("do not care") elsewhere, which leaves the flexor to the layers below. A layer either replaces what is
below it or adds to it (an offset: the head's moves on top of an emotion's chin-up, idle noise on top of
everything).

Two kinds of layer:
- settled layers hold constant poses (the natural face, the emotion). Their composite is the target of
  a `Settler`, so every flexor approaches a new target with its own settle time, in closed form from the
  time the target changed. They form the bottom of the stack.
- trajectory layers hold actions that already move smoothly (head moves, gaze, blink, lip-sync mouth,
  idle noise) and are sampled at the frame time as they are.

The composite at t is a function of the layer contents, the times they were set, and t only: any frame
rate, or none, gives the same values.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from enum import Enum

import numpy as np

from eca.agent.face.actions import Action, Pose, SparseValues, as_pose_vector
from eca.agent.face.flexors import N_FLEXORS
from eca.agent.face.frame import FLEXOR_MAX, FLEXOR_MIN, FlexorFrame, dont_care_vector
from eca.agent.face.settling import Settler


class Blend(Enum):
    REPLACE = "replace"
    ADD = "add"


@dataclass(frozen=True)
class LayerSpec:
    name: str
    blend: Blend = Blend.REPLACE
    settles: bool = False


# Bottom to top. The emotion sits on the natural face; head moves add to the emotion's head posture, the
# turn toward the person attended (situated gaze) and head gestures (a listener's nods) add to those;
# gaze, lip-sync and blinks override what the emotion says about eyes, mouth and lids while they care.
DEFAULT_LAYERS: tuple[LayerSpec, ...] = (
    LayerSpec("base", Blend.REPLACE, settles=True),
    LayerSpec("emotion", Blend.REPLACE, settles=True),
    LayerSpec("head", Blend.ADD),
    LayerSpec("attention", Blend.ADD),
    LayerSpec("gesture", Blend.ADD),
    LayerSpec("gaze", Blend.REPLACE),
    LayerSpec("mouth", Blend.REPLACE),
    LayerSpec("blink", Blend.REPLACE),
    # timed facial behaviours (BML faceLexeme, faceFacs, blink): over everything the face does, so a lexeme's open
    # mouth adds to the speech's and a blink closes the lids whatever the gaze's lid is
    LayerSpec("expression", Blend.ADD),
    LayerSpec("idle", Blend.ADD),
)


def blend_onto(below: np.ndarray, layer: np.ndarray, blend: Blend) -> np.ndarray:
    """One layer over the composite below it; NaN in the layer leaves the value below untouched."""
    cares = ~np.isnan(layer)
    if blend is Blend.ADD:
        # Adding to "do not care" below adds to the relaxed value 0.
        return np.where(cares, np.nan_to_num(below) + np.nan_to_num(layer), below)
    return np.where(cares, layer, below)


class Compositor:
    def __init__(
        self,
        settle_s: np.ndarray | float,
        layers: Sequence[LayerSpec] = DEFAULT_LAYERS,
        t_ns: int = 0,
    ) -> None:
        names = [spec.name for spec in layers]
        if len(set(names)) != len(names):
            raise ValueError(f"layer names must be unique, got {names}")
        settled = [spec.settles for spec in layers]
        if any(settled[i + 1] and not settled[i] for i in range(len(settled) - 1)):
            raise ValueError(f"settled layers must form the bottom of the stack, got {names}")
        self.layers: tuple[LayerSpec, ...] = tuple(layers)
        self._spec = {spec.name: spec for spec in layers}
        self._poses: dict[str, np.ndarray] = {spec.name: dont_care_vector() for spec in layers if spec.settles}
        self._actions: dict[str, Action | None] = {spec.name: None for spec in layers if not spec.settles}
        self._sparse: dict[str, Callable[[int], SparseValues]] = {}  # the actions that say only what they care about
        self._settler = Settler(settle_s, t_ns=t_ns)
        self._trajectory_layers = tuple((spec.name, spec.blend) for spec in layers if not spec.settles)

    @property
    def layer_names(self) -> tuple[str, ...]:
        return tuple(spec.name for spec in self.layers)

    def _layer(self, name: str) -> LayerSpec:
        try:
            return self._spec[name]
        except KeyError:
            raise ValueError(f"unknown layer {name!r}; layers: {', '.join(self.layer_names)}") from None

    def set_pose(
        self,
        layer: str,
        pose: Pose | np.ndarray | None,
        t_ns: int,
        settle_s: np.ndarray | float | None = None,
    ) -> None:
        """Give a settled layer a new constant pose from t_ns (None = cares about nothing).

        Flexors whose composite target changes settle toward it from their value at t_ns, within
        `settle_s` (default: the per-flexor settle times).
        """
        spec = self._layer(layer)
        if not spec.settles:
            raise ValueError(f"layer {layer!r} takes actions (set_action), not settled poses")
        if pose is None:
            vector = dont_care_vector()
        else:
            vector = as_pose_vector(pose.values if isinstance(pose, Pose) else pose, f"pose for layer {layer!r}")
        self._poses[layer] = vector
        self._settler.retarget(self._settled_target(), t_ns, settle_s)

    def set_action(self, layer: str, action: Action | None) -> None:
        """Give a trajectory layer an action (None = cares about nothing); it is sampled at each frame."""
        spec = self._layer(layer)
        if spec.settles:
            raise ValueError(f"layer {layer!r} settles toward constant poses: use set_pose")
        if action is not None and not isinstance(action, Action):
            raise TypeError(f"layer {layer!r} needs an action with values_at(t_ns), got {action!r}")
        self._actions[layer] = action
        sparse_at = getattr(action, "sparse_at", None)
        if callable(sparse_at):
            self._sparse[layer] = sparse_at
        else:
            self._sparse.pop(layer, None)

    def pose(self, layer: str) -> np.ndarray:
        """The constant pose a settled layer holds (NaN = do not care)."""
        self._layer(layer)
        if layer not in self._poses:
            raise ValueError(f"layer {layer!r} holds an action, not a pose")
        return self._poses[layer].copy()

    def action(self, layer: str) -> Action | None:
        self._layer(layer)
        if layer not in self._actions:
            raise ValueError(f"layer {layer!r} holds a settled pose, not an action")
        return self._actions[layer]

    def _settled_target(self) -> np.ndarray:
        target = dont_care_vector()
        for spec in self.layers:
            if spec.settles:
                target = blend_onto(target, self._poses[spec.name], spec.blend)
        return np.nan_to_num(target, nan=0.0)  # nobody cares: the flexor relaxes

    @property
    def settler(self) -> Settler:
        """The settled layers' composite over time (read it; the layers' poses change it)."""
        return self._settler

    @property
    def top_action(self) -> Action | None:
        """The topmost layer's action (None for a settled layer, or a layer holding none)."""
        spec = self.layers[-1]
        return None if spec.settles else self._actions[spec.name]

    def compose(self, t_ns: int) -> np.ndarray:
        """Every flexor's value at t_ns, in [-1, 1]."""
        values = self._settler.value_at(t_ns)
        self.apply_trajectories(values, t_ns)
        np.maximum(values, FLEXOR_MIN, out=values)  # np.clip's Python wrapper costs more than both
        return np.minimum(values, FLEXOR_MAX, out=values)

    def apply_trajectories(self, values: np.ndarray, t_ns: int, below_top: bool = False) -> None:
        """The trajectory layers at t_ns onto `values` (the settled composite, or a row of many), in place, unclipped;
        with `below_top`, all but the topmost layer (a batch of many faces adds that one for all at once)."""
        # blend_onto, in place: the settled values hold no NaN and a replacing layer writes only values it
        # cares about, so the composite below each layer never does either, and an added layer simply adds
        # where it cares. Per frame this runs once per layer, where numpy's call overhead is the cost.
        if below_top and self.layers[-1].settles:
            raise ValueError(f"the top layer {self.layers[-1].name!r} settles: no trajectory layer to leave out")
        sparse = self._sparse
        layers = self._trajectory_layers[:-1] if below_top else self._trajectory_layers
        for name, blend in layers:
            action = self._actions[name]
            if action is None:
                continue
            if name in sparse:
                # the same arithmetic on the flexors the layer cares about, without a NaN vector and masks
                cared = sparse[name](t_ns)
                if cared is None:
                    continue
                index, value = cared
                if blend is Blend.ADD:
                    values[index] += value
                else:
                    values[index] = value
                continue
            layer = np.asarray(action.values_at(t_ns), dtype=np.float64)
            if layer.shape != (N_FLEXORS,):
                raise ValueError(f"layer {name!r} gave shape {layer.shape}, not ({N_FLEXORS},)")
            cares = layer == layer  # not NaN
            if blend is Blend.ADD:
                np.add(values, layer, out=values, where=cares)
            else:
                np.copyto(values, layer, where=cares)

    def frame_at(self, t_ns: int) -> FlexorFrame:
        return FlexorFrame.composed(self.compose(t_ns), t_ns)
