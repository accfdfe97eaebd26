"""`eca view`: show the face of a running instance, in a window or headless (video / PNG frames).

Attaches a renderer to the instance's bus like any other service; it picks a window where a display
exists and says which. Keys in the window send commands on the bus (see services/processes/renderer/window.py).
"""

from __future__ import annotations

import argparse
import sys

from eca.protocol.endpoints import BusConfigError, load_bus_config
from eca.services.processes.runtime import setup_logging


def register(sub: argparse._SubParsersAction) -> None:
    from eca.services.processes.renderer.options import options_parser

    p = sub.add_parser("view", parents=[options_parser()],
                       help="show the face of a running instance (window, or headless video/PNG)",
                       description="Show the face of a running instance: a window where a display exists, "
                                   "else headless (--video / --png write the frames).")
    p.add_argument("--config", default=None, help="runtime config (default configs/default.toml)")
    p.add_argument("--instance", default=None, help="bus instance name (default from the config)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from eca.services.processes.renderer.options import options_from_namespace
    from eca.services.processes.renderer.service import RendererService

    setup_logging("view")
    try:
        config = load_bus_config(args.config, args.instance)
        options = options_from_namespace(config, args)
    except (BusConfigError, ValueError) as exc:
        print(f"eca view: {exc}", file=sys.stderr)
        return 2
    service = RendererService(config, options)
    service.name = "view"
    return service.run()
