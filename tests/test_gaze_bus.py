"""The gaze service on a real bus: a role change goes out as a saccade at once, not at the next tick."""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np
import zmq

from eca.agent.gaze.synth import eye_position_at
from eca.protocol.bus import Publisher, Subscriber
from eca.protocol.messages import EyeStates, HeadState, RoleState, Saccade
from eca.services.processes.gaze import GazeService
from tests.support.bus import BrokerThread, ServiceThread, private_bus_config

# Scheduled ticks 20 s apart: a saccade within the test's few seconds can only come from the reaction.
SLOW_TICKS = "[gaze]\nrate_hz = 0.05\nseed = 3\n"


@contextmanager
def gaze_service(topics: list[str], agents: list[str] | None = None) -> Iterator[tuple[Subscriber, Publisher]]:
    """A gaze service with slow scheduled ticks on a private bus; a subscriber to `topics` and a publisher
    standing in for the dialogue service."""
    with private_bus_config(agents=agents, extra=SLOW_TICKS) as config, BrokerThread(config):
        ctx = zmq.Context()
        sub = Subscriber(ctx, config, topics)
        dialogue = Publisher(ctx, config, "dialogue")
        try:
            sub.wait_ready()
            dialogue.wait_ready()
            with ServiceThread(GazeService(config)):
                yield sub, dialogue
        finally:
            sub.close()
            dialogue.close()
            ctx.term()


def test_a_role_change_is_published_before_the_next_scheduled_tick() -> None:
    with gaze_service(["event.ada.saccade", "stream.*.eye_states"]) as (sub, dialogue):
        onsets = []
        for role in ("talking", "listening", "talking"):
            role_state = dialogue.publish(RoleState(agent="ada", role=role))
            deadline = time.monotonic() + 5.0
            saccade: Saccade | None = None
            eye: EyeStates | None = None
            while (saccade is None or eye is None) and (left := deadline - time.monotonic()) > 0:
                received = sub.recv(left)
                if received is None:
                    break
                m = received.message
                if isinstance(m, Saccade) and m.onset_ns >= role_state.t_ns:
                    saccade = m
                if isinstance(m, EyeStates) and m.t_ns >= role_state.t_ns and "ada" in m.agents:
                    eye = m
            assert saccade is not None, f"no saccade for the change to {role} before the next tick"
            assert eye is not None, f"no eye state after the change to {role}"
            k = eye.agents.index("ada")
            # the eye state published with the reaction is already on the new saccade
            expected = eye_position_at(
                eye.t_ns,
                saccade.onset_ns,
                (saccade.from_yaw_deg, saccade.from_pitch_deg),
                (saccade.to_yaw_deg, saccade.to_pitch_deg),
                saccade.duration_s,
            )
            assert np.allclose((eye.yaw_deg[k], eye.pitch_deg[k]), expected, atol=1e-9)
            onsets.append(saccade.onset_ns)
        assert len(set(onsets)) == 3


def test_a_reaction_sends_the_eye_state_of_the_agent_it_concerns_only() -> None:
    # bob comes first in the agent list, so a reaction tick that sent his eye state would send it before ada's
    # (a head move concerns its agent only; a role change is a turn, which also turns the other's eyes)
    with gaze_service(["stream.*.eye_states"], agents=["bob", "ada"]) as (sub, dialogue):
        for turn in (0.3, -0.3, 0.2):
            role_state = dialogue.publish(HeadState(agent="ada", turn=turn))
            deadline = time.monotonic() + 5.0
            after: list[EyeStates] = []
            while not any("ada" in m.agents for m in after) and (left := deadline - time.monotonic()) > 0:
                received = sub.recv(left)
                if received is not None and isinstance(received.message, EyeStates):
                    if received.message.t_ns >= role_state.t_ns:
                        after.append(received.message)
            assert [m.agents for m in after] == [["ada"]], f"eye states after the head move {turn}: {after}"
