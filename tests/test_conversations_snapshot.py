"""Agents created at run time outlive a restart of the dialogue service together with the broker (whose cache is
then empty): the dialogue's snapshot on disk holds them, their states and the list of agents; a removed one is
gone from it. And the [conversations] table of the config is checked."""

from __future__ import annotations

import time
from collections.abc import Iterator

import msgpack
import pytest
import zmq

from eca.protocol.bus import Subscriber
from eca.protocol.client import AgentClient
from eca.protocol.codec import decode
from eca.protocol.endpoints import BusConfig, BusConfigError
from eca.protocol.messages import ALL_AGENTS, AgentsState, CreateAgent, EmotionState, RemoveAgent
from eca.services.processes.dialogue import DialogueService
from eca.services.processes.state_snapshot import StateSnapshot, snapshot_path
from tests.support.bus import BrokerThread, ServiceThread, private_bus_config


@pytest.fixture
def config() -> Iterator[BusConfig]:
    with private_bus_config(agents=["ada", "bob"], extra="[conversations]\nmax = 4\ntemplate = \"bob\"\n") as cfg:
        yield cfg


def send(client: AgentClient, msg: CreateAgent | RemoveAgent) -> None:
    client.wait_applied(client.send(msg))


def test_a_dialogue_service_restarted_with_the_broker_keeps_the_created_agents(config: BusConfig) -> None:
    with BrokerThread(config), ServiceThread(DialogueService(config)):
        with AgentClient(config, agent="v1") as v1, AgentClient(config, agent="v2") as v2:
            send(v1, CreateAgent(agent="v1", request_id="c1"))
            send(v2, CreateAgent(agent="v2", request_id="c2", like="ada"))
            v1.wait_applied(v1.set_emotion("annoyed", 0.7))
            send(v2, RemoveAgent(agent="v2", request_id="r2"))
    saved, _, problem = StateSnapshot(snapshot_path(config)).load()
    assert problem is None and not [m for m in saved if m.agent == "v2"]
    [listing] = [m for m in saved if isinstance(m, AgentsState)]
    assert (listing.agents, listing.created, listing.like) == (["ada", "bob", "v1"], ["v1"], ["bob"])
    # both gone: the new broker's cache is empty, and only the snapshot remembers
    with BrokerThread(config), ServiceThread(DialogueService(config)) as second:
        service = second.service
        assert isinstance(service, DialogueService)
        assert service.created == {"v1": "bob"} and service.agents["v1"].emotion.name == "annoyed"
        with AgentClient(config, agent="v1") as v1:
            # the restarted service publishes what it adopted into the new broker's cache; a client may come first
            emotion = v1.state.get("emotion") or v1.expect_state(EmotionState, timeout_s=5.0)
            assert isinstance(emotion, EmotionState) and emotion.intensity == 0.7
            v1.wait_applied(v1.set_role("silence"))  # served by the new instance
            send(v1, RemoveAgent(agent="v1", request_id="r1"))
        assert service.created == {} and "v1" not in service.agents


def test_the_snapshot_holds_each_state_as_the_bus_carried_it(config: BusConfig) -> None:
    # the snapshot keeps the bytes each state was published as (not a copy encoded again per batch): a new broker
    # and a successor get exactly what subscribers saw
    ctx = zmq.Context()
    with BrokerThread(config), ServiceThread(DialogueService(config)):
        sub = Subscriber(ctx, config, ["state."])
        try:
            sub.wait_ready()
            with AgentClient(config, agent="v1") as v1:
                send(v1, CreateAgent(agent="v1", request_id="c1"))
                v1.wait_applied(v1.set_emotion("annoyed", 0.7))
                v1.wait_applied(v1.set_role("silence"))
                v1.wait_applied(v1.set_emotion("surprised", 0.4))
            carried: set[bytes] = set()
            deadline = time.monotonic() + 10.0
            while True:
                carried.update(payload for _, payload in sub.read_frames(1000))
                raw = msgpack.unpackb(snapshot_path(config).read_bytes(), raw=False)
                # v1's states and the list of agents: all published after this subscriber was ready
                later = [m for m in raw["messages"] if decode(m).agent in ("v1", ALL_AGENTS)]
                if set(later) <= carried or time.monotonic() > deadline:
                    break
                sub.socket.poll(100)
        finally:
            sub.close()
            ctx.term()
    assert len(later) >= 4  # emotion, role and more of v1, and the list
    missing = [m for m in later if m not in carried]
    assert not missing, f"{len(missing)} of {len(later)} snapshot states are not what the bus carried"
    saved, _, problem = StateSnapshot(snapshot_path(config)).load()
    emotion = next(m for m in saved if m.agent == "v1" and m.TYPE == "emotion")
    assert problem is None and emotion.name == "surprised"  # type: ignore[attr-defined]


@pytest.mark.parametrize(("table", "says"), [
    ("max = -1", "'max' must be an integer in 0..256"),
    ("max = 1000", "'max' must be an integer in 0..256"),
    ("max = \"sixty\"", "'max' must be an integer in 0..256"),
    ("template = \"zed\"", "'template' must be one of the configured agents (ada)"),
])
def test_a_bad_conversations_table_is_one_clear_error(table: str, says: str,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    with private_bus_config(extra=f"[conversations]\n{table}\n") as cfg:
        with pytest.raises(BusConfigError, match=r"\[conversations\]"):
            DialogueService(cfg)
        with pytest.raises(SystemExit) as stopped:
            DialogueService.from_args(cfg, [])
    assert stopped.value.code == 2
    err = capsys.readouterr().err
    assert "[dialogue] ERROR" in err and says in err


def test_the_shipped_config_allows_sixty_conversations_like_the_first_agent() -> None:
    with private_bus_config(agents=["bob", "ada"]) as cfg:
        service = DialogueService(cfg)
    assert (service.max_created, service.template) == (60, "bob")


def test_the_protocol_s_bound_on_live_agents_holds_every_configured_and_created_one() -> None:
    from eca.protocol.endpoints import MAX_AGENTS
    from eca.protocol.messages import MAX_CREATED_AGENTS, MAX_LIVE_AGENTS

    assert MAX_AGENTS + MAX_CREATED_AGENTS == MAX_LIVE_AGENTS
