"""Running eca commands as child processes and reading their output line by line."""

from __future__ import annotations

import os
import sys
import threading
import time
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[2]


def eca_command(*args: str) -> list[str]:
    return [sys.executable, "-m", "services.tools.cli", *args]


def subprocess_env() -> dict[str, str]:
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    env["PYTHONPATH"] = str(REPO_ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    return env


class LineReader:
    """Collects a child's output lines in a thread, so tests can wait for a line with a timeout."""

    def __init__(self, stream: object) -> None:
        self.lines: list[str] = []
        self._cond = threading.Condition()
        self._thread = threading.Thread(target=self._pump, args=(stream,), daemon=True)
        self._thread.start()

    def _pump(self, stream: object) -> None:
        for raw in iter(stream.readline, b""):  # type: ignore[attr-defined]
            with self._cond:
                self.lines.append(raw.decode("utf-8", "replace").rstrip("\n"))
                self._cond.notify_all()

    def wait_for(self, needle: str, timeout_s: float, start: int = 0) -> int:
        """Index of the first line from `start` on that contains `needle`; TimeoutError if none comes."""
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while True:
                for i in range(start, len(self.lines)):
                    if needle in self.lines[i]:
                        return i
                left = deadline - time.monotonic()
                if left <= 0:
                    tail = "\n".join(self.lines[-30:])
                    raise TimeoutError(f"no line containing {needle!r} within {timeout_s} s; last lines:\n{tail}")
                self._cond.wait(left)
