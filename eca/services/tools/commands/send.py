"""`eca send role|emotion|head|eyes|gaze|say|interrupt|user ...`: one command to a running instance.

Each waits for the dialogue service's acknowledgement of that very command (by its request id, never a
value the cache happens to hold) and prints the state it caused; `say --wait` waits on for the
request's terminal event. Exit codes: 0 applied (with --wait: spoken to the end), 1 refused, not
answered in time, interrupted or failed, 2 bad arguments or config.
"""

from __future__ import annotations

import argparse
import sys
import typing
from pathlib import Path
from typing import Any, Literal

from eca.agent.script import DEFAULT_AGENT
from eca.agent.vocabulary import EYE_MODES
from eca.protocol.bus import BusTimeout
from eca.protocol.client import AgentClient, CommandRejected
from eca.protocol.codec import FieldSpec, ProtocolError, field_specs
from eca.protocol.endpoints import BusConfigError, load_bus_config
from eca.protocol.messages import (
    ENVELOPE_FIELDS,
    Message,
    MoveHead,
    Say,
    SetEmotion,
    SetEyes,
    SetGazeTarget,
    SetRole,
    SpeechFinished,
    StateCommand,
)
from eca.services.processes.audio.tts import SpeechSynthesisError
from eca.services.tools import cli_args


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("send", help="send one command to an agent of a running instance")
    p.add_argument("--config", default=None)
    p.add_argument("--instance", default=None)
    p.add_argument("--agent", default=DEFAULT_AGENT, help=f"the agent to drive (default {DEFAULT_AGENT!r})")
    p.add_argument("--timeout", type=cli_args.seconds, default=5.0,
                   help="seconds to wait for the acknowledgement (default 5)")
    kinds = p.add_subparsers(dest="kind", metavar="KIND", required=True)
    for verb, (cls, help_text) in STATE_VERBS.items():
        _add_state_verb(kinds.add_parser(verb, help=help_text), cls)
    k = kinds.add_parser("say", help="speak a sound file, or text (voiced by the instance's text-to-speech)")
    src = k.add_mutually_exclusive_group(required=True)
    src.add_argument("--file", type=Path)
    src.add_argument("--text")
    k.add_argument("--to", nargs="+", default=[], metavar="WHO",
                   help="who it is said to: other agents of the instance and/or 'user' (default everyone)")
    k.add_argument("--wait", action="store_true",
                   help="wait for the terminal lifecycle event; exit 1 unless it is speech_finished")
    k = kinds.add_parser("interrupt", help="stop the agent's speech")
    k.add_argument("--request", default="", help="one request id (default: all)")
    k = kinds.add_parser("user", help="the user starts (or stops) speaking: barge-in")
    k.add_argument("state", choices=["speaking", "quiet"])
    p.set_defaults(func=run)


# The verbs that set a state, with their command; each verb's arguments are made from the command's
# fields (docs/protocol.md): required fields positional, the others `--name` (a unit suffix dropped:
# `transition_s` is `--transition`), with the field's type, choices, default and limits.
STATE_VERBS: dict[str, tuple[type[StateCommand], str]] = {
    "role": (SetRole, "talking, listening or silence"),
    "emotion": (SetEmotion, "an emotion with intensity and transition time"),
    "head": (MoveHead, "head turn/nod/tilt targets in [-1, 1]"),
    "eyes": (SetEyes, f"eye mode: {', '.join(EYE_MODES)}"),
    "gaze": (SetGazeTarget, "where mutual gaze looks (degrees)"),
}


def option_name(field: str) -> str:
    for unit in ("_deg", "_s"):
        if field.endswith(unit):
            field = field[: -len(unit)]
    return field.replace("_", "-")


def _command_fields(cls: type[StateCommand]) -> list[FieldSpec]:
    return [s for s in field_specs(cls) if s.name not in ENVELOPE_FIELDS and s.name != "request_id"]


def _add_state_verb(parser: argparse.ArgumentParser, cls: type[StateCommand]) -> None:
    for spec in _command_fields(cls):
        doc = cls.__dataclass_fields__[spec.name].metadata.get("doc", "")
        kwargs: dict[str, Any] = {"help": doc, "dest": spec.name}
        if typing.get_origin(spec.kind) is Literal:
            kwargs["choices"] = typing.get_args(spec.kind)
        elif spec.kind is float:
            kwargs["type"] = cli_args.bounded_float(spec.lo, spec.hi)
        if spec.required:
            kwargs.pop("dest")
            parser.add_argument(spec.name, **kwargs)
        else:
            default = cls.__dataclass_fields__[spec.name].default
            parser.add_argument(f"--{option_name(spec.name)}", default=default, **kwargs)


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
            say = Say(agent=client.agent, request_id=rid, text=args.text, to=args.to)
        elif args.file.is_dir():
            raise SpeechSynthesisError(f"{args.file}: is a directory, not a sound file")
        elif not args.file.is_file():
            raise SpeechSynthesisError(f"{args.file}: no such file")
        else:
            say = Say(agent=client.agent, request_id=rid, audio_path=str(args.file.resolve()), to=args.to)
        client.wait_applied(client.send(say), t)
        print(f"request {rid} accepted")
        return client.wait_for_speech(rid, timeout_s=max(t, 120.0)) if args.wait else None
    if args.kind in STATE_VERBS:
        cls = STATE_VERBS[args.kind][0]
        sent = client.command(cls, **{spec.name: getattr(args, spec.name) for spec in _command_fields(cls)})
        caused: str | None = cls.STATE.TYPE
    elif args.kind == "interrupt":
        sent, caused = client.interrupt(args.request), None
    else:
        sent = client.user_speaking(args.state == "speaking")
        caused = "role" if args.state == "speaking" else None
    client.wait_applied(sent, t)
    # the state the command caused came before its acknowledgement (same publisher, in order)
    return client.state.get(caused) if caused else None


def describe(msg: Message) -> str:
    body = {k: v for k, v in vars(msg).items() if k not in ("agent", "seq", "t_ns", "source")}
    fields = " ".join(f"{k}={v!r}" if isinstance(v, str) else f"{k}={v}" for k, v in body.items())
    return f"{msg.CATEGORY}.{msg.agent}.{msg.TYPE} {fields}"
