"""Drawing the face with moderngl: the seam every kind of face plugs in at (drawer.py: `FaceDrawer`,
`make_drawer`), the stage that draws agents side by side (stage.py), the canvases and outputs a process draws
into (context.py, outputs.py, window.py, video.py, yuv.py), and the first kind of face: the 2D flexor face
(renderer.py, with its geometry in geometry.py, outline.py, curves.py and poser.py, its shaders and compiled
kernels). Other processes use the names exported here; what composes the face without GL lives in
eca/services/processes/scene/."""

from eca.services.processes.renderer.config import RenderConfig, load_render_config
from eca.services.processes.renderer.context import (
    HeadlessContextError,
    create_headless_context,
    create_offscreen_target,
    read_rgb,
)
from eca.services.processes.renderer.drawer import DRAWERS, FaceDrawer, FlexorFaceDrawer, make_drawer
from eca.services.processes.renderer.faces import Drawers, agent_faces, check_face
from eca.services.processes.renderer.outputs import OffscreenCanvas
from eca.services.processes.renderer.renderer import Renderer, RenderToggles
from eca.services.processes.renderer.stage import Stage
from eca.services.processes.renderer.yuv import YuvTarget

__all__ = [
    "DRAWERS",
    "Drawers",
    "FaceDrawer",
    "FlexorFaceDrawer",
    "HeadlessContextError",
    "OffscreenCanvas",
    "RenderConfig",
    "RenderToggles",
    "Renderer",
    "Stage",
    "YuvTarget",
    "agent_faces",
    "check_face",
    "create_headless_context",
    "create_offscreen_target",
    "load_render_config",
    "make_drawer",
    "read_rgb",
]
