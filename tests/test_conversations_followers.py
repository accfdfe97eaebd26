"""The services that follow the live agents (`state.*.agents`), each on a real broker with a publisher standing in
for the dialogue service: the live scenes (scene/bus_scene.py, as the renderer, rig and web services use them),
the gaze service (a slot pool in the engine, a conversation of its own per created agent) and the audio service
(a player per created agent, its requests ended once when it goes)."""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager

import pytest
import zmq

from eca.protocol.bus import Publisher, Subscriber
from eca.protocol.endpoints import BusConfig
from eca.protocol.messages import (
    ALL_AGENTS,
    AgentsState,
    AttentionState,
    EmotionState,
    Error,
    EyeStates,
    Interrupt,
    Message,
    PlaybackState,
    RoleState,
    Say,
    SpeechInterrupted,
    SpeechStarted,
)
from eca.services.processes.audio.service import AudioService
from eca.services.processes.audio.sinks import NullSink
from eca.services.processes.gaze import GazeService
from eca.services.processes.runtime import Service, wait_until
from eca.services.processes.scene.bus_scene import BusScenes, agent_topics
from tests.support.bus import BrokerThread, ServiceThread, private_bus_config

NS = 1_000_000_000


def listing(configured: list[str], created: list[str]) -> AgentsState:
    return AgentsState(agent=ALL_AGENTS, agents=[*configured, *created], created=created,
                       like=[configured[0]] * len(created), max_created=60)


@contextmanager
def bus(agents: list[str], extra: str = "") -> Iterator[tuple[BusConfig, Publisher, Callable[[list[str]], Subscriber]]]:
    """A private bus, a publisher that calls itself the dialogue service, and ready subscribers on demand."""
    with private_bus_config(agents=agents, extra=extra) as config, BrokerThread(config):
        ctx = zmq.Context()
        dialogue = Publisher(ctx, config, "dialogue")
        dialogue.wait_ready()
        subs: list[Subscriber] = []

        def subscriber(prefixes: list[str]) -> Subscriber:
            sub = Subscriber(ctx, config, prefixes)
            sub.wait_ready()
            subs.append(sub)
            return sub

        try:
            yield config, dialogue, subscriber
        finally:
            for sub in subs:
                sub.close()
            dialogue.close()
            ctx.term()


def collect(sub: Subscriber, done: Callable[[list[Message]], bool], timeout_s: float = 5.0) -> list[Message]:
    got: list[Message] = []
    deadline = time.monotonic() + timeout_s
    while not done(got) and (left := deadline - time.monotonic()) > 0:
        received = sub.recv(left)
        if received is not None and received.message is not None:
            got.append(received.message)
    assert done(got), f"not there within {timeout_s} s: {got[-5:]}"
    return got


# --- the live scenes --------------------------------------------------------------------------------------


class SceneService(Service):
    """A service that feeds live scenes, as the rig and web services do (without drawing anything). Following by
    hand (`follow` off), its hook adds each created agent and drops each removed one, as a web service would for
    the agents its pages watch: on the service's own thread, which owns the socket."""

    name = "scenes"

    def __init__(self, config: BusConfig, agents: list[str], follow: bool) -> None:
        super().__init__(config)
        self.scenes = BusScenes(self, agents, idle_noise=False, follow=follow)
        self.heard: list[AgentsState] = []
        self.removed: list[tuple[str, bool]] = []  # (agent, whether remove_agent found a scene), by hand
        self.scenes.on_agents = self.on_agents

    def on_agents(self, listing: AgentsState) -> None:
        self.heard.append(listing)
        if self.scenes.follow:
            return
        for view in list(self.scenes.views):
            if view.agent not in listing.agents:
                self.removed.append((view.agent, self.scenes.remove_agent(view.agent)))
                self.removed.append((view.agent, self.scenes.remove_agent(view.agent)))
        for agent in listing.created:
            self.scenes.add_agent(agent)

    def subscriptions(self) -> list[str]:
        return self.scenes.subscriptions()

    def run_once(self) -> None:
        assert self.sub is not None
        self.beat_if_due(self.clock.now_ns())
        if self.sub.socket.poll(20):
            self.scenes.drain()


def emotion_of(service: SceneService, agent: str) -> tuple[str, float] | None:
    view = service.scenes.by_agent.get(agent)
    return None if view is None else view.scene.emotion


def eye_mode_of(service: SceneService, agent: str) -> str | None:
    view = service.scenes.by_agent.get(agent)
    return None if view is None else view.scene.eye_mode


@pytest.mark.parametrize("follow", [True, False], ids=["follow", "by hand"])
def test_scenes_add_each_created_agent_with_its_cached_state_and_drop_it_again(follow: bool) -> None:
    with bus(["ada"]) as (config, dialogue, _):
        service = SceneService(config, ["ada"], follow=follow)
        assert service.scenes.subscriptions()[-1] == f"state.{ALL_AGENTS}.agents"
        with ServiceThread(service):
            dialogue.publish(EmotionState(agent="v1", name="happy", intensity=0.5, transition_s=0.0))
            dialogue.publish(listing(["ada"], ["v1"]))  # the new agent's state came first: the cache has it
            assert wait_until(lambda: emotion_of(service, "v1") == ("happy", 0.5), 5.0)
            assert [v.agent for v in service.scenes.views] == ["ada", "v1"] and service.scenes.live == ("ada", "v1")
            dialogue.publish(EyeStates(agent=ALL_AGENTS, agents=["v1"], yaw_deg=[5.0], pitch_deg=[0.0], lid=[0.0],
                                       mode=["static"]))
            assert wait_until(lambda: eye_mode_of(service, "v1") == "static", 5.0)  # its eyes reach its new scene
            dialogue.publish(listing(["ada"], []))
            assert wait_until(lambda: "v1" not in service.scenes.by_agent, 5.0)
            # what is still on its way for it is dropped without a word (ada's emotion, sent after it, marks the
            # point where the scenes have read it, if it came at all)
            dialogue.publish(EmotionState(agent="v1", name="angry"))
            dialogue.publish(EmotionState(agent="ada", name="annoyed", intensity=1.0, transition_s=0.0))
            assert wait_until(lambda: emotion_of(service, "ada") == ("annoyed", 1.0), 5.0)
            assert sum(service.bad_messages.values()) == 0
            assert [v.agent for v in service.scenes.views] == ["ada"]
            assert [m.agents for m in service.heard] == [["ada", "v1"], ["ada"]]
            assert service.removed == ([] if follow else [("v1", True), ("v1", False)])


def test_scenes_that_neither_follow_nor_listen_subscribe_as_before() -> None:
    with private_bus_config() as config:
        service = SceneService(config, ["ada"], follow=False)
    plain = BusScenes(service, ["ada", "bob"])  # a renderer's: no follow, no hook
    assert plain.subscriptions() == ["stream.*.eye_states", *agent_topics("ada"), *agent_topics("bob")]


# --- the gaze service ---------------------------------------------------------------------------------------


def test_the_gaze_engine_reuses_the_slots_of_removed_agents_and_each_created_one_looks_alone() -> None:
    with bus(["ada", "bob"], "[gaze]\nrate_hz = 30\nseed = 3\n") as (config, dialogue, subscriber):
        service = GazeService(config)
        with ServiceThread(service):
            eyes = subscriber(["stream.", "state.", "error."])
            dialogue.publish(listing(["ada", "bob"], ["v1", "v2"]))
            collect(eyes, lambda got: {a for m in got if isinstance(m, EyeStates) for a in m.agents}
                    >= {"ada", "bob", "v1", "v2"})
            assert service.engine.n_agents == 4
            for k in range(10):  # visitors come and go: the engine never grows past the most alive at once
                dialogue.publish(listing(["ada", "bob"], ["v2", f"w{k}"]))
            dialogue.publish(listing(["ada", "bob"], ["v2", "v3"]))
            got = collect(eyes, lambda got: any(isinstance(m, EyeStates) and "v3" in m.agents for m in got))
            assert service.engine.n_agents == 4 and sorted(service.index) == ["ada", "bob", "v2", "v3"]
            assert not [m for m in got if isinstance(m, Error)], got
            # a removed agent's eyes stop: a whole tick of every live agent's, and none of v1's in it
            tick = {"ada", "bob", "v2", "v3"}

            def whole_tick(got: list[Message]) -> bool:
                if not got or not isinstance(got[-1], EyeStates):
                    return False
                agents = set(got[-1].agents)
                assert agents <= tick | {"v1"} or any(a.startswith("w") for a in agents), agents
                return agents == tick

            collect(eyes, whole_tick)
            # a created agent talks with its own user only: nobody else turns to it, it turns to nobody
            dialogue.publish(RoleState(agent="v3", role="talking", speaker="v3", set_by="speech"))
            dialogue.publish(RoleState(agent="ada", role="talking", speaker="ada", set_by="speech", addressees=["bob"]))
            got = collect(eyes, lambda got: {m.agent for m in got if isinstance(m, AttentionState)} >= {"ada", "bob"})
            assert {m.agent for m in got if isinstance(m, AttentionState)} == {"ada", "bob"}
            assert [m.person for m in got if isinstance(m, AttentionState) and m.agent == "bob"] == ["ada"]


# --- the audio service --------------------------------------------------------------------------------------


def pcm(seconds: float, rate: int = 16_000) -> bytes:
    samples = [round(0.2 * 32767 * math.sin(2 * math.pi * 220 * k / rate)) for k in range(int(seconds * rate))]
    return b"".join(s.to_bytes(2, "little", signed=True) for s in samples)


def test_the_audio_service_plays_for_a_created_agent_and_ends_its_requests_once_when_it_goes() -> None:
    with bus(["ada"]) as (config, dialogue, subscriber):
        service = AudioService(config, sink_factory=lambda: NullSink(48_000, 480))
        with ServiceThread(service):
            heard = subscriber(["audio.v1.", "state.v1.", "error."])
            got: list[Message] = []

            def hear(done: Callable[[list[Message]], bool]) -> None:
                got.extend(collect(heard, lambda new: done(got + new)))

            dialogue.publish(listing(["ada"], ["v1"]))
            hear(lambda all_: any(isinstance(m, PlaybackState) for m in all_))  # its player is there
            dialogue.publish(Say(agent="v1", request_id="r1", pcm=pcm(5.0), sample_rate=16_000), "play")
            hear(lambda all_: any(isinstance(m, SpeechStarted) for m in all_))
            dialogue.publish(listing(["ada"], []))
            hear(lambda all_: any(isinstance(m, SpeechInterrupted) for m in all_))
            assert wait_until(lambda: "v1" not in service.players, 5.0)
            # a request still on its way for it is dropped without a word, and so are its player's last reports
            # (a say of ada's after it, sent by the same publisher, marks the point where they would have come)
            dialogue.publish(Interrupt(agent="v1", request_id="r1"), "play")
            barrier = subscriber(["audio.ada."])
            dialogue.publish(Say(agent="ada", request_id="a1", pcm=pcm(0.05), sample_rate=16_000), "play")
            collect(barrier, lambda new: any(getattr(m, "request_id", "") == "a1" for m in new))
            got += heard.drain()
            endings = [m for m in got if m.TYPE.startswith("speech_") and m.TYPE != "speech_started"]
            assert [(m.TYPE, m.reason) for m in endings] == [("speech_interrupted", "the agent was removed")]  # type: ignore[attr-defined]
            assert not [m for m in got if isinstance(m, Error)], got
            # its playback state was published while it lived, never after
            last_playback = max(i for i, m in enumerate(got) if isinstance(m, PlaybackState))
            assert last_playback < got.index(endings[0]) and got[last_playback].request_ids == ["r1"]  # type: ignore[attr-defined]
