"""`eca check FILE...`: validate dialogue scripts and parameter files without playing anything."""

from __future__ import annotations

import argparse
import sys

from eca.agent.script import ScriptError, check_agent_id, load_script
from eca.services.tools.script_input import AGENT_HELP, sound_duration


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "check",
        help="validate dialogue scripts (XML) and parameter files",
        description="Parse each file as `eca play` would and print OK with a summary, or every problem of "
        "the file as file:line:column: message, in file order. Exit 0 when all files are valid, 1 otherwise.",
    )
    parser.add_argument("files", nargs="+", metavar="FILE", help="a dialogue (.xml) or parameter file")
    parser.add_argument("--agent", default=None, help=AGENT_HELP)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    try:
        check_agent_id(args.agent)
    except ValueError as exc:
        print(f"eca check: {exc}", file=sys.stderr)
        return 2
    failed = 0
    for path in args.files:
        try:
            # Audio is measured as the render and the audio service read it, so a file they cannot
            # play fails here too.
            script = load_script(path, agent=args.agent, duration_of=sound_duration)
        except ScriptError as exc:
            for problem in exc.errors:
                print(problem, file=sys.stderr)
            failed += 1
            continue
        print(f"{path}: OK: {script.summary}")
    return 1 if failed else 0
