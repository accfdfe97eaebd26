"""Drawing the face with moderngl: the seam every kind of face plugs in at (drawer.py: `FaceDrawer`,
`make_drawer`), the stage that draws agents side by side (stage.py), the canvases and outputs a process draws
into (context.py, outputs.py, window.py, video.py, yuv.py), and the first kind of face: the 2D flexor face
(renderer.py, with its geometry in geometry.py, outline.py, curves.py and poser.py, its shaders and compiled
kernels). Other processes use the names exported here; what composes the face without GL lives in
eca/services/processes/scene/.

The names load lazily, each from its module when first asked for: a process that names the seam, checks a
face or opens a canvas does not load the 2D face's compiled drawing code (numba, some 80 MB with LLVM) until
it makes a `Renderer`, which is when it is about to draw."""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from eca.services.processes.renderer.common import RenderToggles
    from eca.services.processes.renderer.config import RenderConfig, load_render_config
    from eca.services.processes.renderer.context import (
        HeadlessContextError,
        create_headless_context,
        create_offscreen_target,
        read_rgb,
    )
    from eca.services.processes.renderer.drawer import DRAWERS, FaceDrawer, FlexorFaceDrawer, make_drawer
    from eca.services.processes.renderer.faces import Drawers, agent_faces, check_face
    from eca.services.processes.renderer.head.camera import avatar_framing
    from eca.services.processes.renderer.outputs import OffscreenCanvas
    from eca.services.processes.renderer.renderer import Renderer
    from eca.services.processes.renderer.stage import Stage
    from eca.services.processes.renderer.yuv import YuvTarget

# name -> the module (in this package) that defines it
_EXPORTS: dict[str, str] = {
    "DRAWERS": "drawer",
    "Drawers": "faces",
    "FaceDrawer": "drawer",
    "FlexorFaceDrawer": "drawer",
    "HeadlessContextError": "context",
    "OffscreenCanvas": "outputs",
    "RenderConfig": "config",
    "RenderToggles": "common",
    "Renderer": "renderer",
    "Stage": "stage",
    "YuvTarget": "yuv",
    "agent_faces": "faces",
    "avatar_framing": "head.camera",
    "check_face": "faces",
    "create_headless_context": "context",
    "create_offscreen_target": "context",
    "load_render_config": "config",
    "make_drawer": "drawer",
    "read_rgb": "context",
}

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
    "avatar_framing",
    "check_face",
    "create_headless_context",
    "create_offscreen_target",
    "load_render_config",
    "make_drawer",
    "read_rgb",
]  # the keys of _EXPORTS


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{module}"), name)
    globals()[name] = value  # found once: later lookups do not come here
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_EXPORTS})
