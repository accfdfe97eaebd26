"""`eca up`: the broker and the configured services as fresh interpreters, watched and restarted.

Each child is `python -m services.run NAME` in its own process session (so a Ctrl-C reaches only the
supervisor, which then stops everything in order) and watches the supervisor's pid, so none outlives
it even if the supervisor is killed. Children's output is printed line by line with their name.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Sequence
from pathlib import Path

import zmq

from agent.clock import MonotonicClock
from protocol.bus import BusTimeout, Subscriber
from protocol.endpoints import BusConfig
from protocol.messages import Heartbeat
from services.bus_view import BusView
from services.run import SERVICES
from services.supervisor import RestartPolicy, Supervisor

_print_lock = threading.Lock()


def say(line: str) -> None:
    with _print_lock:
        print(f"[up] {line}", flush=True)


def _pump(name: str, stream: object) -> None:
    prefix = f"[{name}]"
    for raw in iter(stream.readline, b""):  # type: ignore[attr-defined]
        line = raw.decode("utf-8", "replace").rstrip("\n")
        with _print_lock:
            print(line if line.startswith(prefix) else f"{prefix} {line}", flush=True)


class InterpreterFactory:
    """Starts `python -m services.run NAME` with the supervisor's config and instance."""

    def __init__(self, config: BusConfig, extra_args: dict[str, list[str]] | None = None) -> None:
        self.config = config
        self.extra_args = extra_args or {}
        self.children: list[subprocess.Popen[bytes]] = []

    def __call__(self, name: str) -> subprocess.Popen[bytes]:
        argv = [sys.executable, "-m", "services.run", name, "--config", str(self.config.config_path),
                "--instance", self.config.instance, "--parent-pid", str(os.getpid()),
                *self.extra_args.get(name, [])]
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        repo_root = str(Path(__file__).resolve().parent.parent)
        env["PYTHONPATH"] = repo_root + os.pathsep + env.get("PYTHONPATH", "")
        proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                env=env, start_new_session=True)
        threading.Thread(target=_pump, args=(name, proc.stdout), daemon=True).start()
        self.children.append(proc)
        return proc


def policy_from(config: BusConfig) -> RestartPolicy:
    sup = config.raw.get("supervisor", {})
    return RestartPolicy(
        heartbeat_timeout_s=config.heartbeat_timeout_s,
        ready_timeout_s=float(sup.get("ready_timeout_s", 15.0)),
        backoff_s=tuple(float(x) for x in sup.get("restart_backoff_s", (0.05, 0.25, 0.5, 1.0, 2.0))),
        restart_limit=int(sup.get("restart_limit", 5)),
        restart_window_s=float(sup.get("restart_window_s", 60.0)),
        stop_grace_s=float(sup.get("stop_grace_s", 1.0)),
    )


def choose_services(config: BusConfig, only: Sequence[str] = (), without: Sequence[str] = ()) -> list[str]:
    configured = list(config.raw.get("supervisor", {}).get("services", ["dialogue"]))
    for name in [*configured, *only, *without]:
        if name not in SERVICES:
            raise ValueError(f"unknown service '{name}'; known: {', '.join(SERVICES)}")
    chosen = list(only) if only else configured
    return [n for n in chosen if n not in without]


def instance_running(config: BusConfig, timeout_s: float = 0.3) -> bool:
    """Whether a broker already answers for this instance (a second one must not start beside it)."""
    ctx = zmq.Context()
    probe = Subscriber(ctx, config, [])
    try:
        probe.wait_ready(timeout_s)
        return True
    except BusTimeout:
        return False
    finally:
        probe.close()
        ctx.term()


def run_up(config: BusConfig, services: Sequence[str], *, view: bool = True, duration_s: float | None = None,
           extra_args: dict[str, list[str]] | None = None) -> int:
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    if instance_running(config):
        say(f"instance '{config.instance}' is already running (a broker answers at {config.backend}); "
            "stop it first or pick another --instance")
        return 1
    factory = InterpreterFactory(config, extra_args)
    clock = MonotonicClock()
    supervisor = Supervisor(["broker", *services], factory, clock, policy_from(config), say=say)
    ctx = zmq.Context()
    sub = Subscriber(ctx, config, ["sys.", "state.", "error."])
    bus_view = BusView(config.raw.get("agents", {}).get("ids", []))
    t0 = time.monotonic()
    code = 0
    try:
        supervisor.start("broker")
        try:
            for got in sub.wait_ready(timeout_s=supervisor.policy.ready_timeout_s):
                bus_view.add(got)
        except BusTimeout:
            say("the broker did not come up; see its output above")
            return 1
        for name in services:
            supervisor.start(name)
        announced = False
        next_view = time.monotonic() + 2.0
        while not stop.is_set():
            if duration_s is not None and time.monotonic() - t0 > duration_s:
                break
            got = sub.recv(0.05)
            batch = ([got] if got else []) + sub.drain(5000)
            for item in batch:
                if isinstance(item.message, Heartbeat):
                    supervisor.on_heartbeat(item.message.service, item.message.pid)
                bus_view.add(item)
            supervisor.check()
            if not announced and supervisor.all_ready():
                announced = True
                say(f"ready in {time.monotonic() - t0:.2f} s: {', '.join(s.name for s in supervisor.services)} "
                    f"(instance '{config.instance}', publish to {config.frontend}, "
                    f"subscribe at {config.backend}); Ctrl-C stops")
            if all(s.given_up for s in supervisor.services if s.name != "broker") and services:
                say("every service has given up: stopping")
                code = 1
                break
            if view and time.monotonic() >= next_view:
                next_view = time.monotonic() + 2.0
                say(bus_view.summary())
    finally:
        say("stopping")
        supervisor.begin_stop()
        deadline = time.monotonic() + supervisor.policy.stop_grace_s + 2.0
        while not supervisor.finish_stop() and time.monotonic() < deadline:
            time.sleep(0.02)
        for proc in factory.children:
            if proc.poll() is None:
                proc.kill()
            proc.wait(timeout=2.0)
        sub.close()
        ctx.term()
        say("stopped")
    return code
