"""Running eca commands as child processes and reading their output line by line."""

from __future__ import annotations

import os
import site
import sys
import threading
import time
from pathlib import Path

PACKAGE_PARENT = Path(__file__).resolve().parents[3]  # the folder that holds the eca package


def eca_command(*args: str) -> list[str]:
    return [sys.executable, "-m", "eca.services.tools.cli", *args]


def subprocess_env() -> dict[str, str]:
    """The environment for a child eca process: unbuffered output, and this eca importable in it. An installed
    eca is found by the same interpreter anyway; a source tree (run without installing) is put on the path,
    behind what is there already."""
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    if not _is_site_dir(PACKAGE_PARENT):
        env["PYTHONPATH"] = os.pathsep.join(p for p in (env.get("PYTHONPATH", ""), str(PACKAGE_PARENT)) if p)
    return env


def _is_site_dir(folder: Path) -> bool:
    sites = [*site.getsitepackages(), site.getusersitepackages()]
    return any(folder == Path(s).resolve() for s in sites if s)


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
