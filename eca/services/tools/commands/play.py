"""`eca play SCRIPT...`: publish a script's timeline in real time to a running instance."""

from __future__ import annotations

import argparse
import sys
import time

from eca.agent.script import ScriptError
from eca.protocol.bus import BusTimeout
from eca.protocol.client import AgentClient
from eca.protocol.codec import ProtocolError, encode
from eca.protocol.endpoints import BusConfigError, load_bus_config
from eca.services.processes.audio.tts import SpeechSynthesisError
from eca.services.tools.playback import CueTranslator
from eca.services.tools.script_input import AGENT_HELP, load_run, open_voices, print_failure


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("play", help="replay scripts over the bus to a running instance, or send it BML blocks")
    p.add_argument("scripts", nargs="+", help="dialogue XML and/or parameter files, or BML blocks (.bml, one after "
                                              "the other, each waited for; needs the bml service: eca up --bml)")
    p.add_argument("--config", default=None)
    p.add_argument("--instance", default=None)
    p.add_argument("--agent", default=None, help=AGENT_HELP)
    p.add_argument("--speed", type=float, default=1.0, help="playback speed factor (2 = twice as fast)")
    p.add_argument("--no-voice", action="store_true", help="do not speak lines that have only text")
    p.add_argument("--timeout", type=float, default=120.0, help="BML: seconds to wait for each block's end")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    bml = [path.lower().endswith(".bml") for path in args.scripts]
    if any(bml):
        if not all(bml):
            print("eca play: BML blocks (.bml) play on their own, not mixed with dialogue scripts", file=sys.stderr)
            return 2
        from eca.services.tools.bml_play import play_bml

        return play_bml(args)
    if not 0.05 <= args.speed <= 100:
        print(f"eca play: --speed {args.speed} must lie in [0.05, 100]", file=sys.stderr)
        return 2
    voices = open_voices("play", args.no_voice)
    try:
        config = load_bus_config(args.config, args.instance)
        loaded = load_run(args.scripts, args.agent, voices)
    except (ScriptError, BusConfigError, SpeechSynthesisError, ValueError) as exc:
        print_failure("play", exc, "nothing played")
        return 1
    timeline, agent = loaded.timeline, loaded.agent
    # Every command is made and checked before the first is sent: a cue the protocol refuses (an id or a
    # text over its limit) must stop the script before it starts, not half-way through.
    translator = CueTranslator(agent, voices)
    plan = []
    for cue in timeline.cues:
        try:
            commands = translator.commands(cue)
            for msg in commands:
                encode(msg, config.max_message_bytes)
        except ProtocolError as exc:
            print(f"eca play: the {type(cue).__name__[:-3].lower()} cue at {cue.t_s:.2f} s cannot be sent: {exc}",
                  file=sys.stderr)
            return 1
        plan.append((cue, commands))
    try:
        with AgentClient(config, agent=agent, source="eca-play") as client:
            print(f"playing {len(timeline.cues)} cues for {agent}, {timeline.length_s:.1f} s", flush=True)
            start = time.monotonic()
            for cue, commands in plan:
                due = start + cue.t_s / args.speed
                while (left := due - time.monotonic()) > 0:
                    time.sleep(min(left, 0.05))
                for msg in commands:
                    client.send(msg)
                print(f"{cue.t_s:7.2f} s  {type(cue).__name__[:-3].lower():8s} {_describe(cue)}", flush=True)
            end = start + timeline.length_s / args.speed
            while (left := end - time.monotonic()) > 0:
                time.sleep(min(left, 0.05))
    except (BusTimeout, ProtocolError) as exc:
        print(f"eca play: {exc}", file=sys.stderr)
        return 1
    print("done", flush=True)
    return 0


def _describe(cue: object) -> str:
    fields = {k: v for k, v in vars(cue).items() if k not in ("t_s",) and v is not None}
    return " ".join(f"{k}={v}" for k, v in fields.items())
