"""Agents created and removed at run time (docs/protocol.md section 14), against real processes under `eca up`
(broker, dialogue, gaze, audio on the silent sink): a created agent talks and looks about, two created agents know
nothing of each other, a removed one ends its say once and leaves nothing behind (streams, the agents list, the
broker's cache), the limit is kept, a visitor who comes and goes 200 times costs no memory, a restarted dialogue
service keeps the created agents, and a service that starts late follows them."""

from __future__ import annotations

import os
import re
import signal
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np
import pytest
import zmq

from eca.protocol.bus import Publisher, Subscriber
from eca.protocol.client import AgentClient
from eca.protocol.endpoints import BusConfig
from eca.protocol.messages import (
    ALL_AGENTS,
    TERMINAL_SPEECH_EVENTS,
    Ack,
    AgentsState,
    CreateAgent,
    EmotionState,
    Error,
    EyeStates,
    Heartbeat,
    Message,
    RemoveAgent,
    RigPose,
    RoleState,
    Say,
    SetEmotion,
    SpeechInterrupted,
    SpeechStarted,
    VoiceBlock,
)
from eca.services.tools.child_processes import LineReader
from tests.support.bus import eca_command, private_bus_config, running

pytestmark = pytest.mark.slow

SERVICES = ["dialogue", "gaze", "audio"]
MAX = 3  # [conversations] max of this instance
LOOPS = 200
GROWTH_LIMIT_KB = 3 * 1024  # "back to its level": a few MB at most, whatever the 200 visitors left


@dataclass
class Instance:
    config: BusConfig
    reader: LineReader

    def pid(self, name: str) -> int:
        """The pid the service last reported ready with."""
        found = [int(m.group(1)) for line in self.reader.lines
                 if (m := re.match(rf"\[{name}\] INFO ready \(pid (\d+)", line))]
        assert found, f"{name} never reported ready"
        return found[-1]


@pytest.fixture(scope="module")
def instance() -> Iterator[Instance]:
    extra = f"[conversations]\nmax = {MAX}\ntemplate = \"\"\n"
    with private_bus_config(services=SERVICES, agents=["ada", "bob"], extra=extra) as config:
        argv = eca_command("up", "--config", str(config.config_path), "--instance", config.instance, "--quiet",
                           "--silent-audio")
        with running(argv) as (proc, reader):
            reader.wait_for("[up] ready in", 90.0)
            for name in ("broker", *SERVICES):
                reader.wait_for(f"[{name}] INFO ready (pid", 10.0)
            yield Instance(config, reader)
            assert proc.poll() is None, "eca up itself stopped"
            assert not [line for line in reader.lines if "Traceback" in line]


@pytest.fixture
def config(instance: Instance) -> Iterator[BusConfig]:
    yield instance.config
    left = agents_state(instance.config).created
    assert left == [], f"a test left created agents behind: {left}"


# --- helpers -----------------------------------------------------------------------------------------


def create(client: AgentClient, like: str = "") -> Ack:
    return client.wait_applied(client.send(CreateAgent(agent=client.agent, like=like,
                                                       request_id=client.new_request_id())), 10.0)


def remove(client: AgentClient) -> Ack:
    return client.wait_applied(client.send(RemoveAgent(agent=client.agent, request_id=client.new_request_id())), 10.0)


def cached(config: BusConfig, prefix: str) -> list[Message]:
    """What the broker's cache holds under `prefix`: what a subscriber that comes now gets at once."""
    ctx = zmq.Context()
    sub = Subscriber(ctx, config, [prefix])
    try:
        return [got.message for got in sub.wait_ready() if got.message is not None]
    finally:
        sub.close()
        ctx.term()


def agents_state(config: BusConfig) -> AgentsState:
    [listing] = cached(config, f"state.{ALL_AGENTS}.agents")
    assert isinstance(listing, AgentsState)
    return listing


def say_pcm(seconds: float, rate: int = 16_000) -> bytes:
    t = np.arange(int(seconds * rate)) / rate
    return (0.2 * np.sin(2 * np.pi * 220 * t) * 32767).astype("<i2").tobytes()


def collect(sub: Subscriber, done: Callable[[list[Message]], bool], timeout_s: float = 10.0) -> list[Message]:
    got: list[Message] = []
    deadline = time.monotonic() + timeout_s
    while not done(got) and (left := deadline - time.monotonic()) > 0:
        received = sub.recv(left)
        if received is not None and received.message is not None:
            got.append(received.message)
    assert done(got), f"not there within {timeout_s} s; got {len(got)} messages, the last {got[-3:]}"
    return got


def agents_of(m: Message) -> list[str]:
    """The agents a message is about: an eye-state message's list, any other's agent."""
    return m.agents if isinstance(m, EyeStates) else [m.agent]


def stopped(sub: Subscriber, agent: str, witness: str, n: int = 12) -> None:
    """`agent`'s stream has stopped: `n` messages of the witness agent's (same topic type, same publisher's ticks)
    in a row come without one of `agent`'s between them."""
    run = 0

    def done(got: list[Message]) -> bool:
        nonlocal run
        if got and agent in agents_of(got[-1]):
            run = 0
        elif got and witness in agents_of(got[-1]):
            run += 1
        return run >= n

    collect(sub, done)


@pytest.fixture
def bus_io(instance: Instance) -> Iterator[tuple[Publisher, Callable[[list[str]], Subscriber]]]:
    """A publisher, and subscribers made ready on demand (closed afterwards)."""
    ctx = zmq.Context()
    pub = Publisher(ctx, instance.config, "test")
    pub.wait_ready()
    subs: list[Subscriber] = []

    def subscriber(prefixes: list[str]) -> Subscriber:
        sub = Subscriber(ctx, instance.config, prefixes)
        sub.wait_ready()
        subs.append(sub)
        return sub

    yield pub, subscriber
    for sub in subs:
        sub.close()
    pub.close()
    ctx.term()


# --- create, talk, look ------------------------------------------------------------------------------


def test_a_created_agent_talks_and_its_eyes_move(config: BusConfig, bus_io) -> None:
    _, subscriber = bus_io
    with AgentClient(config, agent="page-1") as page:
        ack = create(page)
        assert (ack.command, ack.agent) == ("create_agent", "page-1")
        # its states were published before the list that names it, the list before the ack
        assert page.state["role"].role == "listening" and page.state["emotion"].name == "natural"
        listing = agents_state(config)
        assert listing.agents == ["ada", "bob", "page-1"] and listing.created == ["page-1"]
        assert listing.like == ["ada"] and listing.max_created == MAX
        eyes = subscriber(["stream.*.eye_states", "stream.page-1.voice", "stream.page-1.mouth"])
        collect(eyes, lambda got: sum("page-1" in agents_of(m) for m in got if isinstance(m, EyeStates)) >= 5)
        rid = page.new_request_id()
        page.wait_applied(page.send(Say(agent="page-1", request_id=rid, pcm=say_pcm(0.6), sample_rate=16_000,
                                        text="hello")), 10.0)
        started = page.wait_for(lambda m: isinstance(m, SpeechStarted) and m.request_id == rid, 10.0)
        assert started.agent == "page-1"
        page.expect_state(RoleState, lambda m: m.role == "talking")
        ended = page.wait_for_speech(rid, 20.0)
        assert ended.TYPE == "speech_finished" and ended.played_s > 0.5  # type: ignore[attr-defined]
        heard = collect(eyes, lambda got: any(isinstance(m, VoiceBlock) and m.request_id == rid for m in got))
        assert any(m.TYPE == "mouth" for m in heard), "no lip-sync keys for the created agent"
        remove(page)


def test_two_created_agents_know_nothing_of_each_other(config: BusConfig, bus_io) -> None:
    _, subscriber = bus_io
    with AgentClient(config, agent="page-a") as a, AgentClient(config, agent="page-b") as b:
        create(a)
        create(b, like="bob")
        assert agents_state(config).like == ["ada", "bob"]
        watch_b = subscriber(["state.page-b.", "event.page-b.", "error.page-b."])
        a.wait_applied(a.set_emotion("angry", 0.8))
        a.wait_applied(a.set_role("talking", speaker="page-a"))
        a.wait_applied(a.move_head(turn=0.5))
        # a's say may not be addressed to b: each has a conversation of its own, with its own user
        a.send(Say(agent="page-a", request_id="to-b", text="hi", to=["page-b"]))
        err = a.wait_for(lambda m: isinstance(m, Error) and m.request_id == "to-b", 5.0)
        assert "page-b" in err.reason  # type: ignore[attr-defined]
        b.wait_applied(b.set_emotion("happy", 0.3))  # after a's commands: what b's watcher sees comes before
        seen = collect(watch_b, lambda got: any(isinstance(m, EmotionState) and m.name == "happy" for m in got))
        assert {m.agent for m in seen} == {"page-b"}
        assert [m.name for m in seen if isinstance(m, EmotionState)] == ["happy"]  # type: ignore[attr-defined]
        assert not [m for m in seen if isinstance(m, RoleState | SpeechStarted)], "b heard of a's commands"
        assert b.state["role"].role == "listening" and b.state["head"].turn == 0.0  # type: ignore[attr-defined]
        assert a.state["emotion"].name == "angry"  # type: ignore[attr-defined]
        remove(a)
        remove(b)


# --- remove -------------------------------------------------------------------------------------------


def test_a_removed_agent_ends_its_say_once_and_leaves_nothing_behind(config: BusConfig, bus_io) -> None:
    _, subscriber = bus_io
    with AgentClient(config, agent="page-r") as page, AgentClient(config, agent="ada") as ada:
        create(page)
        page.wait_applied(page.set_emotion("happy"))
        events = subscriber(["event.page-r.", "audio.page-r."])
        eyes = subscriber(["stream.*.eye_states"])
        voice = subscriber(["stream.page-r.voice", "stream.ada.voice"])
        collect(eyes, lambda got: any("page-r" in agents_of(m) for m in got))
        rid = page.new_request_id()
        page.wait_applied(page.send(Say(agent="page-r", request_id=rid, pcm=say_pcm(8.0), sample_rate=16_000)))
        page.wait_for(lambda m: isinstance(m, SpeechStarted) and m.request_id == rid, 10.0)
        remove(page)
        # The audio service ends what it held for the agent too, on audio.: once it has (seen here), and once
        # a later command of this client's has been applied, the dialogue service has had that report as well
        # (the broker hands both to it in the order it got them). It must not have made a second ending of it.
        got = collect(events, lambda got: any(m.TYPE == "speech_interrupted" and m.request_id == rid  # type: ignore[attr-defined]
                                              and m.source == "audio" for m in got))
        ada.wait_applied(ada.set_emotion("natural"))
        got += events.drain()
        endings = [m for m in got if isinstance(m, TERMINAL_SPEECH_EVENTS) and m.source == "dialogue"]
        assert len(endings) == 1, endings
        assert isinstance(endings[0], SpeechInterrupted) and endings[0].reason == "the agent was removed"
        assert page.wait_for_speech(rid, 1.0) == endings[0]  # what the agent's own client got: the same one
        # its streams stop while the others' go on
        stopped(eyes, "page-r", "ada")
        ada.say(pcm=say_pcm(2.0), sample_rate=16_000)  # the witness's voice: only a voice that sounds is sent
        stopped(voice, "page-r", "ada")
        # the list no longer names it, and the broker holds nothing of it
        assert "page-r" not in agents_state(config).agents
        assert cached(config, "state.page-r.") == []
        # it does not exist any more: a command for it is refused as for any unknown agent
        page.send(SetEmotion(agent="page-r", name="angry", request_id="late"))
        err = page.wait_for(lambda m: isinstance(m, Error) and m.request_id == "late", 5.0)
        assert "unknown agent 'page-r'" in err.reason  # type: ignore[attr-defined]


def test_the_limit_is_kept_and_a_refused_create_changes_nothing(config: BusConfig) -> None:
    clients = [AgentClient(config, agent=f"full-{k}") for k in range(MAX + 1)]
    try:
        for client in clients[:MAX]:
            create(client)
        listing = agents_state(config)
        over = clients[MAX]
        over.send(CreateAgent(agent=over.agent, request_id="too-many"))
        answer = over.wait_for(lambda m: isinstance(m, Error | Ack), 5.0)
        assert isinstance(answer, Error), answer
        assert answer.kind == "busy" and answer.request_id == "too-many"
        assert answer.reason == f"busy: all {MAX} conversations are in use, try again later"
        assert agents_state(config) == listing  # the very message: nothing was published again
        assert cached(config, f"state.{over.agent}.") == []
        # an id that exists is refused too, configured or created, and a configured agent cannot be removed
        with AgentClient(config, agent="bob") as bob:
            for client, command, says in ((clients[0], CreateAgent(agent="full-0", request_id="x1"), "exists"),
                                          (bob, CreateAgent(agent="bob", request_id="x2"), "exists"),
                                          (bob, RemoveAgent(agent="bob", request_id="x3"), "configured")):
                client.send(command)
                err = client.wait_for(lambda m, rid=command.request_id: isinstance(m, Error | Ack)
                                      and m.request_id == rid, 5.0)
                assert isinstance(err, Error) and says in err.reason, err
        assert agents_state(config) == listing
        # one removed, one may come
        remove(clients[0])
        create(over)
        assert agents_state(config).created == ["full-1", "full-2", f"full-{MAX}"]
        for client in clients[1:]:
            remove(client)
    finally:
        for client in clients:
            client.close()


# --- memory -------------------------------------------------------------------------------------------


def rss_kb(pid: int) -> int:
    with open(f"/proc/{pid}/status") as fh:
        for line in fh:
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    raise AssertionError(f"no VmRSS for {pid}")


def test_visitors_who_come_and_go_cost_no_memory(instance: Instance, config: BusConfig, bus_io) -> None:
    pub, subscriber = bus_io
    answers = subscriber(["event.", "error.", "sys."])
    pids = {name: instance.pid(name) for name in ("broker", "dialogue", "gaze", "audio")}

    def answered(agent: str, rid: str) -> Callable[[list[Message]], bool]:
        def done(got: list[Message]) -> bool:
            last = got[-1] if got else None
            return isinstance(last, Ack | Error) and last.agent == agent and last.request_id == rid
        return done

    def command(msg: CreateAgent | RemoveAgent) -> None:
        pub.publish(msg)
        got = collect(answers, answered(msg.agent, msg.request_id))
        assert isinstance(got[-1], Ack), got[-1]

    def cycle(k: int) -> None:
        command(CreateAgent(agent=f"visitor-{k}", request_id=f"c{k}"))
        command(RemoveAgent(agent=f"visitor-{k}", request_id=f"r{k}"))

    def settled(k: int) -> dict[str, int]:
        """The resident memory of each service once it has handled every create and remove so far: a probe agent's
        eyes move (the gaze service has read every list before the one that names it) and is removed again, and
        then every service beats once more (the heartbeat hands free heap back to the system)."""
        probe = f"probe-{k}"
        eyes = subscriber(["stream.*.eye_states"])
        command(CreateAgent(agent=probe, request_id=f"p{k}"))
        collect(eyes, lambda got: sum(probe in agents_of(m) for m in got) >= 2)
        command(RemoveAgent(agent=probe, request_id=f"q{k}"))
        since = time.monotonic_ns()
        beaten: set[str] = set()

        def all_beaten(got: list[Message]) -> bool:
            last = got[-1] if got else None
            if isinstance(last, Heartbeat) and last.t_ns > since:
                beaten.add(last.service)
            return beaten >= set(pids)

        collect(answers, all_beaten)
        return {name: rss_kb(pid) for name, pid in pids.items()}

    for k in range(20):  # warm up: first imports, first allocations, caches filled
        cycle(-1 - k)
    before = settled(0)
    for k in range(LOOPS):
        cycle(k)
    after = settled(1)
    grown = {name: after[name] - before[name] for name in pids}
    print(f"resident memory before and after {LOOPS} visitors (KB): {before} -> {after}")
    for name in ("broker", "dialogue", "gaze"):
        assert grown[name] < GROWTH_LIMIT_KB, f"{name} grew by {grown[name]} KB over {LOOPS} visitors"
    assert instance.pid("dialogue") == pids["dialogue"], "the dialogue service was restarted meanwhile"


# --- restarts and late joiners -----------------------------------------------------------------------


def test_a_restarted_dialogue_service_keeps_the_created_agents(instance: Instance, config: BusConfig) -> None:
    with AgentClient(config, agent="page-k", timeout_s=20.0) as page:
        create(page, like="bob")
        page.wait_applied(page.set_emotion("surprised", 0.6))
        listing = agents_state(config)
        start = len(instance.reader.lines)
        old = instance.pid("dialogue")
        os.kill(old, signal.SIGKILL)
        instance.reader.wait_for("dialogue is back", 30.0, start)
        assert instance.pid("dialogue") != old
        # a command it must handle: the new instance serves the created agent
        page.wait_applied(page.set_role("silence"), 20.0)
        listing_now = agents_state(config)
        assert (listing_now.agents, listing_now.created, listing_now.like) == (
            listing.agents, listing.created, listing.like)
        with AgentClient(config, agent="page-k") as late:
            assert late.state["emotion"].name == "surprised"  # type: ignore[attr-defined]
            assert late.state["role"].role == "silence"  # type: ignore[attr-defined]
        remove(page)
    assert "page-k" not in agents_state(config).agents


def test_a_rig_started_late_follows_the_created_agents(instance: Instance, config: BusConfig, bus_io) -> None:
    _, subscriber = bus_io
    with AgentClient(config, agent="page-g") as page:
        create(page)
        argv = eca_command("rig", "--config", str(config.config_path), "--instance", config.instance, "--rate", "30")
        with running(argv) as (_, reader):
            reader.wait_for("[rig] INFO ready (pid", 60.0)
            rig = subscriber(["stream.page-g.rig", "stream.ada.rig"])
            collect(rig, lambda got: sum(isinstance(m, RigPose) and m.agent == "page-g" for m in got) >= 3)
            with AgentClient(config, agent="page-h") as other:
                create(other)  # one created while it runs
                late = subscriber(["stream.page-h.rig"])
                collect(late, lambda got: len(got) >= 3)
                remove(other)
            remove(page)
            stopped(rig, "page-g", "ada")
            assert not [line for line in reader.lines if "ERROR" in line or "Traceback" in line]
