"""The gaze service on a real bus: a role change goes out as a saccade at once, not at the next tick."""

from __future__ import annotations

import time

import numpy as np
import zmq

from agent.gaze.synth import eye_position_at
from protocol.bus import Publisher, Subscriber
from protocol.messages import EyeState, RoleState, Saccade
from services.gaze import GazeService
from services.testing import BrokerThread, ServiceThread, private_bus_config

# Scheduled ticks 20 s apart: a saccade within the test's few seconds can only come from the reaction.
SLOW_TICKS = "[gaze]\nrate_hz = 0.05\nseed = 3\n"


def test_a_role_change_is_published_before_the_next_scheduled_tick() -> None:
    with private_bus_config(extra=SLOW_TICKS) as config, BrokerThread(config):
        ctx = zmq.Context()
        sub = Subscriber(ctx, config, ["event.ada.saccade", "stream.ada.eye_state"])
        dialogue = Publisher(ctx, config, "dialogue")
        try:
            sub.wait_ready()
            dialogue.wait_ready()
            with ServiceThread(GazeService(config)):
                onsets = []
                for role in ("talking", "listening", "talking"):
                    role_state = dialogue.publish(RoleState(agent="ada", role=role))
                    deadline = time.monotonic() + 5.0
                    saccade: Saccade | None = None
                    eye: EyeState | None = None
                    while (saccade is None or eye is None) and (left := deadline - time.monotonic()) > 0:
                        received = sub.recv(left)
                        if received is None:
                            break
                        m = received.message
                        if isinstance(m, Saccade) and m.onset_ns >= role_state.t_ns:
                            saccade = m
                        if isinstance(m, EyeState) and m.t_ns >= role_state.t_ns:
                            eye = m
                    assert saccade is not None, f"no saccade for the change to {role} before the next tick"
                    assert eye is not None, f"no eye state after the change to {role}"
                    # the eye state published with the reaction is already on the new saccade
                    expected = eye_position_at(
                        eye.t_ns,
                        saccade.onset_ns,
                        (saccade.from_yaw_deg, saccade.from_pitch_deg),
                        (saccade.to_yaw_deg, saccade.to_pitch_deg),
                        saccade.duration_s,
                    )
                    assert np.allclose((eye.yaw_deg, eye.pitch_deg), expected, atol=1e-9)
                    onsets.append(saccade.onset_ns)
                assert len(set(onsets)) == 3
        finally:
            sub.close()
            dialogue.close()
            ctx.term()
