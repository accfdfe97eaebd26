"""Helper processes of the benches' viewers, on a host (tests/support/netns.py), driven by lines on their stdin:
each prints "ready N" once its N viewers receive, snapshots its counts on "mark", and prints its report (one JSON
line) on "stop". bench/_scale_janus.py and bench/janus_faces.py run their viewers so."""

from __future__ import annotations

import json
import re
import subprocess
from pathlib import Path
from typing import Any

from bench.procs import descendants

REPO = Path(__file__).resolve().parent.parent


class WorkerProcesses:
    """Worker processes on a host, driven by lines on their stdin: each prints "ready N" once its N viewers receive,
    snapshots its counts on "mark", and prints its report (one JSON line) on "stop"."""

    def __init__(self, host: Any, argvs: list[list[str]]) -> None:
        self.procs: list[subprocess.Popen[str]] = [
            host.popen(argv, cwd=REPO, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                       text=True) for argv in argvs]

    @property
    def pids(self) -> list[int]:
        return [pid for proc in self.procs for pid in [proc.pid, *descendants(proc.pid)]]

    def wait_ready(self) -> int:
        ready = 0
        for proc in self.procs:
            assert proc.stdout is not None
            line = proc.stdout.readline()  # the worker's first line, once its viewers receive (or it failed)
            match = re.match(r"ready (\d+)", line)
            if match is None:
                raise RuntimeError(f"a viewer process did not connect ({proc.poll()})")
            ready += int(match.group(1))
        return ready

    def say(self, line: str) -> None:
        for proc in self.procs:
            assert proc.stdin is not None
            proc.stdin.write(line + "\n")
            proc.stdin.flush()

    def finish(self) -> list[dict[str, Any]]:
        self.say("stop")
        out = []
        for proc in self.procs:
            stdout, _ = proc.communicate(timeout=60)
            lines = [line for line in stdout.splitlines() if line.startswith("{")]
            if lines:
                out.append(json.loads(lines[-1]))
        return out

    def kill(self) -> None:
        for proc in self.procs:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
