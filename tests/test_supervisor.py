"""The supervisor's timing logic on virtual time with fake processes."""

from __future__ import annotations

import signal

import pytest

from eca.agent.clock import VirtualClock
from eca.services.tools.supervisor import RestartPolicy, Supervisor


class FakeProcess:
    next_pid = 100

    def __init__(self, name: str) -> None:
        FakeProcess.next_pid += 1
        self.pid = FakeProcess.next_pid
        self.name = name
        self.code: int | None = None
        self.signals: list[int] = []
        self.ignores_term = False

    def poll(self) -> int | None:
        return self.code

    def send_signal(self, sig: int) -> None:
        self.signals.append(sig)
        if sig == signal.SIGTERM and not self.ignores_term:
            self.code = 0

    def kill(self) -> None:
        self.signals.append(signal.SIGKILL)
        self.code = -9


class Factory:
    def __init__(self) -> None:
        self.started: list[FakeProcess] = []

    def __call__(self, name: str) -> FakeProcess:
        proc = FakeProcess(name)
        self.started.append(proc)
        return proc

    def latest(self, name: str) -> FakeProcess:
        return [p for p in self.started if p.name == name][-1]


POLICY = RestartPolicy(heartbeat_timeout_s=1.5, ready_timeout_s=5.0, backoff_s=(0.1, 0.5, 1.0),
                       restart_limit=3, restart_window_s=60.0, stop_grace_s=1.0)


@pytest.fixture
def rig() -> tuple[Supervisor, Factory, VirtualClock, list[str]]:
    clock = VirtualClock()
    factory = Factory()
    said: list[str] = []
    sup = Supervisor(["broker", "dialogue"], factory, clock, POLICY, say=said.append)
    for name in ("broker", "dialogue"):
        sup.start(name)
    return sup, factory, clock, said


def beat_all(sup: Supervisor, factory: Factory) -> None:
    for name in ("broker", "dialogue"):
        sup.on_heartbeat(name, factory.latest(name).pid)


def test_ready_only_after_every_first_heartbeat(rig) -> None:
    sup, factory, clock, _ = rig
    assert not sup.all_ready()
    sup.on_heartbeat("broker", factory.latest("broker").pid)
    assert not sup.all_ready()
    sup.on_heartbeat("dialogue", factory.latest("dialogue").pid)
    assert sup.all_ready()


def test_heartbeat_from_an_old_instance_does_not_count(rig) -> None:
    sup, factory, clock, _ = rig
    sup.on_heartbeat("dialogue", 99999)
    assert not sup.by_name["dialogue"].ready


def test_exit_restarts_after_backoff(rig) -> None:
    sup, factory, clock, said = rig
    beat_all(sup, factory)
    first = factory.latest("dialogue")
    first.code = 1
    sup.check()
    assert "exited with code 1" in said[-1]
    assert factory.latest("dialogue") is first  # not yet: backoff
    clock.advance_s(0.09)
    sup.check()
    assert factory.latest("dialogue") is first
    clock.advance_s(0.02)
    sup.check()
    assert factory.latest("dialogue") is not first
    assert not sup.by_name["dialogue"].ready  # until the new instance beats


def test_silent_service_is_killed_and_restarted(rig) -> None:
    sup, factory, clock, said = rig
    beat_all(sup, factory)
    hung = factory.latest("dialogue")
    clock.advance_s(1.0)
    sup.on_heartbeat("broker", factory.latest("broker").pid)
    sup.check()
    assert hung.signals == []
    clock.advance_s(0.6)  # 1.6 s since dialogue's last beat
    sup.on_heartbeat("broker", factory.latest("broker").pid)
    sup.check()
    assert hung.signals == [signal.SIGKILL]
    assert "no heartbeat" in said[-1]
    clock.advance_s(0.2)
    sup.check()
    assert factory.latest("dialogue") is not hung


def test_backoff_grows_then_gives_up_with_a_clear_message(rig) -> None:
    sup, factory, clock, said = rig
    delays = []
    for _ in range(3):
        factory.latest("dialogue").code = 1
        sup.check()
        svc = sup.by_name["dialogue"]
        delays.append((svc.restart_at_ns - clock.now_ns()) / 1e9)
        clock.advance_ns(svc.restart_at_ns - clock.now_ns())
        sup.check()
    assert delays == pytest.approx([0.1, 0.5, 1.0])
    factory.latest("dialogue").code = 1
    sup.check()
    assert sup.by_name["dialogue"].given_up
    assert "not restarted again" in said[-1]
    n = len(factory.started)
    clock.advance_s(10)
    sup.check()
    assert len(factory.started) == n


def test_restarts_outside_the_window_are_forgotten(rig) -> None:
    sup, factory, clock, _ = rig
    for _ in range(3):
        factory.latest("dialogue").code = 1
        sup.check()
        clock.advance_s(61.0)  # each failure far apart
        sup.check()
        sup.on_heartbeat("dialogue", factory.latest("dialogue").pid)
        sup.on_heartbeat("broker", factory.latest("broker").pid)
    factory.latest("dialogue").code = 1
    sup.check()
    assert not sup.by_name["dialogue"].given_up


def test_stop_terms_in_reverse_order_and_kills_after_grace(rig) -> None:
    sup, factory, clock, said = rig
    beat_all(sup, factory)
    stubborn = factory.latest("dialogue")
    stubborn.ignores_term = True
    order: list[str] = []
    for proc in factory.started:
        original = proc.send_signal

        def record(sig: int, proc=proc, original=original) -> None:
            order.append(proc.name)
            original(sig)

        proc.send_signal = record  # type: ignore[method-assign]
    sup.begin_stop()
    assert order == ["dialogue", "broker"]
    assert not sup.finish_stop()
    clock.advance_s(0.5)
    assert not sup.finish_stop()
    assert signal.SIGKILL not in stubborn.signals
    clock.advance_s(0.6)
    sup.finish_stop()
    assert stubborn.signals[-1] == signal.SIGKILL
    assert sup.finish_stop()


def test_service_that_never_beats_is_restarted_after_ready_timeout(rig) -> None:
    sup, factory, clock, said = rig
    sup.on_heartbeat("broker", factory.latest("broker").pid)
    mute = factory.latest("dialogue")
    clock.advance_s(4.9)
    sup.check()
    assert mute.signals == []
    clock.advance_s(0.2)
    sup.check()
    assert mute.signals == [signal.SIGKILL]


def test_a_broker_that_cannot_bind_releases_its_sockets_and_lock(tmp_path) -> None:
    import socket

    import zmq

    from eca.services.processes.broker import Broker
    from tests.support.bus import private_bus_config

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        port = taken.getsockname()[1]
        extra = f'[bus]\ntransport = "tcp"\ninstance = "x"\nruntime_dir = ""\ntcp_host = "127.0.0.1"\n' \
                f'tcp_frontend_port = {port}\ntcp_backend_port = {port}\nallow_remote = false\nhwm = 100\n' \
                f'max_message_bytes = 65536\n'
        with private_bus_config(extra=extra) as config:
            ctx = zmq.Context()
            with pytest.raises(zmq.ZMQError):
                Broker(config, ctx)
            ctx.term()  # would hang if a socket had been left open


def test_a_killed_service_is_polled_until_its_end_is_collected(rig) -> None:
    """A hung process killed and replaced is still polled (which reaps it) until it has ended: none stays a
    zombie for the life of `eca up`."""
    sup, factory, clock, _ = rig
    beat_all(sup, factory)
    hung = factory.latest("dialogue")
    hung.kill = lambda: hung.signals.append(signal.SIGKILL)  # type: ignore[method-assign]  # takes effect later
    polls: list[int] = []
    hung.poll = lambda: polls.append(1) or hung.code  # type: ignore[method-assign]
    clock.advance_s(1.6)
    sup.on_heartbeat("broker", factory.latest("broker").pid)
    sup.check()
    assert hung.signals == [signal.SIGKILL] and hung in sup.retired
    clock.advance_s(0.2)
    sup.check()
    assert factory.latest("dialogue") is not hung  # replaced already
    before = len(polls)
    sup.check()
    assert len(polls) > before and hung in sup.retired  # not ended yet: polled again
    sup.begin_stop()
    assert not sup.finish_stop()  # a stop waits for it too
    hung.code = -9
    sup.check()
    assert hung not in sup.retired


def test_the_bus_view_holds_a_fixed_amount_whatever_arrives() -> None:
    from eca.protocol.bus import Received
    from eca.protocol.messages import ALL_AGENTS, EmotionState, Error, Heartbeat
    from eca.services.tools.bus_view import MAX_SERVICES_SHOWN, BusView

    view = BusView(["ada"])
    for k in range(1000):
        view.add(Received("sys.*.heartbeat", Heartbeat(agent=ALL_AGENTS, service=f"s{k}", pid=1, started_ns=1)))
        view.add(Received(f"state.x{k}.emotion", EmotionState(agent=f"x{k}", name="happy")))
    view.add(Received("state.ada.emotion", EmotionState(agent="ada", name="angry", intensity=0.5)))
    view.add(Received("error.*.error", Error(agent=ALL_AGENTS, reason="bad frames", service="dialogue")))
    assert len(view.services) == MAX_SERVICES_SHOWN and list(view.emotion) == ["ada"]
    line = view.summary()
    assert "ada: ?, angry 0.5" in line and "1 errors, last: dialogue: bad frames" in line
    assert view.arrived == 0  # counted, then reset by the summary: nothing kept per message
