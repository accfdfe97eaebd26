"""Where the loop draws (a canvas) and where each drawn frame goes (outputs).

A canvas is a GL context and the framebuffer the next frame is drawn into: a window (window.py) or an
offscreen EGL target. An output is told of every frame once the stage has drawn it, through one method,
`present(frame)`: the window shows it, a file writer reads its pixels back, a headless renderer that
only publishes face frames waits for the GPU. Any number of outputs share one canvas, and a new one
(another process's, say) needs nothing of the loop but a place in its list.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol

import moderngl
import numpy as np

from eca.services.processes.renderer.context import create_headless_context, create_offscreen_target, read_rgb
from eca.services.processes.renderer.video import FrameSink, PngWriter, VideoWriter

if TYPE_CHECKING:
    from eca.services.processes.renderer.options import RendererOptions
    from eca.services.processes.renderer.window import Window


@dataclass
class DrawnFrame:
    """One frame as the outputs see it, just drawn."""

    target: moderngl.Framebuffer  # the frame is in this framebuffer's viewport
    index: int  # its frame slot: slot k is due k / fps after the schedule began (schedule.py)
    display_ns: int  # the display time it was composed for (bus clock, ns); its face frames carry it too
    _rgb: np.ndarray | None = field(default=None, init=False, repr=False)

    def rgb(self) -> np.ndarray:
        """The frame's pixels, (H, W, 3) uint8, top row first. Read back from the GPU once however many
        outputs ask, so every output gets the same array: one that changes it must copy it first."""
        if self._rgb is None:
            self._rgb = read_rgb(self.target)
        return self._rgb


class Output(Protocol):
    def present(self, frame: DrawnFrame) -> None:
        """Called once per drawn frame, in slot order (skipped slots never come), on the loop's thread
        with the canvas's GL context current. Read the pixels with `frame.rgb()`."""

    def close(self) -> None:
        """Called once after the last frame; a failure is logged, and the other outputs still close."""


class Canvas(Protocol):
    ctx: moderngl.Context

    @property
    def screen(self) -> moderngl.Framebuffer:
        """The framebuffer to draw the next frame into, its viewport the whole of it."""

    def close(self) -> None:
        """Release the context (after every output has closed)."""


class OffscreenCanvas:
    """A headless EGL context and one offscreen framebuffer of a fixed size."""

    def __init__(self, size: tuple[int, int]) -> None:
        self.ctx = create_headless_context()
        self.target = create_offscreen_target(self.ctx, size)

    @property
    def screen(self) -> moderngl.Framebuffer:
        return self.target

    def close(self) -> None:
        self.ctx.release()


class WindowOutput:
    """Shows frames in a window (the canvas they were drawn on), with a help line along the bottom."""

    def __init__(self, window: Window, help_line: Callable[[], str]) -> None:
        self.window = window
        self.help_line = help_line

    def present(self, frame: DrawnFrame) -> None:
        self.window.draw_text_line(frame.target, self.help_line())
        self.window.swap()

    def close(self) -> None:
        """Nothing: the window is the canvas, which the loop closes last."""


class SinkOutput:
    """A frame sink (an H.264 file, PNG files, see video.py) fed each frame's pixels and slot."""

    def __init__(self, sink: FrameSink) -> None:
        self.sink = sink

    @property
    def name(self) -> str:
        return type(self.sink).__name__

    def present(self, frame: DrawnFrame) -> None:
        self.sink.write(frame.rgb(), frame.index)

    def close(self) -> None:
        self.sink.close()


class FinishOutput:
    """Nothing but the face frames on the bus: each frame waits for the GPU to finish drawing it, so the
    frame costs its time within its own slot (as a read-back would), never in a queue of GL commands."""

    def __init__(self, ctx: moderngl.Context) -> None:
        self.ctx = ctx

    def present(self, frame: DrawnFrame) -> None:
        self.ctx.finish()

    def close(self) -> None:
        pass


def file_outputs(options: RendererOptions) -> list[Output]:
    """The headless files the options ask for: an H.264 video and/or PNG frames."""
    outputs: list[Output] = []
    if options.video:
        outputs.append(SinkOutput(VideoWriter(options.video, options.fps, options.size)))
    if options.png_dir:
        outputs.append(SinkOutput(PngWriter(options.png_dir, options.png_every)))
    return outputs


def output_name(output: Output) -> str:
    """How logs name an output: its `name` where it has one, else its class."""
    return str(getattr(output, "name", type(output).__name__))
