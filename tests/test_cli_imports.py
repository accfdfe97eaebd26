"""A command loads only its own module: a long-running `eca up` (one per instance, one per pipecat session)
must not carry the GL, video and plotting libraries of commands it never runs."""

from __future__ import annotations

import subprocess
import sys

from eca.services.tools.child_processes import subprocess_env

PROBE = """
import sys
from eca.services.tools import cli
try:
    cli.main({argv!r})
except SystemExit:
    pass
heavy = sorted(m for m in ("moderngl", "numba", "matplotlib", "PIL", "av", "aiortc") if m in sys.modules)
print("HEAVY", ",".join(heavy))
"""


def loaded_by(argv: list[str]) -> set[str]:
    done = subprocess.run([sys.executable, "-c", PROBE.format(argv=argv)], capture_output=True, text=True,
                          env=subprocess_env(), timeout=120)
    line = next(line for line in done.stdout.splitlines() if line.startswith("HEAVY"))
    return set(filter(None, line.removeprefix("HEAVY").strip().split(",")))


def test_up_and_send_load_no_drawing_video_or_plotting_library() -> None:
    assert loaded_by(["up", "--help"]) == set()
    assert loaded_by(["send", "--help"]) == set()


def test_the_whole_help_still_lists_every_command() -> None:
    done = subprocess.run([sys.executable, "-m", "eca.services.tools.cli", "--help"], capture_output=True, text=True,
                          env=subprocess_env(), timeout=120)
    assert done.returncode == 0
    assert all(name in done.stdout for name in ("up", "send", "snapshot", "render", "warm-up", "web"))
