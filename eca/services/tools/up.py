"""`eca up`: the broker and the configured services as fresh interpreters, watched and restarted.

Each child is `python -m eca.services.processes.run NAME` in its own process session (so a Ctrl-C reaches only the
supervisor, which then stops everything in order) and watches the supervisor's pid, so none outlives
it even if the supervisor is killed. Children's output is printed line by line with their name.

Whether a child is alive is judged by the heartbeats it sends straight to the supervisor
(services/processes/liveness.py), never through the bus, so a broker that is down or slow to come back gets no
healthy service killed; the bus is only watched for the summary line, and nothing on it can stop the
supervisor. On every way out the children are stopped and reaped and the instance's runtime files (the
sockets, the broker's lock, the state snapshot) are removed.
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

from eca.agent.clock import MonotonicClock
from eca.protocol.bus import BusTimeout, Subscriber
from eca.protocol.endpoints import BusConfig
from eca.services.processes.broker import BROKER_LOCK
from eca.services.processes.liveness import LivenessListener, liveness_endpoint
from eca.services.processes.run import SERVICES
from eca.services.processes.state_snapshot import StateSnapshot, snapshot_path
from eca.services.tools.bus_view import BusView
from eca.services.tools.child_processes import subprocess_env
from eca.services.tools.supervisor import RestartPolicy, Supervisor

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
    """Starts `python -m eca.services.processes.run NAME` with the supervisor's config and instance."""

    def __init__(self, config: BusConfig, extra_args: dict[str, list[str]] | None = None,
                 liveness: str | None = None) -> None:
        self.config = config
        self.extra_args = extra_args or {}
        self.liveness = liveness
        self.children: list[subprocess.Popen[bytes]] = []

    def __call__(self, name: str) -> subprocess.Popen[bytes]:
        argv = [sys.executable, "-m", "eca.services.processes.run", name, "--config", str(self.config.config_path),
                "--instance", self.config.instance, "--parent-pid", str(os.getpid()),
                *(["--liveness", self.liveness] if self.liveness else []), *self.extra_args.get(name, [])]
        proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                env=subprocess_env(), start_new_session=True)
        threading.Thread(target=_pump, args=(name, proc.stdout), daemon=True).start()
        self.children = [p for p in self.children if p.poll() is None]  # the ended ones are reaped now
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
    ctx = zmq.Context()
    try:
        liveness = LivenessListener(ctx, config)
    except zmq.ZMQError as exc:
        say(f"cannot listen for heartbeats in {config.runtime_dir}: {exc}")
        ctx.term()
        return 1
    StateSnapshot(snapshot_path(config)).remove()  # a new instance starts from the defaults, not an old run's
    factory = InterpreterFactory(config, extra_args, liveness.endpoint)
    supervisor = Supervisor(["broker", *services], factory, MonotonicClock(), policy_from(config), say=say)
    sub = Subscriber(ctx, config, ["sys.", "state.", "error."])
    poller = zmq.Poller()
    poller.register(liveness.socket, zmq.POLLIN)
    poller.register(sub.socket, zmq.POLLIN)
    bus_view = BusView(list(config.agents))
    t0 = time.monotonic()
    code = 0
    try:
        supervisor.start("broker")
        if not _wait_for_broker(supervisor, liveness, stop):
            if not stop.is_set():
                say("the broker did not come up; see its output above")
                code = 1
            return code
        try:
            for got in sub.wait_ready(timeout_s=supervisor.policy.ready_timeout_s):
                bus_view.add(got)
        except BusTimeout:
            say("the broker sends heartbeats but does not answer on the bus; see its output above")
            return 1
        for name in services:
            supervisor.start(name)
        announced = False
        next_view = time.monotonic() + 2.0
        while not stop.is_set():
            if duration_s is not None and time.monotonic() - t0 > duration_s:
                break
            ready = dict(poller.poll(50))
            for beat in liveness.drain():
                supervisor.on_heartbeat(beat.service, beat.pid)
            if sub.socket in ready:
                _watch_bus(sub, bus_view)
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
        all_ended = _stop_all(supervisor, factory)
        sub.close()
        liveness.close()
        ctx.term()
        if all_ended:
            remove_runtime_files(config)
        say("stopped")
    return code


def _wait_for_broker(supervisor: Supervisor, liveness: LivenessListener, stop: threading.Event) -> bool:
    """Until the broker's first heartbeat (True), or it gave up, the ready timeout passed, or a stop."""
    broker = supervisor.by_name["broker"]
    deadline = time.monotonic() + supervisor.policy.ready_timeout_s
    while not stop.is_set() and not broker.given_up and time.monotonic() < deadline:
        liveness.socket.poll(50)
        for beat in liveness.drain():
            supervisor.on_heartbeat(beat.service, beat.pid)
        if broker.ready:
            return True
        supervisor.check()
    return False


def _watch_bus(sub: Subscriber, bus_view: BusView) -> None:
    """Feed the summary line; whatever arrives, the supervisor goes on (it must outlive any bad message)."""
    for item in sub.drain(5000):
        try:
            bus_view.add(item)
        except Exception as exc:  # a bug in the summary must not cost the supervisor
            say(f"could not show one bus message ({type(exc).__name__}); carrying on")


def _stop_all(supervisor: Supervisor, factory: InterpreterFactory) -> bool:
    """Stop every child in reverse order, kill what outlives the grace period, reap all; True when none is
    left running."""
    supervisor.begin_stop()
    deadline = time.monotonic() + supervisor.policy.stop_grace_s + 2.0
    while not supervisor.finish_stop() and time.monotonic() < deadline:
        time.sleep(0.02)  # pacing a poll of child processes, not synchronisation
    ended = True
    for proc in factory.children:
        if proc.poll() is None:
            proc.kill()
        try:
            proc.wait(timeout=2.0)
        except subprocess.TimeoutExpired:
            say(f"process {proc.pid} did not end after SIGKILL")
            ended = False
    return ended


def remove_runtime_files(config: BusConfig) -> None:
    """The instance's sockets, lock and state snapshot; the directory too when nothing else is in it."""
    files = [Path(e.removeprefix("ipc://")) for e in (config.frontend, config.backend) if e.startswith("ipc://")]
    files += [config.runtime_dir / BROKER_LOCK, Path(liveness_endpoint(config).removeprefix("ipc://")),
              snapshot_path(config)]
    for path in files:
        path.unlink(missing_ok=True)
    try:
        config.runtime_dir.rmdir()
    except OSError:
        pass  # something else lives there (a user's own file): leave the directory
