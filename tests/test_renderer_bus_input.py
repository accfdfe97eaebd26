"""The renderer's bus input without drawing: how a batch read off the socket is filtered and applied."""

from __future__ import annotations

import time

import pytest
import zmq

from eca.protocol.bus import Publisher, Received, Subscriber
from eca.protocol.messages import ClockAnchor, EmotionState, MouthKeys, SpeechFailed, SpeechStarted
from eca.protocol.topics import topic_for
from eca.services.processes.renderer.options import RendererOptions
from eca.services.processes.renderer.service import RendererService
from tests.support.bus import BrokerThread, private_bus_config

pytestmark = pytest.mark.gl  # draws: the renderer's compiled code is loaded first (conftest.py)


def drain_until(svc: RendererService, predicate, timeout_s: float = 5.0) -> bool:  # noqa: ANN001
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        assert svc.sub is not None
        if svc.sub.socket.poll(50, zmq.POLLIN):
            svc.drain()
        if predicate():
            return True
    return predicate()


def test_a_restarted_publisher_s_new_state_is_applied_even_when_its_seq_repeats() -> None:
    # A restarted dialogue service counts seq from 1 again: only a byte-identical repeat is a re-send.
    with private_bus_config() as config, BrokerThread(config):
        ctx = zmq.Context()
        svc = RendererService(config, RendererOptions(mode="headless", idle_noise=False, progress=False,
                                                      agents=("ada",)))
        scene = svc.views[0].scene
        old = Publisher(ctx, config, "dialogue")
        new = None
        try:
            svc.sub = Subscriber(ctx, config, svc.subscriptions())
            svc.sub.wait_ready()
            old.wait_ready()
            old.publish(EmotionState(agent="ada", name="happy", transition_s=0.0))
            assert drain_until(svc, lambda: scene.emotion[0] == "happy")
            old.close()
            new = Publisher(ctx, config, "dialogue")
            new.wait_ready()
            stamped = new.publish(EmotionState(agent="ada", name="angry", transition_s=0.0))
            assert stamped.seq == 1
            assert drain_until(svc, lambda: scene.emotion[0] == "angry"), scene.emotion
        finally:
            for sock in (old, new, svc.sub):
                if sock is not None:
                    sock.close()
            ctx.term()


def test_the_mouth_closes_when_speech_fails_mid_utterance() -> None:
    # The audio service died while speaking: no reset and no played_s come, only the dialogue
    # service's speech_failed. The keys were sent ahead for the whole file; the mouth must stop with
    # the voice (its last clock anchor), not run on through them.
    s = 1_000_000_000
    with private_bus_config() as config:
        svc = RendererService(config, RendererOptions(mode="headless", idle_noise=False, progress=False,
                                                      agents=("ada",)))
        scene = svc.views[0].scene
        n = 200  # 2 s of 10 ms keys at 16 kHz
        for msg in (
            MouthKeys(agent="ada", request_id="u1", sample_rate=16_000, sample_index=[160 * k for k in range(n)],
                      weights={"say_ah": [0.5] * n}),
            SpeechStarted(agent="ada", request_id="u1", dac_time_ns=10 * s),
            ClockAnchor(agent="ada", request_id="u1", sample_index=0, sample_rate=16_000, dac_time_ns=10 * s),
            ClockAnchor(agent="ada", request_id="u1", sample_index=8_000, sample_rate=16_000,
                        dac_time_ns=10 * s + s // 2),
        ):
            svc.dispatch(Received(topic_for(msg), msg))
        assert scene.mouth_at(11 * s) is not None  # still speaking, as far as anyone knows
        failed = SpeechFailed(agent="ada", request_id="u1", reason="the audio service stopped answering",
                              t_ns=12 * s)
        svc.dispatch(Received(topic_for(failed), failed))
        assert sum(svc.bad_messages.values()) == 0
        assert scene.mouth_at(10 * s + s // 4) is not None  # what was heard stays as it was
        assert scene.mouth_at(11 * s) is None
        assert scene.mouth_at(12 * s + s // 2) is None
