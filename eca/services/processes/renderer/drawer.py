"""The drawing seam: a `FaceDrawer` draws a composed face (agent/face/composed.py) into a framebuffer, and
`make_drawer` makes one by kind. Every output that shows a face (the window, headless video and PNGs, the
web service's video track, the pipecat face, the offline renders and stills) draws through this seam, so a
new kind of face plugs in here (a class and a line in DRAWERS) and nowhere else.

The first kind is the 2D flexor face ("flexor"): the cartoon face of the paper's flexors, drawn by
`Renderer` (renderer.py) from the composed face's flexor frame. The second is a 3D avatar (head/: `HeadDrawer`):
"head" is the default head (eca/assets/default_head.glb), and any .glb, .gltf or .vrm file's path is a kind too.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Protocol, TypeAlias

if TYPE_CHECKING:  # names for the hints only: a process that merely chooses a face loads no GL or drawing code
    import moderngl
    import numpy as np

    from eca.agent.face.composed import ComposedFace
    from eca.services.processes.renderer.common import RenderToggles
    from eca.services.processes.renderer.config import RenderConfig


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
        # Imported here: the 2D face's compiled drawing code (numba, and LLVM under it: some 80 MB) loads when a
        # process first makes one, which is when it is about to draw, never because it named the seam.
        from eca.services.processes.renderer.renderer import Renderer

        self.renderer = Renderer(ctx, size=size, config=config)
        self.size = self.renderer.size

    def draw(self, face: ComposedFace, target: moderngl.Framebuffer | None = None, *, view: str = "full",
             toggles: RenderToggles | None = None, trail: np.ndarray | None = None) -> moderngl.Framebuffer:
        return self.renderer.render(face.flexors, target=target, view=view, toggles=toggles, overlay_points=trail)

    def release(self) -> None:
        self.renderer.release()


def default_head_drawer(ctx: moderngl.Context, size: tuple[int, int]) -> FaceDrawer:
    """The default 3D head (imported here, so the 2D face's users never load the 3D drawer)."""
    from eca.services.processes.renderer.head import HeadDrawer

    return HeadDrawer.default(ctx, size)


def avatar_drawer(ctx: moderngl.Context, size: tuple[int, int], path: str | Path) -> FaceDrawer:
    """A 3D drawer of the avatar in a .glb, .gltf or .vrm file."""
    from eca.services.processes.renderer.head import HeadDrawer

    return HeadDrawer(ctx, size, path)


DrawerFactory: TypeAlias = "Callable[[moderngl.Context, tuple[int, int]], FaceDrawer]"
DRAWERS: dict[str, DrawerFactory] = {"flexor": FlexorFaceDrawer, "head": default_head_drawer}
AVATAR_SUFFIXES = (".glb", ".gltf", ".vrm")


def make_drawer(ctx: moderngl.Context, size: tuple[int, int], kind: str = "flexor") -> FaceDrawer:
    """A drawer of `kind` on `ctx`, drawing pictures of `size`: one of DRAWERS, or the path of an avatar file
    (.glb, .gltf, .vrm). ValueError for an unknown kind, naming the known ones."""
    factory = DRAWERS.get(kind)
    if factory is not None:
        return factory(ctx, size)
    if Path(kind).suffix.lower() in AVATAR_SUFFIXES:
        return avatar_drawer(ctx, size, kind)
    raise ValueError(f"unknown face kind {kind!r}; known: {', '.join(sorted(DRAWERS))}, or the path of a "
                     f"{'/'.join(AVATAR_SUFFIXES)} file")
