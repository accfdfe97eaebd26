"""An eca instance started for a pipeline: `eca up` in the background, stopped with it.

`EcaInstance.start()` runs `eca up --only dialogue --only gaze --only audio --quiet --silent-audio` (the
broker comes with it; no renderer, no web service: the pipeline draws the face itself; no sound card: the
pipeline's transport plays the voice) as a child process in its own
session, on a private instance (`pipecat-<pid>-<random>`) unless one is named, and returns once it
reports ready. Its output is kept (the last lines, for errors); its errors are logged.
`stop()` sends it Ctrl-C (SIGINT to its process group): `eca up` stops its services in order and removes
the instance's runtime files (sockets, lock, state snapshot, and the directory when empty); one that
does not stop in time is killed with its group and those files are removed here.

`eca up` runs under a small guard (services/pipecat/guard.py) that stops it the same way when this
process dies without stopping it (a SIGKILL, a crash, an event loop torn down before the pipeline's
cleanup ran): nothing is left behind, no process and no file.
"""

from __future__ import annotations

import os
import secrets
import signal
import subprocess
import sys
import threading
import time
from collections import deque
from pathlib import Path

from loguru import logger

from eca.protocol.endpoints import BusConfig, load_bus_config
from eca.services.tools.child_processes import eca_command, subprocess_env

SERVICES = ("dialogue", "gaze", "audio")  # with the broker: what a face in a pipeline needs
READY_LINE = "[up] ready in"
GUARD = Path(__file__).resolve().with_name("guard.py")


def runtime_files(config: BusConfig) -> list[str]:
    """The instance's runtime directory and the names of the files `eca up` makes in it."""
    from eca.services.processes.broker import BROKER_LOCK
    from eca.services.processes.liveness import liveness_endpoint
    from eca.services.processes.state_snapshot import snapshot_path

    sockets = [e.removeprefix("ipc://") for e in (config.frontend, config.backend, liveness_endpoint(config))
               if e.startswith("ipc://")]
    names = [Path(s).name for s in sockets if Path(s).parent == config.runtime_dir]
    return [str(config.runtime_dir), *names, BROKER_LOCK, snapshot_path(config).name]


class EcaStartError(RuntimeError):
    """`eca up` did not come up; the message says why (its last lines)."""


class EcaInstance:
    """A running `eca up` child; see the module docstring."""

    def __init__(self, proc: subprocess.Popen[bytes], config: BusConfig) -> None:
        self.proc = proc
        self.config = config
        self.lines: deque[str] = deque(maxlen=200)
        self._ready = threading.Event()
        self._reader = threading.Thread(target=self._read, daemon=True, name=f"eca-up-{config.instance}")
        self._reader.start()

    @classmethod
    def start(cls, instance: str | None = None, config_path: str | Path | None = None, timeout_s: float = 60.0,
              services: tuple[str, ...] = SERVICES) -> EcaInstance:
        """Start `eca up` with `services` (and the broker) and wait for its ready line (EcaStartError after
        `timeout_s`, or when it ends first)."""
        name = instance or f"pipecat-{os.getpid()}-{secrets.token_hex(3)}"
        config = load_bus_config(config_path, instance=name)
        up = eca_command("up", "--instance", name, "--quiet", "--silent-audio",
                         *(a for s in services for a in ("--only", s)))
        if config_path is not None:
            up += ["--config", str(config_path)]
        argv = [sys.executable, str(GUARD), str(os.getpid()), "--clean", *runtime_files(config), "--", *up]
        proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                env=subprocess_env(), start_new_session=True)
        started = cls(proc, config)
        try:
            started._wait_ready(timeout_s)
        except BaseException:
            started.stop()
            raise
        logger.info(f"eca instance '{name}' is up (pid {proc.pid})")
        return started

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for raw in iter(self.proc.stdout.readline, b""):
            line = raw.decode("utf-8", "replace").rstrip("\n")
            self.lines.append(line)
            if READY_LINE in line:
                self._ready.set()
            elif " ERROR " in line or line.startswith("Traceback"):
                logger.warning(f"eca: {line}")
            else:  # eca's own warnings (no sound card, say) are about eca's outputs, not the pipeline's
                logger.debug(f"eca: {line}")

    def _wait_ready(self, timeout_s: float) -> None:
        deadline = time.monotonic() + timeout_s
        while not self._ready.wait(0.05):
            if self.proc.poll() is not None:
                self._reader.join(timeout=2.0)
                raise EcaStartError(f"`eca up` ended (exit code {self.proc.returncode}) before it was ready:\n"
                                    + "\n".join(list(self.lines)[-20:]))
            if time.monotonic() >= deadline:
                raise EcaStartError(f"`eca up` was not ready within {timeout_s:g} s:\n"
                                    + "\n".join(list(self.lines)[-20:]))

    @property
    def running(self) -> bool:
        return self.proc.poll() is None

    def stop(self, timeout_s: float = 10.0) -> None:
        """Stop it as Ctrl-C would (SIGINT to the guard's group: `eca up` stops, the guard waits for it); kill
        the whole group if it is not gone within `timeout_s`. Idempotent."""
        proc = self.proc
        if proc.poll() is None:
            try:
                os.killpg(proc.pid, signal.SIGINT)
            except ProcessLookupError:
                pass
            try:
                proc.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                logger.warning(f"eca instance '{self.config.instance}' did not stop within {timeout_s:g} s: killed")
                try:
                    os.killpg(proc.pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
                proc.wait(timeout=5.0)
        try:
            os.killpg(proc.pid, 0)  # a service still alive in the group (it outlived its supervisor)?
        except ProcessLookupError:
            pass
        else:
            os.killpg(proc.pid, signal.SIGKILL)
        self._reader.join(timeout=2.0)
        if proc.stdout is not None:
            proc.stdout.close()
        from eca.services.tools.up import remove_runtime_files  # what `eca up` removes on a clean stop

        remove_runtime_files(self.config)
