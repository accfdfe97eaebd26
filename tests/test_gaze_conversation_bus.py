"""The gaze service hosts the conversation on a real bus: turns turn the listeners toward the speaker
(attention states, as the model decides them), and the user's pauses get the listeners' backchannel nods."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager

import zmq

from eca.agent.clock import VirtualClock
from eca.agent.gaze.backchannel import USER, Backchannel
from eca.agent.gaze.backchannel import Nod as NodAction
from eca.agent.gaze.situated import Conversation, HeadTurn
from eca.protocol.bus import Publisher, Subscriber
from eca.protocol.messages import AttentionState, EmotionState, Error, EyesState, Message, Nod, RoleState, UserSpeech
from eca.services.processes.gaze import GazeService
from tests.support.bus import BrokerThread, ServiceThread, private_bus_config

AGENTS = ["ada", "bob", "cy"]
SEED = 14  # its first pause draws nods from ada and bob
NS = 1_000_000_000


@contextmanager
def conversation_bus(clock: VirtualClock) -> Iterator[tuple[Subscriber, Publisher]]:
    extra = f"[gaze]\nrate_hz = 60\nseed = {SEED}\n"
    with private_bus_config(agents=AGENTS, extra=extra) as config, BrokerThread(config):
        ctx = zmq.Context()
        topics = [f"state.{a}.attention" for a in AGENTS] + [f"event.{a}." for a in AGENTS] + ["error."]
        sub = Subscriber(ctx, config, topics)
        dialogue = Publisher(ctx, config, "dialogue")
        try:
            sub.wait_ready()
            dialogue.wait_ready()
            with ServiceThread(GazeService(config, clock=clock)):
                yield sub, dialogue
        finally:
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
    return got


def handled(sub: Subscriber, dialogue: Publisher, mark: str) -> list[Message]:
    """A barrier: an emotion the gaze service refuses is answered by an error at once, so everything the
    same publisher sent before it has been handled. Returns what came meanwhile."""
    dialogue.publish(EmotionState(agent="ada", name=mark))
    got = collect(sub, lambda m: any(isinstance(x, Error) and mark in x.reason for x in m))
    assert any(isinstance(x, Error) and mark in x.reason for x in got), "the gaze service did not answer"
    return got


def test_a_turn_turns_the_listeners_toward_the_speaker_as_the_model_decides() -> None:
    expected = [a for a in Conversation(AGENTS, SEED).start_turn(0, "ada", ["bob"]) if isinstance(a, HeadTurn)]
    assert {a.agent for a in expected} == set(AGENTS)  # everyone's head turns: bob and cy to ada, ada to bob
    with conversation_bus(VirtualClock(10 * NS)) as (sub, dialogue):
        dialogue.publish(RoleState(agent="ada", role="talking", speaker="ada", set_by="speech", addressees=["bob"]))
        got = collect(sub, lambda m: len([x for x in m if isinstance(x, AttentionState)]) >= len(expected))
    states = {m.agent: m for m in got if isinstance(m, AttentionState)}
    assert set(states) == set(AGENTS), got
    assert states["bob"].person == "ada" and states["cy"].person == "ada" and states["ada"].person == "bob"
    for turn in expected:
        s = states[turn.agent]
        assert (s.yaw_deg, s.pitch_deg, s.duration_s) == (turn.yaw_deg, turn.pitch_deg, turn.duration_s)
    # the screen order: ada is on bob's and cy's right-hand side as they face the user (positive yaw)
    assert states["bob"].yaw_deg > 0 and states["cy"].yaw_deg > states["bob"].yaw_deg and states["ada"].yaw_deg < 0


def test_the_user_s_pause_gets_the_nods_the_model_draws() -> None:
    model = Backchannel(AGENTS, SEED)
    model.speaking(0, USER, True)
    model.speaking(NS, USER, False)
    expected = [a for a in model.due(3 * NS) if isinstance(a, NodAction)]
    assert expected, "pick a seed whose first pause draws a nod"
    clock = VirtualClock(10 * NS)
    with conversation_bus(clock) as (sub, dialogue):
        dialogue.publish(UserSpeech(agent="ada", speaking=True), category="event")
        handled(sub, dialogue, "mark1")
        clock.advance_s(1.0)
        dialogue.publish(UserSpeech(agent="ada", speaking=False), category="event")
        handled(sub, dialogue, "mark2")
        clock.advance_s(2.0)
        got = collect(sub, lambda m: len([x for x in m if isinstance(x, Nod)]) >= len(expected))
    nods = sorted((m for m in got if isinstance(m, Nod)), key=lambda m: m.agent)
    want = sorted(expected, key=lambda a: a.agent)
    assert [(n.agent, n.amplitude_deg, n.duration_s) for n in nods] == \
        [(a.agent, a.amplitude_deg, a.duration_s) for a in want]
    assert all(n.reason == "backchannel" for n in nods)


def test_an_agent_that_talks_does_not_nod_at_the_user_s_pause() -> None:
    seed_model = Backchannel(AGENTS, SEED)
    seed_model.speaking(0, USER, True)
    seed_model.speaking(0, "ada", True)
    seed_model.speaking(NS, USER, False)
    expected = {a.agent for a in seed_model.due(3 * NS) if isinstance(a, NodAction)}
    assert "ada" not in expected and expected  # (silent, ada would nod at this pause: the test above)
    clock = VirtualClock(10 * NS)
    with conversation_bus(clock) as (sub, dialogue):
        dialogue.publish(UserSpeech(agent="ada", speaking=True), category="event")
        dialogue.publish(RoleState(agent="ada", role="talking", speaker="ada", set_by="speech"))
        handled(sub, dialogue, "mark3")
        clock.advance_s(1.0)
        dialogue.publish(UserSpeech(agent="ada", speaking=False), category="event")
        handled(sub, dialogue, "mark4")
        clock.advance_s(2.0)
        got = handled(sub, dialogue, "mark5")  # ticks have run past every nod's time
        got += collect(sub, lambda m: len([x for x in m if isinstance(x, Nod)]) >= len(expected), timeout_s=2.0)
    assert {m.agent for m in got if isinstance(m, Nod)} == expected


def test_an_agent_in_one_of_the_paper_s_conditions_does_not_backchannel() -> None:
    model = Backchannel(AGENTS, SEED)
    model.speaking(0, USER, True)
    model.speaking(NS, USER, False)
    expected = {a.agent for a in model.due(3 * NS) if isinstance(a, NodAction)} - {"ada"}
    assert expected == {"bob"}
    clock = VirtualClock(10 * NS)
    with conversation_bus(clock) as (sub, dialogue):
        dialogue.publish(EyesState(agent="ada", mode="saccade+blink"))
        dialogue.publish(UserSpeech(agent="ada", speaking=True), category="event")
        handled(sub, dialogue, "mode")
        clock.advance_s(1.0)
        dialogue.publish(UserSpeech(agent="ada", speaking=False), category="event")
        handled(sub, dialogue, "stop")
        clock.advance_s(2.0)
        got = handled(sub, dialogue, "after")  # ticks have run past every nod's time
        got += collect(sub, lambda m: any(isinstance(x, Nod) for x in m), timeout_s=2.0)
        got += collect(sub, lambda m: False, timeout_s=0.3)  # anything else still on its way
    assert {m.agent for m in got if isinstance(m, Nod)} == expected
