"""`eca web`: serve the live agent of a running instance to browsers, over WebRTC.

Attaches a web service to the instance's bus like any other service (`eca up --web` starts one with
the rest): open the address it prints, see and hear the agent, speak to it.
"""

from __future__ import annotations

import argparse
import logging
import sys

from eca.protocol.endpoints import BusConfigError, load_bus_config
from eca.services.processes.runtime import setup_logging


def register(sub: argparse._SubParsersAction) -> None:
    from eca.services.processes.web.options import add_arguments

    p = sub.add_parser("web", help="serve the agents of a running instance to browsers (WebRTC)",
                       description="Serve a page where a browser sees and hears the agents of a running "
                                   "instance and speaks to them, over WebRTC.")
    p.add_argument("--config", default=None, help="runtime config (default configs/default.toml)")
    p.add_argument("--instance", default=None, help="bus instance name (default from the config)")
    add_arguments(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from eca.services.processes.realtime import ask_for_realtime, realtime_settings
    from eca.services.processes.run import KNOWN
    from eca.services.processes.web.options import WebOptionsError, options_from
    from eca.services.processes.web.service import WebService

    setup_logging("web")
    try:
        config = load_bus_config(args.config, args.instance)
        realtime = realtime_settings(config, KNOWN)
        options = options_from(dict(config.raw.get("web", {})), args)
        if options.workers > 1:
            raise WebOptionsError(f"{options.workers} web workers are started by `eca up --web` (one process each); "
                                  "`eca web` is one process: give --web-workers 1")
        service = WebService(config, options)
    except (BusConfigError, WebOptionsError) as exc:
        print(f"eca web: {exc}", file=sys.stderr)
        return 2
    # as `eca up`'s web service, once it can start (a start that fails says one line): every thread so far, and
    # those it makes from now on
    scheduling = ask_for_realtime("web", realtime)
    if scheduling is not None:
        logging.getLogger("web").info("%s", scheduling)
    return service.run()
