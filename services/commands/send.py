"""`eca send role|emotion|head|eyes|gaze|say|interrupt|user ...`: one command to a running instance.

Each waits for the result it should cause (the new state, or the say request's terminal event with
--wait) and prints it, or the dialogue service's error, so scripts can check the exit code.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

from agent.face.emotions import canonical_emotion_name
from protocol.bus import BusTimeout
from protocol.client import AgentClient, CommandRejected
from protocol.codec import ProtocolError
from protocol.endpoints import BusConfigError, load_bus_config
from protocol.messages import EmotionState, EyesState, GazeTargetState, HeadState, Message, RoleState
from services.tts import SpeechSynthesisError, synthesize


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("send", help="send one command to an agent of a running instance")
    p.add_argument("--config", default=None)
    p.add_argument("--instance", default=None)
    p.add_argument("--agent", default="ada")
    p.add_argument("--timeout", type=float, default=5.0, help="seconds to wait for the result")
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
    k = kinds.add_parser("eyes", help="eye mode: static, noise, saccade, saccade+blink")
    k.add_argument("mode", choices=["static", "noise", "saccade", "saccade+blink"])
    k = kinds.add_parser("gaze", help="where mutual gaze looks (degrees)")
    k.add_argument("--yaw", type=float, default=0.0)
    k.add_argument("--pitch", type=float, default=0.0)
    k.add_argument("--target", default="")
    k = kinds.add_parser("say", help="speak a sound file, or text through espeak-ng")
    src = k.add_mutually_exclusive_group(required=True)
    src.add_argument("--file", type=Path)
    src.add_argument("--text")
    k.add_argument("--wait", action="store_true", help="wait for the terminal lifecycle event")
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
    return 0


def _send(client: AgentClient, args: argparse.Namespace) -> Message | None:
    t = args.timeout
    if args.kind == "role":
        client.set_role(args.role, args.speaker)
        return client.expect_state(RoleState, lambda m: (m.role, m.speaker) == (args.role, args.speaker), t)
    if args.kind == "emotion":
        client.set_emotion(args.name, args.intensity, args.transition)
        # the whole answer: a cached state that merely shares the intensity must not pass for it
        asked = (canonical_emotion_name(args.name), args.intensity, args.transition)
        return client.expect_state(EmotionState, lambda m: (m.name, m.intensity, m.transition_s) == asked, t)
    if args.kind == "head":
        client.move_head(args.turn, args.nod, args.tilt, args.duration)
        return client.expect_state(HeadState, lambda m: (m.turn, m.nod, m.tilt) == (args.turn, args.nod, args.tilt), t)
    if args.kind == "eyes":
        client.set_eyes(args.mode)
        return client.expect_state(EyesState, lambda m: m.mode == args.mode, t)
    if args.kind == "gaze":
        client.set_gaze_target(args.yaw, args.pitch, args.target)
        return client.expect_state(
            GazeTargetState, lambda m: (m.yaw_deg, m.pitch_deg, m.target) == (args.yaw, args.pitch, args.target), t)
    if args.kind == "say":
        path = args.file
        if args.text is not None:
            path = synthesize(args.text, Path(tempfile.mkdtemp(prefix="eca-say-")) / "say.wav")
        elif not path.is_file():
            raise SpeechSynthesisError(f"{path}: no such file")
        rid = client.say(audio_path=str(Path(path).resolve()), text=args.text)
        print(f"request {rid} sent")
        return client.wait_for_speech(rid, timeout_s=max(t, 120.0)) if args.wait else None
    if args.kind == "interrupt":
        client.interrupt(args.request)
        return None
    client.user_speaking(args.state == "speaking")
    return client.expect_state(RoleState, lambda m: m.role == "listening", t) if args.state == "speaking" else None


def describe(msg: Message) -> str:
    body = {k: v for k, v in vars(msg).items() if k not in ("agent", "seq", "t_ns", "source")}
    fields = " ".join(f"{k}={v!r}" if isinstance(v, str) else f"{k}={v}" for k, v in body.items())
    return f"{msg.CATEGORY}.{msg.agent}.{msg.TYPE} {fields}"
