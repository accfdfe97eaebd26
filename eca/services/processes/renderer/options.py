"""The renderer's options: the config's [renderer] table, overridden on the command line.

Shared by every process that draws the live face (the renderer service, `eca view`, `eca up`'s checks
of renderer arguments), so the same names mean the same thing everywhere and a bad value fails with
the same sentence.
"""

from __future__ import annotations

import argparse
import math
import shlex
from dataclasses import dataclass, replace
from typing import Any

from eca.protocol.endpoints import BusConfig
from eca.services.processes.renderer.faces import agent_faces, check_face

MODES = ("auto", "window", "headless")


@dataclass
class RendererOptions:
    agents: tuple[str, ...] = ()  # empty: every agent of the instance ([agents] ids)
    fps: float = 60.0
    size: tuple[int, int] = (640, 480)
    view: str = "full"
    mode: str = "auto"  # auto: a window where a display exists, else headless
    idle_noise: bool = True
    seed: int = 0
    video: str | None = None  # headless: write an H.264 MP4 here
    png_dir: str | None = None  # headless: write PNG frames here
    png_every: int = 1
    seconds: float | None = None  # stop after this long (the length of a video)
    frames: int | None = None  # stop after this many frame slots
    progress: bool = True  # a progress bar when the length is known
    lead_s: float = 0.0  # display time = slot time + lead (a window's presentation delay)
    # staging turn of side-by-side agents toward each other (flexor units): 0, since the conversation itself
    # turns each head toward the person it attends (docs/gaze.md, "Who looks at whom")
    facing_turn: float = 0.0
    trail_s: float = 1.0  # length of the saccade trajectory overlay
    vsync: bool = True
    publish_frames: bool = True
    face: str | None = None  # --face for every agent (None: the config's [faces], else the 2D face: faces.py)

    def check(self) -> RendererOptions:
        if not (1.0 <= self.fps <= 240.0):
            raise ValueError(f"fps must lie in [1, 240], got {self.fps}")
        if self.view not in ("full", "upper"):
            raise ValueError(f"view must be full or upper, got {self.view!r}")
        if self.mode not in MODES:
            raise ValueError(f"mode must be one of {', '.join(MODES)}, got {self.mode!r}")
        w, h = self.size
        if not (16 <= w <= 8192 and 16 <= h <= 8192):
            raise ValueError(f"size must lie between 16x16 and 8192x8192, got {w}x{h}")
        if self.seconds is not None and self.seconds <= 0:
            raise ValueError(f"seconds must be positive, got {self.seconds}")
        if self.frames is not None and self.frames <= 0:
            raise ValueError(f"frames must be positive, got {self.frames}")
        if self.mode == "window" and (self.video or self.png_dir):
            raise ValueError("video and PNG output are headless features: add --headless")
        return self

    @property
    def total_slots(self) -> int | None:
        slots = [
            n
            for n in (self.frames, None if self.seconds is None else math.ceil(self.seconds * self.fps))
            if n is not None
        ]
        return min(slots) if slots else None

    def agent_ids(self, config: BusConfig) -> list[str]:
        """The agents drawn: those named here, else every agent of the instance."""
        return list(self.agents or config.agents)

    @classmethod
    def from_table(cls, table: dict[str, Any]) -> RendererOptions:
        """Options from a config's [renderer] table (unknown keys are an error naming them)."""
        names = {f.name for f in cls.__dataclass_fields__.values()} | {"width", "height", "headless"}
        unknown = set(table) - names
        if unknown:
            raise ValueError(f"[renderer]: unknown keys {sorted(unknown)}")
        values = {k: v for k, v in table.items() if k not in ("width", "height", "headless")}
        if "agents" in values:
            values["agents"] = tuple(values["agents"])
        opts = cls(**values)
        if "width" in table or "height" in table:
            opts.size = (int(table.get("width", opts.size[0])), int(table.get("height", opts.size[1])))
        if table.get("headless"):
            opts.mode = "headless"
        return opts


def options_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="renderer", add_help=False)
    p.add_argument("--agent", action="append", default=None, help="draw this agent (repeat for side by side)")
    p.add_argument("--fps", type=float, default=None, help="frame rate (default 60)")
    p.add_argument("--size", default=None, metavar="WxH", help="window or image size (default 640x480)")
    p.add_argument("--view", choices=("full", "upper"), default=None, help="full face or upper face only")
    p.add_argument("--headless", action="store_true", help="render offscreen (EGL) even where a display exists")
    p.add_argument("--window", action="store_true", help="require a window (fail without a display)")
    p.add_argument("--no-idle", action="store_true", help="no idle noise (exact, repeatable frames)")
    p.add_argument("--seed", type=int, default=None, help="idle-noise seed")
    p.add_argument("--video", default=None, metavar="PATH", help="headless: write an H.264 MP4")
    p.add_argument("--png", default=None, metavar="DIR", help="headless: write PNG frames")
    p.add_argument("--png-every", type=int, default=None, metavar="N", help="only every Nth frame as PNG")
    p.add_argument("--seconds", type=float, default=None, help="stop after this long")
    p.add_argument("--frames", type=int, default=None, help="stop after this many frames")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--lead-ms", type=float, default=None, help="display time ahead of the frame slot")
    p.add_argument("--face", default=None, metavar="FACE",
                   help="the face of every agent: flexor (the paper's 2D face), head (eca's 3D head) or a "
                        ".glb/.gltf/.vrm file (default: the config's [faces], else flexor)")
    return p


def parse_size(text: str) -> tuple[int, int]:
    try:
        w, h = text.lower().split("x")
        return int(w), int(h)
    except ValueError:
        raise ValueError(f"size must look like 640x480, got {text!r}") from None


def options_from(config: BusConfig, argv: list[str]) -> RendererOptions:
    """The config's [renderer] table overridden by command-line arguments; ValueError names the problem."""
    args, unknown = options_parser().parse_known_args(argv)
    if unknown:
        raise ValueError(f"unknown renderer arguments: {shlex.join(unknown)}")
    return options_from_namespace(config, args)


def options_from_namespace(config: BusConfig, args: argparse.Namespace) -> RendererOptions:
    opts = RendererOptions.from_table(dict(config.raw.get("renderer", {})))
    if args.headless and args.window:
        raise ValueError("--headless and --window exclude each other")
    changes: dict[str, Any] = {}
    if args.agent:
        changes["agents"] = tuple(args.agent)
    for name in ("fps", "view", "seed", "video", "seconds", "frames", "png_every"):
        if getattr(args, name) is not None:
            changes[name] = getattr(args, name)
    if args.size is not None:
        changes["size"] = parse_size(args.size)
    if args.png is not None:
        changes["png_dir"] = args.png
    if args.headless:
        changes["mode"] = "headless"
    if args.window:
        changes["mode"] = "window"
    if args.no_idle:
        changes["idle_noise"] = False
    if args.no_progress:
        changes["progress"] = False
    if args.lead_ms is not None:
        changes["lead_s"] = args.lead_ms / 1000.0
    if args.face is not None:
        changes["face"] = check_face(args.face, "--face")
    options = replace(opts, **changes).check()
    agent_faces(config.raw, options.agent_ids(config), options.face)  # a bad [faces] table fails here
    return options
