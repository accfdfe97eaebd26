"""The drawing seam: a `FaceDrawer` draws a composed face (agent/face/composed.py) into a framebuffer, and
`make_drawer` makes one by kind. Every output that shows a face (the window, headless video and PNGs, the
web service's video track, the pipecat face, the offline renders and stills) draws through this seam, so a
new kind of face plugs in here (a class and a line in DRAWERS) and nowhere else.

The first kind is the 2D flexor face ("flexor"): the cartoon face of the paper's flexors, drawn by
`Renderer` (renderer.py) from the composed face's flexor frame.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

import moderngl
import numpy as np

from eca.agent.face.composed import ComposedFace
from eca.services.processes.renderer.config import RenderConfig
from eca.services.processes.renderer.renderer import Renderer, RenderToggles


class FaceDrawer(Protocol):
    """Draws composed faces. `view` is "full" or "upper" (the paper's upper face); `toggles` the visual
    switches a window's keys set (a kind honours those that mean something for it); `trail` recent gaze as
    (look_x, look_y) flexor rows, oldest first, drawn as the pupils' path where the toggles say so."""

    size: tuple[int, int]

    def draw(self, face: ComposedFace, target: moderngl.Framebuffer | None = None, *, view: str = "full",
             toggles: RenderToggles | None = None, trail: np.ndarray | None = None) -> moderngl.Framebuffer:
        """Draw `face` into `target` (None: the drawer's own offscreen target); the framebuffer drawn into."""
        ...

    def release(self) -> None:
        """Free the drawer's GL objects."""
        ...


class FlexorFaceDrawer:
    """The 2D flexor face: `Renderer` draws the composed face's flexor frame."""

    def __init__(self, ctx: moderngl.Context, size: tuple[int, int], config: RenderConfig | None = None) -> None:
        self.renderer = Renderer(ctx, size=size, config=config)
        self.size = self.renderer.size

    def draw(self, face: ComposedFace, target: moderngl.Framebuffer | None = None, *, view: str = "full",
             toggles: RenderToggles | None = None, trail: np.ndarray | None = None) -> moderngl.Framebuffer:
        return self.renderer.render(face.flexors, target=target, view=view, toggles=toggles, overlay_points=trail)

    def release(self) -> None:
        self.renderer.release()


DrawerFactory = Callable[[moderngl.Context, tuple[int, int]], FaceDrawer]
DRAWERS: dict[str, DrawerFactory] = {"flexor": FlexorFaceDrawer}


def make_drawer(ctx: moderngl.Context, size: tuple[int, int], kind: str = "flexor") -> FaceDrawer:
    """A drawer of `kind` (one of DRAWERS) on `ctx`, drawing pictures of `size`; ValueError for an unknown
    kind, naming the known ones."""
    try:
        factory = DRAWERS[kind]
    except KeyError:
        raise ValueError(f"unknown face kind {kind!r}; known: {', '.join(sorted(DRAWERS))}") from None
    return factory(ctx, size)
