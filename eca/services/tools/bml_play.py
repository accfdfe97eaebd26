"""`eca play FILE.bml...`: each block sent to the agent's realizer as a `bml` command, its feedback printed as it
comes (the standard's elements), until the block's end; then the next file."""

from __future__ import annotations

import argparse
import sys
import time

from eca.protocol.bus import BusTimeout
from eca.protocol.client import AgentClient
from eca.protocol.codec import ProtocolError
from eca.protocol.endpoints import BusConfigError, load_bus_config
from eca.protocol.messages import Bml, BmlFeedback, Error, Message
from eca.services.tools.bml_files import read_bml


def play_bml(args: argparse.Namespace) -> int:
    if not 1.0 <= args.timeout <= 3600.0:
        print(f"eca play: --timeout {args.timeout} must lie in [1, 3600] s", file=sys.stderr)
        return 2
    try:
        config = load_bus_config(args.config, args.instance)
        texts = [(path, read_bml(path)) for path in args.scripts]  # all read before the first is sent
    except (BusConfigError, ValueError) as exc:
        print(f"eca play: {exc}; nothing played", file=sys.stderr)
        return 1
    agent = args.agent or config.agents[0]
    try:
        with AgentClient(config, agent=agent, source="eca-play") as client:
            for path, text in texts:
                if not _play_one(client, agent, path, text, args.timeout):
                    return 1
    except (BusTimeout, ProtocolError) as exc:
        print(f"eca play: {exc}", file=sys.stderr)
        return 1
    print("done", flush=True)
    return 0


def _play_one(client: AgentClient, agent: str, path: str, text: str, timeout_s: float) -> bool:
    rid = client.new_request_id()
    client.send(Bml(agent=agent, request_id=rid, xml=text))

    def ours(m: Message) -> bool:
        return isinstance(m, Error | BmlFeedback) and getattr(m, "request_id", "") == rid

    deadline = time.monotonic() + timeout_s
    while (left := deadline - time.monotonic()) > 0:
        try:
            msg = client.wait_for(ours, min(0.5, left))
        except BusTimeout:
            continue
        if isinstance(msg, Error):
            print(f"eca play: {path}: refused: {msg.reason}", file=sys.stderr)
            return False
        assert isinstance(msg, BmlFeedback)
        print(f"{path}: {msg.xml}", flush=True)
        if msg.kind == "blockProgress" and msg.sync == "end":
            return True
    print(f"eca play: {path}: no end of the block within {timeout_s:g} s", file=sys.stderr)
    return False
