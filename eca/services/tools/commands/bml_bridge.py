"""`eca bml-bridge --stomp HOST:PORT`: BML blocks from an ActiveMQ broker (AsapRealizer's, Greta's and the Virtual
Human Toolkit's topics) to the agents of a running instance, and the realizer's feedback back
(eca/services/processes/bml_bridge.py says what goes where).

Exit codes: 0 stopped (Ctrl-C, SIGTERM), 1 no instance answered, 2 bad arguments or config (one line saying which).
"""

from __future__ import annotations

import argparse
import sys

from eca.protocol.codec import is_agent_id
from eca.protocol.endpoints import BusConfigError, load_bus_config


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("bml-bridge", help="bridge BML over ActiveMQ (AsapRealizer, Greta, VHMsg) to the agents",
                       description="Forward BML blocks from an ActiveMQ broker's STOMP connector to the agents' "
                                   "realizer, and its feedback back: AsapRealizer's asap.bml.request/feedback, "
                                   "Greta's greta.BML, the Virtual Human Toolkit's vrAgentBML lines.")
    # No `required=True` or `type=` here: a bad value is said in one line by `run`, not with argparse's usage.
    p.add_argument("--stomp", default=None, metavar="HOST:PORT", help="the broker's STOMP connector (required)")
    p.add_argument("--user", default=None, help="STOMP login (default: none)")
    p.add_argument("--password", default=None, help="STOMP passcode (default: none)")
    p.add_argument("--agent", default=None,
                   help="the agent of a block that names none (default: the config's first agent)")
    p.add_argument("--topics", default="asap,greta,vhmsg", metavar="LIST",
                   help="which transports to bridge, comma-separated (default asap,greta,vhmsg)")
    p.add_argument("--vhmsg-scope", default="DEFAULT_SCOPE", metavar="SCOPE",
                   help="the VHMsg scope: its ActiveMQ topic and ELVISH_SCOPE (default DEFAULT_SCOPE)")
    p.add_argument("--config", default=None, help="runtime config (default configs/default.toml)")
    p.add_argument("--instance", default=None, help="bus instance name (default from the config)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from eca.services.processes.bml_bridge import BmlBridge, BridgeOptions, parse_host_port, parse_transports
    from eca.services.processes.runtime import setup_logging

    def bad(text: str) -> int:
        print(f"eca bml-bridge: {text}", file=sys.stderr)
        return 2

    if not args.stomp:
        return bad("--stomp HOST:PORT is required (the ActiveMQ broker's STOMP connector, e.g. 127.0.0.1:61613)")
    try:
        host, port = parse_host_port(args.stomp)
        transports = parse_transports(args.topics)
        config = load_bus_config(args.config, args.instance)
    except (ValueError, BusConfigError) as exc:
        return bad(str(exc))
    agent = args.agent if args.agent is not None else config.agents[0]
    if not is_agent_id(agent) or agent == "*":
        return bad(f"--agent {agent!r} is not an agent id (1-32 letters, digits, '_' or '-')")
    scope = args.vhmsg_scope.strip()
    if not scope or any(c in scope for c in " /,*>\n"):
        return bad(f"--vhmsg-scope {args.vhmsg_scope!r} is not a topic name")
    try:
        import stomp  # type: ignore[import-untyped]  # noqa: F401 (checked here, used by the bridge)
    except ImportError:
        return bad("the stomp.py package is missing (pip install stomp.py)")
    setup_logging("bml-bridge")
    options = BridgeOptions(host=host, port=port, agent=agent, transports=transports, user=args.user,
                            password=args.password, vhmsg_scope=scope)
    return BmlBridge(config, options).run()
