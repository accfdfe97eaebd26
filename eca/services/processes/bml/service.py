"""The bml service: one thin loop around the BML realizer (agent/bml/).

`cmd.<agent>.bml` carries a block. It is parsed and checked (agent/bml/parse.py; a block refused is answered
with a warningFeedback and an error, and nothing of it runs), its speech voiced with the times of its sync
marks (bml/speech.py, on a worker thread), scheduled on the master clock (agent/bml/schedule.py) after the
blocks it must follow (APPEND) or in place of them (REPLACE), and realized as eca's own messages
(bml/realize.py). Every tick the sync points that have passed go out as the standard's feedback on
`event.<agent>.bml_feedback` (agent/bml/realizer.py); a speech's points follow its audio (the audio
service's speech events). An interrupted say (an `interrupt`, a barge-in) ends its block: its face behaviours
stop, its end is reported once.
"""

from __future__ import annotations

import argparse
import concurrent.futures
import secrets
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from eca.agent.bml import (
    Block,
    BmlError,
    GazeParams,
    HeadDirectionParams,
    SpeechParams,
    feedback,
    parse_block,
    schedule,
)
from eca.agent.bml.realizer import NS, AgentRealizer, Feedback
from eca.agent.face.settings import load_flexor_units
from eca.agent.gaze.situated import USER, SituatedParams
from eca.protocol.endpoints import BusConfig
from eca.protocol.messages import (
    ALL_AGENTS,
    Ack,
    AgentsState,
    Bml,
    BmlFeedback,
    GazeTargetState,
    HeadState,
    Interrupt,
    SpeechFailed,
    SpeechFinished,
    SpeechInterrupted,
    SpeechStarted,
)
from eca.services.processes.audio.config import AudioConfig
from eca.services.processes.bml.realize import HeadAim, Realization, Timed, cut_messages, realize
from eca.services.processes.bml.speech import SpeechAudio, voice
from eca.services.processes.runtime import Rejected, Service, parse_service_args

AGENTS_TOPIC = f"state.{ALL_AGENTS}.{AgentsState.TYPE}"
SPEECH_LEAD_NS = 80_000_000  # a block with speech starts this long after it is ready: the say's way to the audio
MAX_WAITING = 16  # blocks being voiced at once, per instance; one more is refused (busy)
ACKED_KEPT = 1024


@dataclass
class Waiting:
    """A parsed block whose speech is being voiced."""

    msg: Bml
    block: Block
    voices: concurrent.futures.Future[dict[str, SpeechAudio]]


BUSY_TICK_HZ = 200.0  # with blocks under way: sync points reported within 5 ms of their time
IDLE_TICK_HZ = 4.0  # with none: a block's arrival wakes the loop anyway (a message), so ticks are only bookkeeping


class BmlService(Service):
    name = "bml"
    tick_hz = IDLE_TICK_HZ

    def __init__(self, config: BusConfig, **kwargs: Any) -> None:
        super().__init__(config, **kwargs)
        self.agents: list[str] = list(config.agents)
        self.realizers = {a: AgentRealizer(a) for a in self.agents}
        self.tts = AudioConfig.load().tts
        self.seats = SituatedParams.load()
        units = load_flexor_units()
        self.aim = HeadAim(units.turn_deg, units.nod_deg, self.seats.head_share)
        self.targets = named_targets(config)
        self.gaze: dict[str, GazeTargetState] = {}
        self.head: dict[str, HeadState] = {}
        self.timed: list[Timed] = []
        self.realizations: dict[tuple[str, str], Realization] = {}  # (agent, block) -> what it sent
        self.waiting: list[Waiting] = []
        self.acked: OrderedDict[tuple[str, str], None] = OrderedDict()
        self.worker = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="bml-voice")
        self.handle(Bml, self.on_bml)
        self.handle(SpeechStarted, self.on_speech_started)
        self.handle(SpeechFinished, self.on_speech_ended)
        self.handle(SpeechInterrupted, self.on_speech_ended)
        self.handle(SpeechFailed, self.on_speech_ended)
        self.handle(GazeTargetState, lambda m: self.gaze.__setitem__(m.agent, m))
        self.handle(HeadState, lambda m: self.head.__setitem__(m.agent, m))
        self.handle(AgentsState, self.on_agents)

    @classmethod
    def from_args(cls, config: BusConfig, argv: list[str], **kwargs: Any) -> BmlService:
        parse_service_args(cls.name, argv, argparse.ArgumentParser(prog="eca service bml"))
        return cls(config, **kwargs)

    def subscriptions(self) -> list[str]:
        return [AGENTS_TOPIC, *(t for a in self.agents for t in agent_topics(a))]

    def teardown(self) -> None:
        self.worker.shutdown(wait=False, cancel_futures=True)

    def on_agents(self, msg: AgentsState) -> None:
        live = set(msg.agents)
        for agent in [a for a in self.agents if a not in live and a not in self.config.agents]:
            self._drop_agent(agent)
        for agent in msg.created:
            if agent not in self.realizers:
                self.agents.append(agent)
                self.realizers[agent] = AgentRealizer(agent)
                if self.sub is not None:
                    for topic in agent_topics(agent):
                        self.sub.subscribe(topic)

    def _drop_agent(self, agent: str) -> None:
        self.agents.remove(agent)
        realizer = self.realizers.pop(agent)
        for item in realizer.interrupt(self.clock.now_ns(), "the agent was removed"):
            self._feedback(agent, item)
        if self.sub is not None:
            for topic in agent_topics(agent):
                self.sub.unsubscribe(topic)

    # --- a block arrives --------------------------------------------------------------------------

    def on_bml(self, msg: Bml) -> None:
        if msg.agent not in self.realizers:
            raise Rejected(f"no agent '{msg.agent}' in this instance", msg.request_id)
        if msg.request_id and (msg.agent, msg.request_id) in self.acked:
            self._ack(msg)  # sent again by a client that missed the acknowledgement: not run twice
            return
        if msg.request_id and any((w.msg.agent, w.msg.request_id) == (msg.agent, msg.request_id)
                                  for w in self.waiting):
            return  # sent again while its speech is being voiced: acknowledged once it runs
        try:
            block = parse_block(msg.xml, f"cmd.{msg.agent}.bml")
        except BmlError as exc:
            self._refuse(msg, exc.block, exc.behaviour, exc.warning_type, str(exc))
            return
        realizer = self.realizers[msg.agent]
        if realizer.is_taken(block.id) or any(w.block.id == block.id and w.msg.agent == msg.agent
                                                for w in self.waiting):
            self._refuse(msg, block.id, "", "PARSING_FAILURE", f"block '{block.id}' is already running")
            return
        speeches = [b for b in block.behaviours if isinstance(b.params, SpeechParams)]
        if speeches and len(self.waiting) >= MAX_WAITING:
            raise Rejected(f"busy: {MAX_WAITING} blocks are being voiced; send it again later", msg.request_id,
                           kind="busy")
        for warning in block.warnings:
            self._feedback(msg.agent, Feedback("warningFeedback", block.id, warning.behaviour, warning.type,
                                               text=warning.text, request_id=msg.request_id))
        self._busy()
        if not speeches:
            self._start(msg, block, {})
            return
        tts = self.tts
        job = self.worker.submit(lambda: {b.id: voice(b.params, tts) for b in speeches  # type: ignore[arg-type]
                                          })
        self.waiting.append(Waiting(msg, block, job))

    def on_tick(self, now_ns: int) -> None:
        for w in [w for w in self.waiting if w.voices.done()]:
            self.waiting.remove(w)
            self._run_guarded(w.msg, lambda w=w: self._voiced(w))  # type: ignore[misc]
        now_ns = self.clock.now_ns()
        self._send_due(now_ns)
        for agent, realizer in self.realizers.items():
            for item in realizer.due(now_ns):
                self._feedback(agent, item)
                if item.kind == "blockProgress" and item.sync == "end":
                    self.realizations.pop((agent, item.block), None)
        busy = bool(self.timed or self.waiting or any(r.blocks for r in self.realizers.values()))
        self.tick_hz = BUSY_TICK_HZ if busy else IDLE_TICK_HZ

    def _busy(self) -> None:
        """Something is under way: tick at once, and often, until it is over."""
        self.tick_hz = BUSY_TICK_HZ
        self._next_tick_ns = 0

    def _voiced(self, w: Waiting) -> None:
        try:
            voices = w.voices.result()
        except ValueError as exc:
            self._refuse(w.msg, w.block.id, "", "CANNOT_CREATE_BEHAVIOR", f"block '{w.block.id}': {exc}")
            return
        except Exception as exc:  # a bug in voicing must not take the service down
            self.log.exception("voicing block %s failed", w.block.id)
            self._refuse(w.msg, w.block.id, "", "CANNOT_CREATE_BEHAVIOR",
                         f"block '{w.block.id}': the speech could not be voiced ({type(exc).__name__})")
            return
        self._start(w.msg, w.block, voices)

    def _send_due(self, now_ns: int) -> None:
        while self.timed and self.timed[0].at_ns <= now_ns:
            self.publish(self.timed.pop(0).message)

    def _run_guarded(self, msg: Bml, call: Callable[[], None]) -> None:
        try:
            call()
        except Rejected as exc:
            self.reject(f"cmd.{msg.agent}.bml", exc.kind, exc.reason, msg.request_id, agent=msg.agent)

    def _start(self, msg: Bml, block: Block, voices: dict[str, SpeechAudio]) -> None:
        agent = msg.agent
        realizer = self.realizers.get(agent)
        if realizer is None:
            raise Rejected(f"agent '{agent}' was removed before its block could start", msg.request_id)
        now = self.clock.now_ns()
        if block.composition == "REPLACE":
            self._interrupt(agent, now, f"replaced by block '{block.id}'")
        lead = SPEECH_LEAD_NS if voices else 0
        start_ns = realizer.start_for(block.composition, now + lead)
        try:
            timeline = schedule(block, start_ns / NS, {k: v.timing for k, v in voices.items()},
                                realizer.known_times_s())
        except BmlError as exc:
            self._refuse(msg, block.id, exc.behaviour, exc.warning_type, str(exc))
            return
        for name, audio in voices.items():
            if audio.approximate_marks:
                self._feedback(agent, Feedback("warningFeedback", block.id, name, "CUSTOM_BEHAVIOUR_NOT_SUPPORTED",
                                               text=f"speech '{name}': the configured text-to-speech engine reports "
                                                    "no marks; they are placed by the characters before them",
                                               request_id=msg.request_id))
        for beh in block.behaviours:
            target = getattr(beh.params, "target", None)
            if isinstance(beh.params, GazeParams | HeadDirectionParams) and target is not None \
                    and self._direction(agent, target) is None:
                self._feedback(agent, Feedback("warningFeedback", block.id, beh.id, "NO_SUCH_TARGET",
                                               text=f"{beh.kind} '{beh.id}' (line {beh.line}): no target "
                                                    f"'{target}' (the user, an agent of this instance or a point of "
                                                    "[bml] targets); it looks straight ahead",
                                               request_id=msg.request_id))
        nonce = secrets.token_hex(3)
        realization = realize(agent, block, timeline, voices,
                              lambda beh: f"bml-{block.id}-{beh}-{nonce}"[:64],
                              self._direction, self.gaze.get(agent), self.head.get(agent), self.aim)
        times_ns = {key: round(t * NS) for key, t in timeline.times.items()}
        try:
            prediction = realizer.begin(block.id, msg.request_id, round(timeline.start_s * NS), times_ns,
                                        realization.says)
        except ValueError as exc:  # the agent's bound on running blocks
            raise Rejected(f"busy: {exc}; send it when one has ended", msg.request_id, kind="busy") from None
        for item in prediction:
            self._feedback(agent, item)
        self.realizations[(agent, block.id)] = realization
        for m in realization.now:
            self.publish(m)
        self.timed = sorted([*self.timed, *realization.timed], key=lambda t: t.at_ns)
        self._send_due(self.clock.now_ns())  # what starts with the block goes now, not at the next tick
        self._ack(msg)

    # --- the voice --------------------------------------------------------------------------------

    def on_speech_started(self, msg: SpeechStarted) -> None:
        realizer = self.realizers.get(msg.agent)
        if realizer is not None:
            realizer.speech_started(msg.request_id, msg.dac_time_ns or self.clock.now_ns())

    def on_speech_ended(self, msg: SpeechFinished | SpeechInterrupted | SpeechFailed) -> None:
        realizer = self.realizers.get(msg.agent)
        if realizer is None:
            return
        running = realizer.block_of_say(msg.request_id)
        if running is None:
            return
        started = next((running.speech_start_ns[b] for b, s in running.speech.items()
                        if s == msg.request_id and b in running.speech_start_ns), None)
        played = getattr(msg, "played_s", 0.0)
        end = started + round(played * NS) if started is not None else self.clock.now_ns()
        realizer.speech_ended(msg.request_id, end)
        if not isinstance(msg, SpeechFinished):  # cut short: the block ends with it
            why = msg.reason if isinstance(msg, SpeechInterrupted | SpeechFailed) else ""
            self._interrupt(msg.agent, self.clock.now_ns(), f"its speech ended early: {why}"[:200],
                            [running.block_id])

    # --- ending blocks ----------------------------------------------------------------------------

    def _interrupt(self, agent: str, now_ns: int, reason: str, block_ids: list[str] | None = None) -> None:
        realizer = self.realizers[agent]
        ids = realizer.running_ids() if block_ids is None else set(block_ids)
        for block_id in ids:
            realization = self.realizations.pop((agent, block_id), None)
            if realization is None:
                continue
            for m in cut_messages(realization, now_ns):
                self.publish(m)
            for say in realization.says.values():
                self.publish(Interrupt(agent=agent, request_id=say, reason=reason[:200]))
        cut = [t for t in self.timed if t.message.agent == agent and t.block in ids]
        self.timed = [t for t in self.timed if not (t.message.agent == agent and t.block in ids)]
        for t in cut:  # what a cut gaze changed goes back now, and the gaze model's saccades go on from there
            if t.restore:
                self.publish(t.message)
        for item in realizer.interrupt(now_ns, reason, ids):
            self._feedback(agent, item)

    # --- answers ----------------------------------------------------------------------------------

    def _refuse(self, msg: Bml, block: str, behaviour: str, warning_type: str, text: str) -> None:
        self._feedback(msg.agent, Feedback("warningFeedback", block or "unknown", behaviour, warning_type,
                                           text=text, request_id=msg.request_id))
        raise Rejected(text, msg.request_id)

    def _ack(self, msg: Bml) -> None:
        self.acked[(msg.agent, msg.request_id)] = None
        while len(self.acked) > ACKED_KEPT:
            self.acked.popitem(last=False)
        self.publish(Ack(agent=msg.agent, request_id=msg.request_id, command=Bml.TYPE))

    def _feedback(self, agent: str, item: Feedback) -> None:
        global_s = item.global_ns / NS
        if item.kind == "blockProgress":
            xml = feedback.block_progress_xml(item.block, item.sync, global_s, agent)
        elif item.kind == "syncPointProgress":
            xml = feedback.sync_point_progress_xml(item.block, item.behaviour, item.sync, item.time_s, global_s, agent)
        elif item.kind == "warningFeedback":
            xml = feedback.warning_feedback_xml(item.block, item.behaviour, item.sync, item.text, agent)
        else:
            xml = feedback.prediction_feedback_xml(item.block, global_s, item.end_ns / NS, agent)
        self.publish(BmlFeedback(agent=agent, kind=item.kind, block=item.block[:64], behaviour=item.behaviour[:64],
                                 sync=item.sync[:64], time_s=max(-86_400.0, min(86_400.0, item.time_s)),
                                 global_ns=max(0, item.global_ns), end_ns=max(0, item.end_ns), text=item.text[:2000],
                                 request_id=item.request_id[:64], xml=xml[:8192]))

    def _direction(self, agent: str, target: str) -> tuple[float, float] | None:
        """Where a gaze target is seen from `agent`: the user (or the camera), another agent of the instance
        where it sits ([seats], configs/conversation.toml), or a point named in the config's [bml] targets."""
        if target in ("", "camera", "CAMERA"):
            target = USER
        if target in self.targets:
            return self.targets[target]
        if target == USER or (target in self.config.agents and agent in self.config.agents):
            return self.seats.direction(self.config.agents, agent, target)
        return None


def agent_topics(agent: str) -> list[str]:
    return [f"cmd.{agent}.bml", f"event.{agent}.speech_", f"state.{agent}.gaze_target", f"state.{agent}.head"]


def named_targets(config: BusConfig) -> dict[str, tuple[float, float]]:
    """[bml] targets: name -> [yaw_deg, pitch_deg] as the agents see it (the config's own named points)."""
    table = config.raw.get("bml", {})
    where = f"{config.config_path} [bml]"
    if not isinstance(table, dict):
        raise ValueError(f"{where} must be a table")
    targets = table.get("targets", {})
    if not isinstance(targets, dict) or len(targets) > 64:
        raise ValueError(f"{where} targets must be a table of at most 64 names")
    out = {}
    for name, point in targets.items():
        if not (isinstance(point, list) and len(point) == 2 and all(isinstance(v, int | float) for v in point)
                and -60 <= point[0] <= 60 and -45 <= point[1] <= 45):
            raise ValueError(f"{where} targets.{name}: [yaw_deg, pitch_deg] within +-60, +-45, got {point!r}"[:300])
        out[str(name)] = (float(point[0]), float(point[1]))
    return out
