"""Whether a window can be tried, told from the environment alone: the supervisor asks it before it starts a
renderer, so it loads nothing (window.py loads glfw and GL)."""

from __future__ import annotations

import os


def display_available() -> bool:
    """Whether a window can be tried: an X11 or Wayland display is named in the environment."""
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
