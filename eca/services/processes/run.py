"""`python -m eca.services.processes.run NAME`: start one eca service as its own fresh interpreter."""

from __future__ import annotations

import argparse
import importlib
import logging
import sys

from eca.protocol.endpoints import BusConfigError, load_bus_config
from eca.services.processes.heap import bound_heap, freeze_startup_objects
from eca.services.processes.realtime import ask_for_realtime, realtime_settings
from eca.services.processes.runtime import one_maths_thread, setup_logging
from eca.services.processes.web.options import MAX_WORKERS, worker_of  # names only: no web stack

# name -> "module:class"; a module is imported only when its service is started.
SERVICES: dict[str, str] = {
    "dialogue": "eca.services.processes.dialogue:DialogueService",
    "gaze": "eca.services.processes.gaze:GazeService",
    "audio": "eca.services.processes.audio.service:AudioService",
    "renderer": "eca.services.processes.renderer.service:RendererService",
    "web": "eca.services.processes.web.service:WebService",
    "rig": "eca.services.processes.rig.service:RigService",
    "bml": "eca.services.processes.bml.service:BmlService",
}


KNOWN = ("broker", *SERVICES)  # what [realtime] services may name


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m eca.services.processes.run")
    parser.add_argument("name", help=f"broker, {', '.join(SERVICES)}, or web-2 ... web-{MAX_WORKERS} (the web "
                                     "service's further workers)")
    parser.add_argument("--config", default=None, help="runtime config (default configs/default.toml)")
    parser.add_argument("--instance", default=None, help="bus instance name")
    parser.add_argument("--parent-pid", type=int, default=None, help="stop when this process is gone")
    parser.add_argument("--liveness", default=None, metavar="ENDPOINT",
                        help="also send heartbeats straight to the supervisor listening here")
    args, extra = parser.parse_known_args(argv)
    service_key = args.name
    worker = worker_of(args.name)
    if worker is not None and worker > 1:  # a further web worker: the web service, told which one it is
        service_key, extra = "web", [*extra, "--web-worker", str(worker)]
    if service_key != "broker" and service_key not in SERVICES:
        parser.error(f"unknown service {args.name!r}; known: broker, {', '.join(SERVICES)}, web-2 ... "
                     f"web-{MAX_WORKERS}")
    one_maths_thread()  # before any service module loads numpy
    bound_heap()  # before the bus: a flood's large messages must not stay resident afterwards
    setup_logging(args.name)
    try:
        config = load_bus_config(args.config, args.instance)
        realtime = realtime_settings(config, KNOWN)
    except BusConfigError as exc:
        print(f"[{args.name}] ERROR {exc}", file=sys.stderr)
        return 2
    scheduling = ask_for_realtime(service_key, realtime)  # before the service makes a thread: they inherit it
    if scheduling is not None:
        logging.getLogger(args.name).info("%s", scheduling)
    if args.name == "broker":
        from eca.services.processes.broker import run_broker

        if extra:
            print(f"[broker] ERROR unknown arguments: {' '.join(extra)}", file=sys.stderr)
            return 2
        return run_broker(config, args.parent_pid, args.liveness)
    module_name, class_name = SERVICES[service_key].split(":")
    service_cls = getattr(importlib.import_module(module_name), class_name)
    common = {"parent_pid": args.parent_pid, "liveness": args.liveness}
    if hasattr(service_cls, "from_args"):
        service = service_cls.from_args(config, extra, **common)
    elif extra:
        print(f"[{args.name}] ERROR unknown arguments: {' '.join(extra)}", file=sys.stderr)
        return 2
    else:
        service = service_cls(config, **common)
    return service.run(on_ready=freeze_startup_objects)


if __name__ == "__main__":
    sys.exit(main())
