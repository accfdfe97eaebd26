"""The stage: every drawn agent's face composed for one display time, and drawn side by side.

Composing asks each agent's live scene for its face at the frame's display time (a ComposedFace) and keeps
the recent gaze for the trajectory overlay; drawing gives each agent its own viewport of one FaceDrawer,
turned toward the others (a staging turn added when drawing only: the composed faces stay each agent's own).
"""

from __future__ import annotations

from collections.abc import Sequence

import moderngl
import numpy as np

from eca.agent.face.composed import ComposedFace
from eca.agent.face.flexors import FLEXOR_INDEX
from eca.agent.face.settings import load_flexor_units
from eca.services.processes.renderer.common import RenderToggles
from eca.services.processes.renderer.drawer import FaceDrawer
from eca.services.processes.scene.bus_scene import AgentView

_TURN = FLEXOR_INDEX["turn"]
_LOOK = [FLEXOR_INDEX["look_x"], FLEXOR_INDEX["look_y"]]


class Stage:
    """Draws `views` left to right in the order given, each with its drawer: `drawers` one for all, or one per
    view (agents of one instance may have different faces: renderer/faces.py).

    fps and trail_s size the trajectory overlay (trail_s of frames); facing_turn is the staging turn
    of side-by-side agents (flexor units)."""

    def __init__(self, drawers: FaceDrawer | Sequence[FaceDrawer], views: Sequence[AgentView], *, fps: float,
                 facing_turn: float = 0.0, trail_s: float = 1.0) -> None:
        self.views = list(views)
        self.drawers = list(drawers) if isinstance(drawers, Sequence) else [drawers] * len(self.views)
        if len(self.drawers) != len(self.views):
            raise ValueError(f"{len(self.drawers)} drawers for {len(self.views)} agents")
        self.facing_turn = facing_turn
        self.trail_len = max(2, round(trail_s * fps))
        self.units = load_flexor_units()

    def compose(self, display_ns: int) -> list[ComposedFace]:
        """Every agent's face at display time display_ns (each view's `face` and `trail` follow)."""
        faces = []
        for v in self.views:
            face = v.scene.compose(display_ns)
            v.scene.prune(display_ns)
            v.face = face
            v.trail.append((float(face.flexors[_LOOK[0]]), float(face.flexors[_LOOK[1]])))
            while len(v.trail) > self.trail_len:
                v.trail.popleft()
            faces.append(face)
        return faces

    def draw(self, faces: Sequence[ComposedFace], target: moderngl.Framebuffer, *, view: str = "full",
             toggles: RenderToggles | None = None) -> None:
        """Draw the agents side by side into target (each in its own viewport, turned toward the other).

        toggles: the drawer's switches (None: its defaults); the gaze trail is drawn where they say so."""
        x0, y0, width, height = target.viewport
        n = len(faces)
        for i, (v, face, drawer) in enumerate(zip(self.views, faces, self.drawers, strict=True)):
            if n > 1:
                # The agent on the left turns to its left (the screen's right) to face the other.
                side = -1.0 if i < n / 2 else 1.0
                values = np.array(face.flexors)
                values[_TURN] = float(np.clip(values[_TURN] + side * self.facing_turn, -1.0, 1.0))
                face = face.with_flexors(values, self.units)
            region = (x0 + i * width // n, y0, (i + 1) * width // n - i * width // n, height)
            target.viewport = region
            target.scissor = region
            trail = np.array(v.trail) if toggles is not None and toggles.trajectory and len(v.trail) >= 2 else None
            drawer.draw(face, target, view=view, toggles=toggles, trail=trail)
        target.viewport = (x0, y0, width, height)
        target.scissor = None
