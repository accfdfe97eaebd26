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
        "the file as file:line:column: message, in file order. A .bml file is a BML block: parsed, voiced and "
        "scheduled as the realizer would, its timeline printed. Exit 0 when all files are valid, 1 otherwise.",
    )
    parser.add_argument("files", nargs="+", metavar="FILE",
                        help="a dialogue (.xml), parameter file or BML block (.bml)")
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
        if path.lower().endswith(".bml"):
            failed += not _check_bml(path)
            continue
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


def _check_bml(path: str) -> bool:
    """A BML block (.bml): parsed, its speech voiced and scheduled as the realizer would; its warnings and
    timeline printed."""
    from eca.services.tools.bml_files import BmlError, check_bml, describe

    try:
        block, timeline = check_bml(path)
    except (BmlError, ValueError) as exc:
        print(str(exc), file=sys.stderr)
        return False
    for warning in block.warnings:
        print(f"{path}:{warning.line}: warning {warning.type}: {warning.text}", file=sys.stderr)
    print(f"{path}: OK: {describe(block, timeline)}")
    for t, behaviour, sync in timeline.in_order():
        print(f"  {t:7.3f} s  {behaviour}:{sync}")
    return True
