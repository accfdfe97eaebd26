"""State that outlives a broker: publishers see a new broker, owners publish their state again, the cache
orders versions by time and stays bounded, and the dialogue service's state survives any restart.

These run the real broker and services in threads of the test process (tests/support/bus.py); the process
tests (test_field_processes.py) do the same with kill -9 on real processes.
"""

from __future__ import annotations

import time
from collections.abc import Iterator

import pytest
import zmq

from eca.agent.clock import VirtualClock
from eca.protocol.bus import Publisher, Subscriber
from eca.protocol.client import AgentClient
from eca.protocol.codec import encode
from eca.protocol.endpoints import BusConfig
from eca.protocol.messages import ALL_AGENTS, EmotionState, HeadState, Heartbeat, RoleState, Say, SpeechFailed
from eca.services.processes import broker as broker_module
from eca.services.processes.broker import Broker
from eca.services.processes.dialogue import DialogueService
from eca.services.processes.runtime import Service, wait_until
from eca.services.processes.state_snapshot import StateSnapshot, snapshot_path
from tests.support.bus import BrokerThread, ServiceThread, private_bus_config


@pytest.fixture
def config() -> Iterator[BusConfig]:
    with private_bus_config() as cfg:
        yield cfg


@pytest.fixture
def ctx() -> Iterator[zmq.Context]:
    context = zmq.Context()
    yield context
    context.term()


def test_seq_counts_per_topic_so_a_prefix_subscriber_sees_no_false_gaps(config: BusConfig, ctx) -> None:
    with BrokerThread(config):
        pub = Publisher(ctx, config, "counter")
        sub = Subscriber(ctx, config, ["state.ada.emotion"])
        try:
            pub.wait_ready()
            sub.wait_ready()
            for k in range(6):
                pub.publish(EmotionState(agent="ada", name="happy", intensity=k / 10))
                pub.publish(HeadState(agent="ada", turn=k / 10))  # another topic in between
            seqs = []
            while len(seqs) < 6:
                got = sub.recv(5.0)
                assert got is not None and got.message is not None
                seqs.append(got.message.seq)
            assert seqs == [1, 2, 3, 4, 5, 6]
        finally:
            pub.close()
            sub.close()


def test_a_publisher_notices_a_restarted_broker(config: BusConfig, ctx) -> None:
    pub = Publisher(ctx, config, "watcher")
    try:
        with BrokerThread(config):
            pub.wait_ready()
            assert not pub.new_broker()  # the first broker is no news
        assert not pub.new_broker()
        with BrokerThread(config):
            assert wait_until(pub.new_broker, 10.0)
            assert not pub.new_broker()  # told once
    finally:
        pub.close()


def _cache_after(broker: Broker, frames: list[list[bytes]]) -> dict[bytes, list[bytes]]:
    for f in frames:
        broker._forward(f)
    return broker.cache


def test_the_cache_keeps_the_newest_version_and_drops_stale_ones(config: BusConfig, ctx) -> None:
    broker = Broker(config, ctx)
    try:
        now = time.monotonic_ns()
        newer = EmotionState(agent="ada", name="happy", t_ns=now, source="dialogue")
        older = EmotionState(agent="ada", name="angry", t_ns=now - 1000, source="dialogue")
        topic = b"state.ada.emotion"
        cache = _cache_after(broker, [[topic, encode(newer)], [topic, encode(older)]])
        assert cache[topic][1] == encode(newer)
        assert broker.stale == 1  # neither cached nor forwarded
        future = EmotionState(agent="ada", name="surprised", t_ns=now + 60 * 10**9, source="x")
        _cache_after(broker, [[topic, encode(future)]])
        assert broker.cache[topic][1] == encode(newer)  # a state from the future cannot pin the topic
    finally:
        broker.close()


def test_the_cache_is_bounded_and_forgets_the_least_recently_changed(config: BusConfig, ctx,
                                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(broker_module, "MAX_CACHED_TOPICS", 3)
    broker = Broker(config, ctx)
    try:
        now = time.monotonic_ns()
        for k, agent in enumerate(["a1", "a2", "a3", "a1", "a4"]):
            msg = EmotionState(agent=agent, name="happy", t_ns=now + k)
            broker._forward([f"state.{agent}.emotion".encode(), encode(msg)])
        assert list(broker.cache) == [b"state.a3.emotion", b"state.a1.emotion", b"state.a4.emotion"]
    finally:
        broker.close()


def test_a_stopped_broker_leaves_no_socket_files_and_a_refused_one_removes_none(config: BusConfig, ctx) -> None:
    from eca.services.processes.broker import BrokerAlreadyRunning

    first = Broker(config, ctx)
    files = [config.runtime_dir / "pub", config.runtime_dir / "sub"]
    assert all(f.exists() for f in files)
    with pytest.raises(BrokerAlreadyRunning):
        Broker(config, ctx)
    assert all(f.exists() for f in files)  # the refused second broker touched nothing of the first
    first.close()
    assert not any(f.exists() for f in files)


def test_the_dialogue_state_is_back_in_a_new_brokers_cache(config: BusConfig) -> None:
    first_broker = BrokerThread(config).__enter__()
    with ServiceThread(DialogueService(config)):
        with AgentClient(config) as client:
            client.wait_applied(client.set_emotion("disappointed", 0.4))
            client.wait_applied(client.move_head(turn=0.3))
        first_broker.__exit__(None, None, None)
        with BrokerThread(config):  # the old broker is gone with its cache; the service lives on
            deadline = time.monotonic() + 10.0
            state: dict[str, object] = {}
            while time.monotonic() < deadline and not {"emotion", "head"} <= state.keys():
                with AgentClient(config) as fresh:  # the service sends its states again, one topic at a time
                    state = dict(fresh.state)
            emotion, head = state.get("emotion"), state.get("head")
            assert isinstance(emotion, EmotionState) and (emotion.name, emotion.intensity) == ("disappointed", 0.4)
            assert isinstance(head, HeadState) and head.turn == 0.3


def test_a_dialogue_service_restarted_with_the_broker_keeps_the_state(config: BusConfig) -> None:
    with BrokerThread(config), ServiceThread(DialogueService(config)), AgentClient(config) as client:
        client.wait_applied(client.set_emotion("frightened", 0.8))
        client.wait_applied(client.set_role("silence"))
    # both gone: the new broker's cache is empty, and only the snapshot remembers
    with BrokerThread(config), ServiceThread(DialogueService(config)) as second, AgentClient(config) as client:
        assert second.service.agents["ada"].emotion.name == "frightened"
        # from the new broker's cache, or as the restarted dialogue service publishes them (a loaded machine)
        assert client.expect_state(EmotionState, timeout_s=5.0).intensity == 0.8
        assert client.expect_state(RoleState, timeout_s=5.0).role == "silence"


def test_a_damaged_snapshot_costs_a_warning_not_the_service(config: BusConfig) -> None:
    snapshot_path(config).write_bytes(b"\x93\xc1 this is not a snapshot")
    with BrokerThread(config), ServiceThread(DialogueService(config)) as thread, AgentClient(config) as client:
        assert thread.service.agents["ada"].emotion.name == "natural"
        client.wait_applied(client.set_emotion("happy"))
    messages, _, problem = StateSnapshot(snapshot_path(config)).load()
    assert problem is None and any(isinstance(m, EmotionState) and m.name == "happy" for m in messages)


def test_a_silent_broker_does_not_make_the_dialogue_fail_its_requests(config: BusConfig) -> None:
    """While the broker is down the audio service's heartbeats cannot arrive; that is no reason to fail
    the requests it is playing. Once the broker beats again, a silent audio service is."""
    clock = VirtualClock(10**12)
    service = DialogueService(config, clock=clock)
    with BrokerThread(config):
        service.connect()
        try:

            def beat(name: str) -> None:
                service.on_heartbeat(Heartbeat(agent=ALL_AGENTS, service=name, pid=1, started_ns=7))

            beat("broker")
            beat("audio")
            service.on_say(Say(agent="ada", request_id="r1", audio_path="/a.wav"))
            service.after_batch()
            clock.advance_s(5.0)  # no beat from anyone: the bus is down
            service.on_tick(clock.now_ns())
            assert "r1" in service.agents["ada"].pending
            beat("broker")  # the bus is back, the audio service is still silent
            clock.advance_s(0.1)
            service.on_tick(clock.now_ns())
            assert "r1" not in service.agents["ada"].pending
            ending = service.agents["ada"].endings[-1]
            assert ending[:2] == ("r1", SpeechFailed.TYPE) and "stopped answering" in ending[3]
        finally:
            service.teardown()
            service.close()


def test_what_a_publisher_remembers_per_topic_is_bounded(monkeypatch: pytest.MonkeyPatch) -> None:
    """Peers choose topics (an error goes to the offending message's agent): a flood of new topics must
    not grow a publisher's counts without bound; a forgotten topic counts from 1 again."""
    from eca.protocol import bus

    monkeypatch.setattr(bus, "MAX_TOPICS_KEPT", 3)
    counts = bus.TopicCounts()
    for topic in ("error.a.error", "error.b.error", "error.a.error", "error.c.error", "error.d.error"):
        counts.sent(topic, counts.next(topic))
    assert len(counts._counts) == 3 and counts.next("error.a.error") == 1 and counts.next("error.d.error") == 2


def test_after_a_broker_restart_a_service_publishes_its_states_again_before_a_new_one(config: BusConfig) -> None:
    """A new broker's cache must get the older states first: a client that finds the newest there would
    otherwise find the others missing, until the service's loop came round to publishing them again."""
    order: list[str] = []

    class Remembering(Service):
        name = "remembering"

        def on_new_broker(self) -> None:
            order.append("the states again")

    service = Remembering(config)
    try:
        with BrokerThread(config):
            service.connect()
        with BrokerThread(config):
            assert service.pub is not None
            # the new broker's subscription waits, unread, at the publisher
            assert wait_until(lambda: service.pub is not None and service.pub.socket.poll(0) != 0, 10.0)
            service.publish(EmotionState(agent="ada", name="happy"))
            order.append("the new state")
    finally:
        service.close()
    assert order == ["the states again", "the new state"]
