"""The audio service: plays the say requests the dialogue service accepted, and is the master clock.

One Player per agent. The player reports from its own publisher thread; zmq sockets must stay on
one thread, so its events go through a queue that this service's loop (ticking at 250 Hz) drains
and publishes: lifecycle on `audio.` (the dialogue service re-publishes it once per request), clock
anchors and mouth keys on `stream.`.
"""

from __future__ import annotations

import queue
from typing import Any

import numpy as np

from protocol.endpoints import BusConfig
from protocol.messages import MAX_PENDING_SAYS, Interrupt, Message, MouthKeys, PlaybackState, Say, SpeechChunk
from protocol.messages import ClockAnchor as ClockAnchorMsg
from protocol.messages import SpeechFailed as SpeechFailedMsg
from protocol.messages import SpeechFinished as SpeechFinishedMsg
from protocol.messages import SpeechInterrupted as SpeechInterruptedMsg
from protocol.messages import SpeechStarted as SpeechStartedMsg
from services.audio import events
from services.audio.config import AudioConfig
from services.audio.player import Player
from services.audio.sinks import Sink, open_sink
from services.runtime import Rejected, Service

MOUTH_KEYS_PER_MESSAGE = 2000  # 20 s of 10 ms keys: far under the message size cap


def pcm16_to_float(pcm: bytes) -> np.ndarray:
    return np.frombuffer(pcm, dtype="<i2").astype(np.float32) / 32768.0


class AudioService(Service):
    name = "audio"
    tick_hz = 250.0  # how promptly player events (anchors >= 60 Hz) leave the queue

    def __init__(self, config: BusConfig, sink_factory: Any = None, **kwargs: Any) -> None:
        super().__init__(config, **kwargs)
        self.agent_ids: list[str] = list(config.raw.get("agents", {}).get("ids", ["ada"]))
        self.audio_config = AudioConfig.load()
        self._sink_factory = sink_factory or (lambda: open_sink(config=self.audio_config, clock=self.clock))
        self.events: queue.SimpleQueue[events.AudioEvent] = queue.SimpleQueue()
        self.players: dict[str, Player] = {}
        self.stream_rates: dict[str, int] = {}
        self.interrupt_reasons: dict[str, str] = {}
        # Per agent, the requests taken and not yet ended (dict: insertion-ordered set), published as
        # state.<agent>.playback so a restarted dialogue service can tell which of its requests ended.
        self.held: dict[str, dict[str, None]] = {a: {} for a in self.agent_ids}
        for cls, handler in ((Say, self.on_say), (SpeechChunk, self.on_chunk), (Interrupt, self.on_interrupt)):
            self.handle(cls, handler)

    def subscriptions(self) -> list[str]:
        return [f"play.{a}." for a in self.agent_ids]

    def setup(self) -> None:
        for agent in self.agent_ids:
            sink: Sink = self._sink_factory()
            self.players[agent] = Player(sink, self.events.put, agent_id=agent, clock=self.clock,
                                         config=self.audio_config).start()
            self._publish_playback(agent)

    def teardown(self) -> None:
        for player in self.players.values():
            player.close()
        self.drain_events()

    def _player(self, msg: Message) -> Player:
        player = self.players.get(msg.agent)
        if player is None:
            raise Rejected(f"unknown agent '{msg.agent}'")
        return player

    def _publish_playback(self, agent: str) -> None:
        self.publish(PlaybackState(agent=agent, request_ids=list(self.held[agent]), started_ns=self.started_ns))

    def on_say(self, msg: Say) -> None:
        player = self._player(msg)
        held = self.held[msg.agent]
        # The dialogue service accepted the request, so a refusal here ends it like any failure: with a
        # speech_failed, which the dialogue service passes on once (an error would leave it pending there).
        if len(held) >= MAX_PENDING_SAYS:
            self._refuse(msg, f"the audio service already holds {MAX_PENDING_SAYS} say requests for this agent")
            return
        try:
            if msg.audio_path is not None:
                player.say_file(msg.request_id, msg.audio_path)
            elif msg.pcm is not None:
                player.say_pcm(msg.request_id, pcm16_to_float(msg.pcm), msg.sample_rate)
            else:
                player.say_stream(msg.request_id, msg.sample_rate)
        except ValueError as exc:
            self._refuse(msg, f"the audio service refused it: {exc}")
            return
        except Exception as exc:  # anything else still ends the request, so the client is not left waiting
            self.log.exception("cannot start %s", msg.request_id)
            self._refuse(msg, f"the audio service could not play it: {type(exc).__name__}: {exc}")
            return
        held[msg.request_id] = None  # a request the player failed at once leaves again with its event
        self._publish_playback(msg.agent)

    def _refuse(self, msg: Say, reason: str) -> None:
        self.log.warning("say request %s of %s not played: %s", msg.request_id, msg.agent, reason)
        self.publish(SpeechFailedMsg(agent=msg.agent, request_id=msg.request_id, reason=reason[:500]), "audio")

    def on_chunk(self, msg: SpeechChunk) -> None:
        player = self._player(msg)
        if not player.feed(msg.request_id, pcm16_to_float(msg.pcm), msg.last):
            raise Rejected(f"request '{msg.request_id}' is not streaming (finished or interrupted)", msg.request_id)

    def on_interrupt(self, msg: Interrupt) -> None:
        stopped = self._player(msg).interrupt(msg.request_id or None)
        for uid in stopped:
            self.interrupt_reasons[uid] = msg.reason

    def on_tick(self, now_ns: int) -> None:
        self.drain_events()

    def drain_events(self) -> None:
        while True:
            try:
                event = self.events.get_nowait()
            except queue.Empty:
                return
            for msg, category in self.to_messages(event):
                self.publish(msg, category)
            if isinstance(event, events.SpeechFinished | events.SpeechInterrupted | events.SpeechFailed):
                held = self.held.get(event.agent_id, {})
                if event.utterance_id in held:
                    del held[event.utterance_id]
                    self._publish_playback(event.agent_id)

    def to_messages(self, ev: events.AudioEvent) -> list[tuple[Message, str]]:
        agent = ev.agent_id
        if isinstance(ev, events.ClockAnchor):
            return [(ClockAnchorMsg(agent=agent, request_id=ev.utterance_id, sample_index=ev.sample_index,
                                    sample_rate=ev.sample_rate, dac_time_ns=max(0, ev.dac_time_ns)), "stream")]
        if isinstance(ev, events.MouthKeys):
            out: list[tuple[Message, str]] = []
            keys = ev.keys
            for start in range(0, len(keys), MOUTH_KEYS_PER_MESSAGE):
                part = keys[start:start + MOUTH_KEYS_PER_MESSAGE]
                names = list(part[0].weights) if part else []
                out.append((MouthKeys(agent=agent, request_id=ev.utterance_id, sample_rate=ev.sample_rate,
                                      sample_index=[k.sample_index for k in part],
                                      weights={n: [float(min(1.0, max(0.0, k.weights[n]))) for k in part]
                                               for n in names}), "stream"))
            return out
        if isinstance(ev, events.MouthReset):
            # stamped with the moment the voice stops at the DAC: the mouth closes from then on
            return [(MouthKeys(agent=agent, t_ns=max(0, ev.dac_time_ns), request_id=ev.utterance_id, sample_rate=1,
                               reset=True), "stream")]
        if isinstance(ev, events.SpeechStarted):
            return [(SpeechStartedMsg(agent=agent, request_id=ev.utterance_id,
                                      dac_time_ns=max(0, ev.dac_time_ns)), "audio")]
        if isinstance(ev, events.SpeechFinished):
            return [(SpeechFinishedMsg(agent=agent, request_id=ev.utterance_id, played_s=ev.played_s), "audio")]
        if isinstance(ev, events.SpeechInterrupted):
            reason = self.interrupt_reasons.pop(ev.utterance_id, "interrupted")
            return [(SpeechInterruptedMsg(agent=agent, request_id=ev.utterance_id, played_s=ev.played_s,
                                          reason=reason[:200]), "audio")]
        if isinstance(ev, events.SpeechFailed):
            return [(SpeechFailedMsg(agent=agent, request_id=ev.utterance_id, reason=ev.reason[:500]), "audio")]
        return []
