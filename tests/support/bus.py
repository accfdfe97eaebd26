"""Test utilities that ship with eca: private bus instances, an in-process broker, real process groups.

Every helper makes a unique instance (its own runtime directory), so tests run in parallel safely.
"""

from __future__ import annotations

import os
import re
import secrets
import shutil
import signal
import subprocess
import tempfile
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import zmq

from eca.protocol.endpoints import DEFAULT_CONFIG, BusConfig, load_bus_config
from eca.services.processes.broker import Broker
from eca.services.tools.child_processes import LineReader, eca_command, subprocess_env  # noqa: F401 (re-exported)

REPO_ROOT = Path(__file__).resolve().parents[2]


# Whether the instances made here run the voice's path at real-time priority as shipped ([realtime]). The benches
# measure the product as shipped; the test suite (tests/conftest.py) turns it off: many instances run at once on two
# cores, each test's timing its own, and a real-time service of one test would take the cores in bursts from the
# ordinary processes of another (a test drawing video in-process, a script player). tests/test_realtime.py asks.
REALTIME = True


def write_test_config(directory: Path, services: list[str] | None = None, agents: list[str] | None = None,
                      extra: str = "", realtime: bool | None = None) -> Path:
    """A copy of the default config with a private runtime directory under `directory`; tables in `extra`
    replace the default tables of the same name. `realtime` (default: REALTIME) False turns [realtime] off."""
    if not (REALTIME if realtime is None else realtime) and not re.search(r"^\[realtime\]", extra, re.MULTILINE):
        extra = f"{extra}\n[realtime]\npriority = 0\n"
    text = DEFAULT_CONFIG.read_text()
    text = text.replace('runtime_dir = ""', f'runtime_dir = "{directory / "run"}"', 1)
    if services is not None:
        text = re.sub(r"^services = \[[^\]]*\]", f"services = {services!r}".replace("'", '"'), text, count=1,
                      flags=re.MULTILINE)
    if agents is not None:
        text = text.replace('ids = ["ada"]', f"ids = {agents!r}".replace("'", '"'), 1)
    for table in re.findall(r"^\[([\w.-]+)\]", extra, flags=re.MULTILINE):
        # a table given in `extra` replaces the default one of that name
        text = re.sub(rf"^\[{re.escape(table)}\]\n.*?(?=^\[|\Z)", "", text, flags=re.MULTILINE | re.DOTALL)
    path = directory / "eca.toml"
    path.write_text(text + "\n" + extra)
    return path


@contextmanager
def private_bus_config(services: list[str] | None = None, agents: list[str] | None = None,
                       extra: str = "", realtime: bool | None = None) -> Iterator[BusConfig]:
    """A config for a fresh instance in a short private directory (ipc paths must stay short)."""
    directory = Path(tempfile.mkdtemp(prefix="eca-"))
    try:
        path = write_test_config(directory, services, agents, extra, realtime)
        yield load_bus_config(path, instance=f"t{secrets.token_hex(4)}")
    finally:
        shutil.rmtree(directory, ignore_errors=True)


class BrokerThread:
    """The real broker, run in a thread of the test process (for tests about the models, not processes)."""

    def __init__(self, config: BusConfig) -> None:
        self.config = config
        self.ctx = zmq.Context()
        self.broker = Broker(config, self.ctx)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, daemon=True, name="broker")

    def _loop(self) -> None:
        next_beat = 0.0
        while not self._stop.is_set():
            if time.monotonic() >= next_beat:
                self.broker.heartbeat()
                next_beat = time.monotonic() + self.config.heartbeat_interval_s
            self.broker.step(20)
        self.broker.close()

    def __enter__(self) -> BrokerThread:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        self.ctx.term()


class ServiceThread:
    """A Service subclass run in a thread (its loop, sockets and handlers are the real ones)."""

    def __init__(self, service: object) -> None:
        self.service = service
        self._thread = threading.Thread(target=self._run, daemon=True, name=getattr(service, "name", "service"))
        self.ready = threading.Event()
        self.error: BaseException | None = None

    def _run(self) -> None:
        try:  # the service's own loop, without the process's signal handlers
            if self.service.run(install_signals=False, on_ready=self.ready.set) != 0:  # type: ignore[attr-defined]
                self.error = RuntimeError(f"{self._thread.name} could not start (its log says why)")
        except BaseException as exc:  # surfaced to the test by __enter__/__exit__
            self.error = exc
        finally:
            self.ready.set()

    def __enter__(self) -> ServiceThread:
        self._thread.start()
        if not self.ready.wait(10) or self.error is not None:
            raise RuntimeError(f"service did not start: {self.error!r}")
        return self

    def __exit__(self, *exc: object) -> None:
        self.service.request_stop()  # type: ignore[attr-defined]
        self._thread.join(timeout=5)
        if self.error is not None:
            raise self.error


@contextmanager
def running(argv: list[str], stop_signal: int = signal.SIGINT, stop_timeout_s: float = 5.0,
            cwd: Path = REPO_ROOT) -> Iterator[tuple[subprocess.Popen[bytes], LineReader]]:
    """Run a command with merged output captured line by line; stop it (and its group) afterwards."""
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                            env=subprocess_env(), cwd=cwd, start_new_session=True)
    reader = LineReader(proc.stdout)
    try:
        yield proc, reader
    finally:
        if proc.poll() is None:
            proc.send_signal(stop_signal)
            try:
                proc.wait(timeout=stop_timeout_s)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait(timeout=5)
