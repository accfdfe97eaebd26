"""`eca`: one console script; each subcommand lives in its own module under services/tools/commands/."""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys

from eca.services.tools import commands


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The parser of every command, or with `only` (a command's module name) of that one alone: a command's
    module imports what it runs (GL, video, plotting), and a long-running `eca up` must not carry all of that
    (about 130 MB) for commands it never runs."""
    parser = argparse.ArgumentParser(prog="eca", description="A live conversational-agent face.")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
        if only is not None and info.name != only:
            continue
        try:
            module = importlib.import_module(f"{commands.__name__}.{info.name}")
        except Exception as exc:  # one broken command must not take every other command down
            _register_broken(sub, info.name, exc)
            continue
        module.register(sub)
    return parser


def _register_broken(sub: argparse._SubParsersAction, name: str, exc: Exception) -> None:
    p = sub.add_parser(name.replace("_", "-"), help=f"(unavailable: {type(exc).__name__})")

    def fail(_: argparse.Namespace) -> int:
        print(f"eca {name}: this command cannot load: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 1

    p.set_defaults(func=fail)


def main(argv: list[str] | None = None) -> int:
    words = sys.argv[1:] if argv is None else argv
    named = words[0].replace("-", "_") if words and not words[0].startswith("-") else None
    known = {info.name for info in pkgutil.iter_modules(commands.__path__)}
    parser = build_parser(named if named in known else None)  # help and mistakes: every command
    args = parser.parse_args(words)
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:
        return 0


if __name__ == "__main__":
    sys.exit(main())
