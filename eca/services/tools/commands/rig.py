"""`eca rig`: send the agents of a running instance to the avatar programs people run, as rig weights.

Attaches a rig service to the instance's bus like any other service (`eca up --rig-vmc ... --rig-livelink ...`
starts one with the rest): each agent's face at the rig rate as ARKit, VRM and viseme weights with head and eye
angles, on the bus (`stream.<agent>.rig`), to a VMC receiver (VSeeFace, Warudo, VMagicMirror, EVMC4U, VMC4B) and to
Unreal's Live Link Face source. Every option is checked, and every receiver's host resolved, before it connects.
"""

from __future__ import annotations

import argparse
import sys

from eca.protocol.endpoints import BusConfigError, load_bus_config
from eca.services.processes.runtime import setup_logging


def register(sub: argparse._SubParsersAction) -> None:
    from eca.services.processes.rig.options import add_arguments

    p = sub.add_parser("rig", help="send the agents of a running instance to VMC and Live Link receivers",
                       description="Send each agent's face, retargeted onto ARKit's blendshapes, VRM's presets and "
                                   "head and eye angles, to a VMC receiver (VSeeFace, Warudo, VMagicMirror: "
                                   "--vmc) and to Unreal's Live Link Face source (--livelink), and on the bus as "
                                   "stream.<agent>.rig.")
    p.add_argument("--config", default=None, help="runtime config (default configs/default.toml)")
    p.add_argument("--instance", default=None, help="bus instance name (default from the config)")
    add_arguments(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from eca.services.processes.rig.options import RigOptionsError, flag_names, given, options_from, plan
    from eca.services.processes.rig.service import RigService

    setup_logging("rig")
    try:
        config = load_bus_config(args.config, args.instance)
        cli = given(args)
        options = options_from(dict(config.raw.get("rig", {})), cli)
        service = RigService(config, plan(options, config.agents, flag_names(cli, where=f"{config.config_path} [rig]")))
    except (BusConfigError, RigOptionsError) as exc:
        print(f"eca rig: {exc}", file=sys.stderr)
        return 2
    return service.run()
