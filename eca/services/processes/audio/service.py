"""The audio service: plays the say requests the dialogue service accepted, and is the master clock.

One Player per agent. The loop only files requests with the players: decoding, resampling and
lip-sync run on each player's preparer thread, so no handler's cost grows with the audio (inline PCM
is passed on as a view of the message's bytes) and the heartbeat, sent from this loop, never waits on
them. The player reports from its own publisher thread; zmq sockets must stay on one thread, so its
events go through a queue that this service's loop (ticking at 250 Hz) drains and publishes, a few
milliseconds' worth per tick: lifecycle on `audio.` (the dialogue service re-publishes it once per
request), clock anchors and mouth keys on `stream.`, and, with `[output] publish_voice` in
configs/audio.toml, the voice itself on `stream.<agent>.voice`: every block the output takes that sounds
(100 per second per speaking agent by default; silence is the gap between blocks), for outputs in other
processes such as the web service's audio track. They come from the player like the other events, so they
share the master clock: a block's `dac_time_ns` is the time the clock anchors give its first sample, and
an interruption shows as silence (no block) from the block where the voice stopped.

Agents created at run time (`state.*.agents`) get a player like the configured ones when the list names them,
and lose it (their voice stopped, its threads and output closed) when it no longer does. The service hears
every agent's `play.` requests: a request for an agent created a moment ago never waits on a subscription.
"""

from __future__ import annotations

import argparse
import queue
import time
from collections import OrderedDict, deque
from collections.abc import Callable
from typing import Any

import numpy as np

from eca.protocol.endpoints import BusConfig
from eca.protocol.messages import (
    ALL_AGENTS,
    MAX_PENDING_SAYS,
    RECENT_ENDINGS,
    TERMINAL_SPEECH_EVENTS,
    AgentsState,
    Interrupt,
    Message,
    MouthKeys,
    PlaybackState,
    Say,
    SpeechChunk,
    SpeechEnding,
)
from eca.protocol.messages import ClockAnchor as ClockAnchorMsg
from eca.protocol.messages import SpeechFailed as SpeechFailedMsg
from eca.protocol.messages import SpeechFinished as SpeechFinishedMsg
from eca.protocol.messages import SpeechInterrupted as SpeechInterruptedMsg
from eca.protocol.messages import SpeechStarted as SpeechStartedMsg
from eca.protocol.messages import VoiceBlock as VoiceBlockMsg
from eca.services.processes.audio import events
from eca.services.processes.audio.config import AudioConfig
from eca.services.processes.audio.output import open_sink
from eca.services.processes.audio.player import Player
from eca.services.processes.audio.sinks import Sink
from eca.services.processes.audio.tts import engine as tts_engine
from eca.services.processes.runtime import Rejected, Service, parse_service_args

MOUTH_KEYS_PER_MESSAGE = 2000  # 20 s of 10 ms keys: far under the message size cap
GONE_KEPT = 1024  # lately removed agents whose requests, still on their way, are dropped without a word
REMOVED_REASON = "the agent was removed"
DRAIN_BUDGET_S = 0.003  # per tick, publishing player events; what is left goes out at the next tick (4 ms)


def pcm16(pcm: bytes) -> np.ndarray:
    """The message's samples as int16, without copying: the player converts them slice by slice."""
    return np.frombuffer(pcm, dtype="<i2")


class AudioService(Service):
    name = "audio"
    tick_hz = 250.0  # how promptly player events (anchors >= 60 Hz) leave the queue

    def __init__(self, config: BusConfig, sink_factory: Any = None, silent: bool = False, **kwargs: Any) -> None:
        super().__init__(config, **kwargs)
        self.agent_ids: list[str] = list(config.agents)  # the configured agents; created ones come and go
        self.created: list[str] = []
        self._gone: OrderedDict[str, None] = OrderedDict()
        self.audio_config = AudioConfig.load()
        self.tts = tts_engine(self.audio_config.tts)  # voices a say that has text and no audio
        self._sink_factory = sink_factory or (
            lambda: open_sink(config=self.audio_config, clock=self.clock, silent=silent))
        self.events: queue.SimpleQueue[events.AudioEvent] = queue.SimpleQueue()
        self.players: dict[str, Player] = {}
        self.stream_rates: dict[str, int] = {}
        self.interrupt_reasons: dict[str, str] = {}
        # Per agent, the requests taken and not yet ended (dict: insertion-ordered set) and how the latest
        # ended, published as state.<agent>.playback: a restarted dialogue service, or one whose terminal
        # event was lost with a broker, learns from it which of its requests ended, and how.
        self.held: dict[str, dict[str, None]] = {a: {} for a in self.agent_ids}
        self.endings: dict[str, deque[tuple[str, SpeechEnding, float, str]]] = {
            a: deque(maxlen=RECENT_ENDINGS) for a in self.agent_ids}
        handlers: tuple[tuple[type[Any], Callable[[Any], None]], ...] = (
            (Say, self.on_say), (SpeechChunk, self.on_chunk), (Interrupt, self.on_interrupt),
            (AgentsState, self.on_agents))
        for cls, handler in handlers:
            self.handle(cls, handler)

    @classmethod
    def from_args(cls, config: BusConfig, argv: list[str], **kwargs: Any) -> AudioService:
        """`--silent`: the voice is heard elsewhere (a pipecat transport, a browser), so no sound card is
        opened (and none is missed): the clock-paced silent sink, as on a machine without one."""
        parser = argparse.ArgumentParser(prog="python -m eca.services.processes.run audio", add_help=False,
                                         exit_on_error=False)
        parser.add_argument("--silent", action="store_true")
        args = parse_service_args("audio", argv, parser)
        return cls(config, silent=args.silent, **kwargs)

    def subscriptions(self) -> list[str]:
        return ["play.", f"state.{ALL_AGENTS}.{AgentsState.TYPE}"]

    def setup(self) -> None:
        for agent in self.agent_ids:
            self._add_player(agent)

    def _add_player(self, agent: str) -> None:
        sink: Sink = self._sink_factory()
        self.players[agent] = Player(sink, self.events.put, agent_id=agent, clock=self.clock,
                                     config=self.audio_config, publish_voice=self.audio_config.publish_voice,
                                     tts=self.tts).start()
        self.held[agent] = {}
        self.endings[agent] = deque(maxlen=RECENT_ENDINGS)
        self._publish_playback(agent)

    def on_agents(self, msg: AgentsState) -> None:
        """Follow the live agents: a player for each created one, none for one removed."""
        live = set(msg.agents)
        for agent in [a for a in self.created if a not in live]:
            self.remove_agent(agent)
        for agent in msg.created:
            if agent not in self.players:
                self.created.append(agent)
                self._gone.pop(agent, None)
                self._add_player(agent)

    def remove_agent(self, agent: str) -> None:
        """Stop the agent's voice and close its player. Each request it held ends here, once, as interrupted (the
        dialogue service ended them when it removed the agent); what the closed player still had to report is
        dropped, and no playback state goes out (that would bring the agent back into the broker's cache)."""
        player = self.players.pop(agent)
        player.interrupt(None)
        player.close()
        self.created.remove(agent)
        self._gone[agent] = None
        while len(self._gone) > GONE_KEPT:
            self._gone.popitem(last=False)
        for rid in self.held.pop(agent, {}):
            self.interrupt_reasons.pop(rid, None)
            self.publish(SpeechInterruptedMsg(agent=agent, request_id=rid, reason=REMOVED_REASON), "audio")
        self.endings.pop(agent, None)

    def teardown(self) -> None:
        for player in self.players.values():
            player.close()
        self.drain_events()

    def _player(self, msg: Message) -> Player | None:
        """The agent's player; None for one removed a moment ago (a request on its way is no news)."""
        player = self.players.get(msg.agent)
        if player is None and msg.agent not in self._gone:
            raise Rejected(f"unknown agent '{msg.agent}'")
        return player

    def _publish_playback(self, agent: str) -> None:
        endings = self.endings[agent]
        self.publish(PlaybackState(agent=agent, request_ids=list(self.held[agent]), started_ns=self.started_ns,
                                   ended_ids=[e[0] for e in endings], ended_as=[e[1] for e in endings],
                                   ended_played_s=[e[2] for e in endings], ended_reasons=[e[3] for e in endings]))

    def on_new_broker(self) -> None:
        for agent in self.players:  # the new broker's cache has no playback state: the owner's again
            self._publish_playback(agent)

    def _ended(self, agent: str, ending: Message) -> None:
        """Record a request's terminal event (already published) and publish the playback it leaves."""
        rid: str = ending.request_id  # type: ignore[attr-defined]  # every terminal event has one
        self.endings[agent].append((rid, ending.TYPE, float(getattr(ending, "played_s", 0.0)),  # type: ignore[arg-type]
                                    str(getattr(ending, "reason", ""))))
        self.held.get(agent, {}).pop(rid, None)
        self._publish_playback(agent)

    def on_say(self, msg: Say) -> None:
        player = self._player(msg)
        if player is None:
            return
        held = self.held[msg.agent]
        # The dialogue service accepted the request, so a refusal here ends it like any failure: with a
        # speech_failed, which the dialogue service passes on once (an error would leave it pending there).
        if len(held) >= MAX_PENDING_SAYS:
            self._refuse(msg, f"the audio service already holds {MAX_PENDING_SAYS} say requests for this agent")
            return
        try:
            if msg.audio_path is not None:
                player.say_file(msg.request_id, msg.audio_path, msg.start_ns)
            elif msg.pcm is not None:
                player.say_pcm(msg.request_id, pcm16(msg.pcm), msg.sample_rate, msg.start_ns)
            elif msg.streamed:
                player.say_stream(msg.request_id, msg.sample_rate, msg.start_ns)
            else:  # text only (the dialogue service lets no other request through)
                player.say_text(msg.request_id, msg.text or "", msg.start_ns)
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
        failed = self.publish(SpeechFailedMsg(agent=msg.agent, request_id=msg.request_id, reason=reason[:500]), "audio")
        self._ended(msg.agent, failed)

    def on_chunk(self, msg: SpeechChunk) -> None:
        player = self._player(msg)
        if player is None:
            return
        if not player.feed(msg.request_id, pcm16(msg.pcm), msg.last):
            raise Rejected(f"request '{msg.request_id}' is not streaming (finished or interrupted)", msg.request_id)

    def on_interrupt(self, msg: Interrupt) -> None:
        player = self._player(msg)
        if player is None:
            return
        stopped = player.interrupt(msg.request_id or None)
        for uid in stopped:
            self.interrupt_reasons[uid] = msg.reason

    def on_tick(self, now_ns: int) -> None:
        self.drain_events(DRAIN_BUDGET_S)

    def drain_events(self, budget_s: float | None = None) -> None:
        """Publish the players' events in order: all of them, or those that fit in `budget_s`."""
        deadline = None if budget_s is None else time.perf_counter() + budget_s
        while deadline is None or time.perf_counter() < deadline:
            try:
                event = self.events.get_nowait()
            except queue.Empty:
                return
            if event.agent in self._gone:
                continue  # a removed agent's player, closed: its requests ended when it was removed
            for msg, category in self.to_messages(event):
                self.publish(msg, category)
                if isinstance(msg, TERMINAL_SPEECH_EVENTS) and msg.agent in self.endings:
                    self._ended(msg.agent, msg)

    def to_messages(self, ev: events.AudioEvent) -> list[tuple[Message, str]]:
        agent = ev.agent
        if isinstance(ev, events.PlayerVoiceBlock):  # first: the most frequent event
            return [(VoiceBlockMsg(agent=agent, sample_rate=ev.sample_rate, first_sample=ev.first_sample,
                                   dac_time_ns=max(0, ev.dac_time_ns), pcm=ev.pcm, request_id=ev.request_id),
                     "stream")]
        if isinstance(ev, events.PlayerAnchor):
            return [(ClockAnchorMsg(agent=agent, request_id=ev.request_id, sample_index=ev.sample_index,
                                    sample_rate=ev.sample_rate, dac_time_ns=max(0, ev.dac_time_ns)), "stream")]
        if isinstance(ev, events.PlayerMouthKeys):
            out: list[tuple[Message, str]] = []
            keys = ev.keys
            for start in range(0, len(keys), MOUTH_KEYS_PER_MESSAGE):
                part = keys[start:start + MOUTH_KEYS_PER_MESSAGE]
                names = list(part[0].weights) if part else []
                out.append((MouthKeys(agent=agent, request_id=ev.request_id, sample_rate=ev.sample_rate,
                                      sample_index=[k.sample_index for k in part],
                                      weights={n: [float(min(1.0, max(0.0, k.weights[n]))) for k in part]
                                               for n in names}), "stream"))
            return out
        if isinstance(ev, events.PlayerMouthReset):
            # stamped with the moment the voice stops at the DAC: the mouth closes from then on
            return [(MouthKeys(agent=agent, t_ns=max(0, ev.dac_time_ns), request_id=ev.request_id, sample_rate=1,
                               reset=True), "stream")]
        if isinstance(ev, events.PlayerStarted):
            return [(SpeechStartedMsg(agent=agent, request_id=ev.request_id,
                                      dac_time_ns=max(0, ev.dac_time_ns)), "audio")]
        if isinstance(ev, events.PlayerFinished):
            return [(SpeechFinishedMsg(agent=agent, request_id=ev.request_id, played_s=ev.played_s), "audio")]
        if isinstance(ev, events.PlayerInterrupted):
            reason = self.interrupt_reasons.pop(ev.request_id, "interrupted")
            return [(SpeechInterruptedMsg(agent=agent, request_id=ev.request_id, played_s=ev.played_s,
                                          reason=reason[:200]), "audio")]
        if isinstance(ev, events.PlayerFailed):
            return [(SpeechFailedMsg(agent=agent, request_id=ev.request_id, reason=ev.reason[:500]), "audio")]
        return []
