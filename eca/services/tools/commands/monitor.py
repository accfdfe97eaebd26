"""`eca monitor`: print the live decoded traffic, filtered by agent and topic, errors highlighted."""

from __future__ import annotations

import argparse
import json
import sys
import time

import zmq

from eca.protocol.bus import BusTimeout, Received, Subscriber
from eca.protocol.endpoints import BusConfigError, load_bus_config
from eca.protocol.messages import Heartbeat, RigPose
from eca.protocol.topics import CATEGORIES
from eca.services.tools import cli_args


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("monitor", help="print live bus traffic")
    p.add_argument("--config", default=None)
    p.add_argument("--instance", default=None)
    p.add_argument("--agent", action="append", default=[], help="only this agent (repeatable)")
    p.add_argument("--topic", action="append", default=[], help="only topics with this prefix (repeatable)")
    p.add_argument("--heartbeats", action="store_true", help="show heartbeats too")
    p.add_argument("--json", action="store_true", help="one JSON object per line")
    p.add_argument("--count", type=cli_args.count, default=None, help="stop after this many messages")
    p.add_argument("--seconds", type=cli_args.seconds, default=None, help="stop after this long")
    p.set_defaults(func=run)


def prefixes(agents: list[str], topics: list[str]) -> list[str]:
    if topics:  # an agent filter on top is applied per message
        return topics
    if agents:
        return [f"{cat}.{a}." for a in agents for cat in CATEGORIES]
    return [""]


def run(args: argparse.Namespace) -> int:
    try:
        config = load_bus_config(args.config, args.instance)
    except BusConfigError as exc:
        print(f"eca monitor: {exc}", file=sys.stderr)
        return 2
    color = sys.stdout.isatty()
    ctx = zmq.Context()
    sub = Subscriber(ctx, config, prefixes(args.agent, args.topic))
    shown = 0
    try:
        try:
            early = sub.wait_ready(5.0)
        except BusTimeout as exc:
            print(f"eca monitor: {exc}", file=sys.stderr)
            return 1
        print(f"# monitoring {config.backend} (instance '{config.instance}')", flush=True)
        deadline = None if args.seconds is None else time.monotonic() + args.seconds
        pending = list(early)
        while args.count is None or shown < args.count:
            if deadline is not None and time.monotonic() > deadline:
                break
            got = pending.pop(0) if pending else sub.recv(0.1)
            if got is None or (isinstance(got.message, Heartbeat) and not args.heartbeats):
                continue
            if args.agent and got.message is not None and got.message.agent not in args.agent:
                continue
            print(format_line(got, args.json, color), flush=True)
            shown += 1
    except KeyboardInterrupt:
        pass
    finally:
        sub.close()
        ctx.term()
    return 0


def format_line(got: Received, as_json: bool, color: bool) -> str:
    if got.error is not None:
        if as_json:
            return json.dumps({"topic": got.topic, "invalid": str(got.error), "kind": got.error.kind})
        line = f"INVALID {got.topic}: {got.error}"
        return f"\033[31m{line}\033[0m" if color else line
    msg = got.message
    assert msg is not None
    body = {k: (v.hex() if isinstance(v, bytes) and len(v) <= 16 else f"<{len(v)} bytes>" if isinstance(v, bytes)
                else v) for k, v in vars(msg).items()}
    if as_json:
        return json.dumps({"topic": got.topic, **body})
    if isinstance(msg, RigPose):
        fields = rig_summary(msg)
    else:
        fields = " ".join(f"{k}={v}" for k, v in body.items() if k not in ("agent", "t_ns"))
    line = f"{msg.t_ns / 1e9:.3f} {got.topic} {fields}"
    if got.topic.startswith("error."):
        return f"\033[31mERROR {line}\033[0m" if color else f"ERROR {line}"
    return line


RIG_TOP = 3  # the strongest ARKit weights a rig frame's line shows


def rig_summary(msg: RigPose) -> str:
    """A rig frame in one short line: its time, head and eye angles, the strongest ARKit weights, the leading
    viseme and VRM emotion (not its 92 numbers; `--json` gives them all)."""
    from eca.agent.rig.names import ARKIT_NAMES, VISEME_NAMES, VRM_NAMES

    yaw, pitch, roll = msg.head_deg
    ly, lp, ry, rp = msg.eyes_deg
    top = sorted(range(len(msg.arkit)), key=lambda i: -msg.arkit[i])[:RIG_TOP]
    weights = " ".join(f"{ARKIT_NAMES[i]}={msg.arkit[i]:.2f}" for i in top if msg.arkit[i] >= 0.01) or "-"
    viseme = max(range(len(msg.visemes)), key=lambda i: msg.visemes[i])
    vrm = max(range(5), key=lambda i: msg.vrm[i])  # the five emotions lead VRM's list
    return (f"frame={msg.frame_ns / 1e9:.3f} head={yaw:+.1f}/{pitch:+.1f}/{roll:+.1f} "
            f"eyes=L{ly:+.1f}/{lp:+.1f},R{ry:+.1f}/{rp:+.1f} top {weights} "
            f"viseme {VISEME_NAMES[viseme]}={msg.visemes[viseme]:.2f} vrm {VRM_NAMES[vrm]}={msg.vrm[vrm]:.2f}")
