"""`eca send role|emotion|head|eyes|gaze|say|interrupt|user ...`: one command to a running instance.

Each waits for the dialogue service's acknowledgement of that very command (by its request id, never a
value the cache happens to hold) and prints the state it caused; `say --wait` waits on for the
request's terminal event. Exit codes: 0 applied (with --wait: spoken to the end), 1 refused, not
answered in time, interrupted or failed, 2 bad arguments or config.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from agent.script import DEFAULT_AGENT
from agent.vocabulary import EYE_MODES
from protocol.bus import BusTimeout
from protocol.client import AgentClient, CommandRejected
from protocol.codec import ProtocolError
from protocol.endpoints import BusConfigError, load_bus_config
from protocol.messages import Message, Say, SpeechFinished
from services import cli_args
from services.tts import SpeechSynthesisError


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("send", help="send one command to an agent of a running instance")
    p.add_argument("--config", default=None)
    p.add_argument("--instance", default=None)
    p.add_argument("--agent", default=DEFAULT_AGENT, help=f"the agent to drive (default {DEFAULT_AGENT!r})")
    p.add_argument("--timeout", type=cli_args.seconds, default=5.0,
                   help="seconds to wait for the acknowledgement (default 5)")
    kinds = p.add_subparsers(dest="kind", metavar="KIND", required=True)
    k = kinds.add_parser("role", help="talking, listening or silence")
    k.add_argument("role", choices=["talking", "listening", "silence"])
    k.add_argument("--speaker", default="")
    k = kinds.add_parser("emotion", help="an emotion with intensity and transition time")
    k.add_argument("name")
    k.add_argument("--intensity", type=float, default=1.0)
    k.add_argument("--transition", type=float, default=0.5, help="seconds")
    k = kinds.add_parser("head", help="head turn/nod/tilt targets in [-1, 1]")
    k.add_argument("--turn", type=float, default=0.0)
    k.add_argument("--nod", type=float, default=0.0)
    k.add_argument("--tilt", type=float, default=0.0)
    k.add_argument("--duration", type=float, default=0.5, help="seconds")
    k = kinds.add_parser("eyes", help=f"eye mode: {', '.join(EYE_MODES)}")
    k.add_argument("mode", choices=EYE_MODES)
    k = kinds.add_parser("gaze", help="where mutual gaze looks (degrees)")
    k.add_argument("--yaw", type=float, default=0.0)
    k.add_argument("--pitch", type=float, default=0.0)
    k.add_argument("--target", default="")
    k = kinds.add_parser("say", help="speak a sound file, or text (voiced by the instance's text-to-speech)")
    src = k.add_mutually_exclusive_group(required=True)
    src.add_argument("--file", type=Path)
    src.add_argument("--text")
    k.add_argument("--wait", action="store_true",
                   help="wait for the terminal lifecycle event; exit 1 unless it is speech_finished")
    k = kinds.add_parser("interrupt", help="stop the agent's speech")
    k.add_argument("--request", default="", help="one request id (default: all)")
    k = kinds.add_parser("user", help="the user starts (or stops) speaking: barge-in")
    k.add_argument("state", choices=["speaking", "quiet"])
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    try:
        config = load_bus_config(args.config, args.instance)
        with AgentClient(config, agent=args.agent, source="eca-send", timeout_s=args.timeout) as client:
            result = _send(client, args)
    except (BusConfigError, ProtocolError, SpeechSynthesisError) as exc:
        print(f"eca send: {exc}", file=sys.stderr)
        return 2
    except CommandRejected as exc:
        print(f"eca send: rejected: {exc}", file=sys.stderr)
        return 1
    except BusTimeout as exc:
        print(f"eca send: {exc}", file=sys.stderr)
        return 1
    if result is not None:
        print(describe(result))
        if args.kind == "say" and not isinstance(result, SpeechFinished):
            return 1  # interrupted or failed: not what was asked
    return 0


def _send(client: AgentClient, args: argparse.Namespace) -> Message | None:
    """Send the command, wait for its acknowledgement; the state it caused (or the say's ending)."""
    t = args.timeout
    if args.kind == "say":
        rid = client.new_request_id()
        if args.text is not None:  # spoken by the instance's own text-to-speech engine: works from anywhere
            say = Say(agent=client.agent, request_id=rid, text=args.text)
        elif args.file.is_dir():
            raise SpeechSynthesisError(f"{args.file}: is a directory, not a sound file")
        elif not args.file.is_file():
            raise SpeechSynthesisError(f"{args.file}: no such file")
        else:
            say = Say(agent=client.agent, request_id=rid, audio_path=str(args.file.resolve()))
        client.wait_applied(client.send(say), t)
        print(f"request {rid} accepted")
        return client.wait_for_speech(rid, timeout_s=max(t, 120.0)) if args.wait else None
    sent = {
        "role": lambda: client.set_role(args.role, args.speaker),
        "emotion": lambda: client.set_emotion(args.name, args.intensity, args.transition),
        "head": lambda: client.move_head(args.turn, args.nod, args.tilt, args.duration),
        "eyes": lambda: client.set_eyes(args.mode),
        "gaze": lambda: client.set_gaze_target(args.yaw, args.pitch, args.target),
        "interrupt": lambda: client.interrupt(args.request),
        "user": lambda: client.user_speaking(args.state == "speaking"),
    }[args.kind]()
    client.wait_applied(sent, t)
    # the state the command caused came before its acknowledgement (same publisher, in order)
    caused = {"role": "role", "emotion": "emotion", "head": "head", "eyes": "eyes", "gaze": "gaze_target",
              "user": "role"}.get(args.kind)
    return client.state.get(caused) if caused and (args.kind != "user" or args.state == "speaking") else None


def describe(msg: Message) -> str:
    body = {k: v for k, v in vars(msg).items() if k not in ("agent", "seq", "t_ns", "source")}
    fields = " ".join(f"{k}={v!r}" if isinstance(v, str) else f"{k}={v}" for k, v in body.items())
    return f"{msg.CATEGORY}.{msg.agent}.{msg.TYPE} {fields}"
