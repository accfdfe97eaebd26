"""`eca up`: start the broker and the services, watch them, stop them all on Ctrl-C."""

from __future__ import annotations

import argparse
import sys

from protocol.endpoints import BusConfigError, load_bus_config
from services.up import choose_services, run_up


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("up", help="run the broker and the services of one instance")
    p.add_argument("--config", default=None, help="runtime config (default configs/default.toml)")
    p.add_argument("--instance", default=None, help="bus instance name (default from the config)")
    p.add_argument("--only", action="append", default=[], metavar="SERVICE", help="start only these")
    p.add_argument("--without", action="append", default=[], metavar="SERVICE", help="do not start these")
    p.add_argument("--quiet", action="store_true", help="no periodic bus summary")
    p.add_argument("--seconds", type=float, default=None, help="stop by itself after this long")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    try:
        config = load_bus_config(args.config, args.instance)
        services = choose_services(config, args.only, args.without)
    except (BusConfigError, ValueError) as exc:
        print(f"eca up: {exc}", file=sys.stderr)
        return 2
    return run_up(config, services, view=not args.quiet, duration_s=args.seconds)
