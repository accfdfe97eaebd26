"""`eca check FILE...`: validate dialogue scripts and parameter files without playing anything."""

from __future__ import annotations

import argparse
import sys

from agent.script import DEFAULT_AGENT, ScriptError, load_script


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "check",
        help="validate dialogue scripts (XML) and parameter files",
        description="Parse each file as `eca play` would and print OK with a summary, or each error as "
        "file:line:column: message. Exit 0 when all files are valid, 1 otherwise.",
    )
    parser.add_argument("files", nargs="+", metavar="FILE", help="a dialogue (.xml) or parameter file")
    parser.add_argument("--agent", default=DEFAULT_AGENT, help="agent id parameter files drive "
                        f"(default {DEFAULT_AGENT!r})")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    failed = 0
    for path in args.files:
        try:
            script = load_script(path, agent=args.agent)
        except ScriptError as exc:
            print(exc, file=sys.stderr)
            failed += 1
            continue
        print(f"{path}: OK: {script.summary}")
    return 1 if failed else 0
