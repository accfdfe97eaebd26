"""The cartoon face renderer: procedural geometry, cel shading and outlines with moderngl."""

from eca.services.processes.renderer.config import RenderConfig, load_render_config
from eca.services.processes.renderer.context import (
    HeadlessContextError,
    create_headless_context,
    create_offscreen_target,
    read_rgb,
)
from eca.services.processes.renderer.renderer import Renderer, RenderToggles

__all__ = [
    "HeadlessContextError",
    "RenderConfig",
    "RenderToggles",
    "Renderer",
    "create_headless_context",
    "create_offscreen_target",
    "load_render_config",
    "read_rgb",
]
