"""Headless OpenGL contexts, offscreen framebuffers and pixel read-back."""

from __future__ import annotations

import threading

import moderngl
import numpy as np


class HeadlessContextError(RuntimeError):
    """No offscreen OpenGL context could be made; the message says why and what to install."""


def create_headless_context(require: int = 330) -> moderngl.Context:
    """An offscreen OpenGL context through EGL (no display needed).

    EGL must be asked for explicitly: moderngl's default standalone backend is X11, which needs a display.
    """
    try:
        return moderngl.create_standalone_context(backend="egl", require=require)
    except Exception as exc:  # moderngl raises plain Exception subclasses that vary by version
        raise HeadlessContextError(
            f"cannot create a headless OpenGL {require // 100}.{require % 100 // 10} context through EGL: "
            f"{exc}. On Debian/Ubuntu install libegl1 and libgl1-mesa-dri."
        ) from exc


def create_offscreen_target(ctx: moderngl.Context, size: tuple[int, int]) -> moderngl.Framebuffer:
    """A colour + depth framebuffer of `size` (width, height) to render into and read back."""
    width, height = check_size(size)
    color = ctx.renderbuffer((width, height), components=4)
    depth = ctx.depth_renderbuffer((width, height))
    return ctx.framebuffer(color_attachments=[color], depth_attachment=depth)


def check_size(size: tuple[int, int]) -> tuple[int, int]:
    try:
        width, height = (int(v) for v in size)
    except (TypeError, ValueError):
        raise ValueError(f"an image size is (width, height), got {size!r}") from None
    if not (1 <= width <= 16384 and 1 <= height <= 16384):
        raise ValueError(f"image size must be between 1x1 and 16384x16384 pixels, got {width}x{height}")
    return width, height


def read_rgb(fbo: moderngl.Framebuffer) -> np.ndarray:
    """The framebuffer's colour as an (H, W, 3) uint8 array, top row first (GL reads bottom row first)."""
    x, y, width, height = fbo.viewport
    # Reading into a reused buffer skips allocating (and page-faulting) a fresh bytes object per frame,
    # which costs about as much as the read itself at 640x480; the flip then makes the caller's copy.
    scratch = _scratch(width * height * 3)
    fbo.read_into(scratch, viewport=(x, y, width, height), components=3, alignment=1)
    rows = np.frombuffer(scratch, dtype=np.uint8, count=width * height * 3).reshape(height, width, 3)
    return rows[::-1].copy()


_buffers = threading.local()


def _scratch(nbytes: int) -> bytearray:
    """A per-thread read-back buffer of at least nbytes (each thread may drive its own GL context)."""
    buf: bytearray | None = getattr(_buffers, "rgb", None)
    if buf is None or len(buf) < nbytes:
        buf = bytearray(nbytes)
        _buffers.rgb = buf
    return buf
