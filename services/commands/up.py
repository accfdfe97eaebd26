"""`eca up`: start the broker and the services, watch them, stop them all on Ctrl-C."""

from __future__ import annotations

import argparse
import sys

from protocol.endpoints import BusConfigError, load_bus_config
from services import cli_args
from services.up import choose_services, run_up


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("up", help="run the broker and the services of one instance")
    p.add_argument("--config", default=None, help="runtime config (default configs/default.toml)")
    p.add_argument("--instance", default=None, help="bus instance name (default from the config)")
    p.add_argument("--only", action="append", default=[], metavar="SERVICE", help="start only these")
    p.add_argument("--without", action="append", default=[], metavar="SERVICE", help="do not start these")
    p.add_argument("--quiet", action="store_true", help="no periodic bus summary")
    p.add_argument("--seconds", type=cli_args.seconds, default=None, help="stop by itself after this long")
    face = p.add_argument_group("renderer", "passed to the renderer (it picks a window where a display exists)")
    face.add_argument("--headless", action="store_true", help="render offscreen (EGL) even where a display exists")
    face.add_argument("--window", action="store_true", help="require a window (fail without a display)")
    face.add_argument("--video", default=None, metavar="PATH", help="headless: write the face as an H.264 MP4")
    face.add_argument("--png", default=None, metavar="DIR", help="headless: write PNG frames")
    face.add_argument("--size", default=None, metavar="WxH", help="window or image size")
    face.add_argument("--fps", type=float, default=None, help="frames per second")
    face.add_argument("--view", choices=("full", "upper"), default=None, help="full face or upper face only")
    p.set_defaults(func=run)


def renderer_args(args: argparse.Namespace) -> list[str]:
    """The renderer's command-line arguments among `eca up`'s."""
    argv = [f"--{flag}" for flag in ("headless", "window") if getattr(args, flag)]
    for name in ("video", "png", "size", "fps", "view"):
        value = getattr(args, name)
        if value is not None:
            argv += [f"--{name}", str(value)]
    return argv


def run(args: argparse.Namespace) -> int:
    face_argv = renderer_args(args)
    try:
        config = load_bus_config(args.config, args.instance)
        services = choose_services(config, args.only, args.without)
        if face_argv:
            if "renderer" not in services:
                raise ValueError(f"renderer options ({' '.join(face_argv)}) given, but the renderer is not started")
            from services.renderer.service import options_from  # GL and video libraries load only here

            options_from(config, face_argv)  # bad options fail here, before anything starts
    except (BusConfigError, ValueError) as exc:
        print(f"eca up: {exc}", file=sys.stderr)
        return 2
    return run_up(config, services, view=not args.quiet, duration_s=args.seconds,
                  extra_args={"renderer": face_argv})
