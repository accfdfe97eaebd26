"""The face's own thread: eca's bus on one side, the pipeline's voice and pictures on the other.

ZeroMQ sockets must stay on the thread that made them, and drawing needs its GL context current on one
thread, so both live on a thread of their own (`LinkThread`), which runs an eca `Service` loop
(`FaceLink`, named `pipecat` in its heartbeats) exactly as the web service does: it follows the agent's
states, events and eye streams into a live scene (`BusScenes`, services/processes/scene/), draws the face
headless at every frame slot (`Stage`, `OffscreenCanvas`) and hands each picture to the pipeline. The
pipeline's side (pipecat's asyncio loop) never touches a socket: what it has for eca (the TTS audio, the
user's turns, interruptions, tool commands) goes into a queue, and a byte on a pipe wakes the thread's
poll at once, so nothing waits for a poll timeout.

What goes on the bus, and how it is made reliable (docs/protocol.md sections 6, 7 and 13):
- each run of TTS audio becomes a streamed `say`, its frames `speech_chunk`s (index 0, 1, ...; the last
  one marked), so eca plays the same samples on its master clock (the role turns `talking`, the gaze
  behaves as the agent's own speech makes it, other outputs of the instance show and voice it);
- a say, an `interrupt`, `user_speech` and the tools' `set_emotion` / `move_head` carry request ids and
  are sent again (Lazy Pirate: after 0.5 s, then at doubling intervals up to 2 s) until acknowledged or
  refused; chunks are not acknowledged, so the chunks a say's `state.<agent>.speech` has not counted
  (`next_chunk`) are sent again when they are overdue. A dropped message never leaves eca talking after
  an interruption: an interrupt is repeated until acknowledged, and one refused because its say was
  not known yet is sent again once that say is acknowledged.

The mouth in the pictures is not eca's: it is computed here from the very frames the pipeline plays, on
the transport's timeline (services/pipecat/voice.py), so the picture pushed at time t shows the sample
the transport plays at t. eca's own voice plays the same samples a little later on its master clock
(its silent sink takes each block 50 ms ahead, plus the bus); that offset is measured per utterance
(the DAC time of sample 0 in `speech_started` minus the time the transport plays it) and reported in
`eca_offsets_s`, for other outputs of the instance.
"""

from __future__ import annotations

import concurrent.futures
import logging
import math
import os
import secrets
import threading
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import zmq

from eca.agent.face.scene import LiveScene
from eca.agent.lipsync.config import MOUTH_FLEXORS
from eca.protocol.codec import ProtocolError, encode
from eca.protocol.endpoints import BusConfig
from eca.protocol.messages import (
    Ack,
    Error,
    Interrupt,
    Message,
    Say,
    SpeechChunk,
    SpeechFailed,
    SpeechFinished,
    SpeechInterrupted,
    SpeechStarted,
    SpeechState,
    UserSpeech,
)
from eca.services.pipecat.voice import HeardVoice
from eca.services.processes.renderer import OffscreenCanvas, Stage, make_drawer, read_rgb
from eca.services.processes.runtime import Service
from eca.services.processes.scene.bus_scene import BusScenes
from eca.services.processes.scene.schedule import FrameSchedule

log = logging.getLogger("pipecat-face")

NS_PER_S = 1_000_000_000
RESEND_FIRST_S = 0.5  # docs/protocol.md section 13: no answer within about 0.5 s, send again ...
RESEND_MAX_S = 2.0  # ... at doubling intervals
CHUNK_OVERDUE_S = 0.5  # chunks the speech state has not counted this long after the latest was sent
MAX_CHUNK_BYTES = 1 << 20  # a longer TTS frame goes out in pieces, far under the bus's 4 MiB message cap
MAX_INBOX = 20_000  # requests from the pipeline waiting for the thread; past that new ones are dropped (counted)
_DUE_SOON_NS = 10_000_000  # audio this close past the composing moment counts as about to come
IDLE_END_S = 0.5  # a say whose audio has all been heard this long ago, with no stop frame: it is over


@dataclass(frozen=True)
class FaceOptions:
    """What the link draws and for whom; checked by the processor's parameters."""

    agent: str = "ada"
    video: bool = True
    width: int = 640
    height: int = 480
    fps: float = 30.0
    video_lead_s: float = 0.0
    command_timeout_s: float = 5.0
    seed: int = 0
    face: str = "flexor"  # a drawer kind or an avatar file (eca/services/processes/renderer/faces.py)


@dataclass(frozen=True)
class Picture:
    """One drawn frame: the transport time it shows (`frame_ns`: the face composed for it), its pixels
    (RGB, top row first) and the mouth in it."""

    frame_ns: int
    rgb: bytes
    width: int
    height: int
    mouth: dict[str, float]
    drawn_ns: int  # when its composition began
    interrupts: int = 0  # the interruptions the face had heard of when it composed it


@dataclass
class _Pending:
    """A command sent with a request id, until its acknowledgement or refusal (or the timeout)."""

    msg: Message
    deadline_ns: int
    next_send_ns: int
    interval_ns: int
    done: Callable[[Ack | Error | None], Any]


@dataclass
class _Say:
    """One streamed say on the eca side."""

    rid: str
    sample_rate: int
    heard0_ns: int  # when the transport plays its sample 0
    chunks: list[bytes] = field(default_factory=list)  # by index; emptied once the speech state counts them
    confirmed: int = 0  # chunks the dialogue service has forwarded (the speech state's next_chunk)
    last_sent: bool = False
    last_chunk_ns: int = 0
    heard_end_ns: int = 0  # when the transport has played all of its audio so far
    acked: bool = False
    interrupted: bool = False  # the pipeline was interrupted: eca must stop it too
    interrupt_acked: bool = False
    ended: bool = False  # eca reported its end (or refused it)


class FaceLink(Service):
    """The eca side of the pipecat face: see the module docstring. Everything but the `submit_*` methods,
    `wake` and `report_push_latency` runs on the link's own thread."""

    name = "pipecat"

    def __init__(self, config: BusConfig, options: FaceOptions,
                 on_picture: Callable[[Picture], None] | None = None, **kwargs: Any) -> None:
        super().__init__(config, **kwargs)
        self.options = options
        self.agent = options.agent
        self.on_picture = on_picture
        self.scenes = BusScenes(self, [self.agent], seed=options.seed)
        self.scene: LiveScene = self.scenes.views[0].scene
        self.voice = HeardVoice(self.scene)
        self._ids = f"pipecat-{secrets.token_hex(3)}"
        self._sent = 0
        self._inbox: deque[tuple[Any, ...]] = deque()
        self._wake_read, self._wake_write = os.pipe()
        os.set_blocking(self._wake_read, False)
        os.set_blocking(self._wake_write, False)
        self._woken = threading.Event()  # a byte is in the pipe: no need to write another
        self._pending: dict[tuple[str, str], _Pending] = {}  # (command type, request id) -> waiting for its answer
        self._says: dict[str, _Say] = {}
        self._say: _Say | None = None  # the say the pipeline's audio goes to now (None: eca does not voice it)
        self._say_rate = 0
        self._new_utterance = True
        self._poller = zmq.Poller()
        self._canvas: Any = None
        self._stage: Any = None
        self._schedule: Any = None
        self.push_latency_ns = 5_000_000  # composition -> pushed into the pipeline (the processor measures it)
        self.eca_offsets_s: deque[float] = deque(maxlen=64)  # per utterance: eca's DAC time - the transport's
        self.frames_drawn = 0
        self.says_sent = 0
        self.interrupts_seen = 0  # pictures carry it: the pipeline drops those composed before an interruption
        self.closed = False  # set once the thread has let go of everything
        self.warnings: deque[str] = deque(maxlen=32)
        for cls in (SpeechStarted, SpeechFinished, SpeechInterrupted, SpeechFailed):
            self._also(cls, self._on_speech_event)
        self.handle(Ack, self._on_ack)
        self.handle(Error, self._on_error)
        self.handle(SpeechState, self._on_speech_state)

    def _also(self, cls: type[Message], fn: Callable[[Any], None]) -> None:
        """Run `fn` after the handler already registered for `cls` (the scene's)."""
        first = self._handlers.get(cls)

        def both(msg: Any) -> None:
            if first is not None:
                first(msg)
            fn(msg)

        self.handle(cls, both)

    def subscriptions(self) -> list[str]:
        # The scene's subscriptions less eca's own mouth keys and clock anchors: the mouth follows the
        # pipeline's audio (voice.py); eca's keys of that audio, or of a say someone else sent on the bus
        # (which the pipeline's listener does not hear), would pull it onto eca's timeline.
        # The acknowledgements of its own commands too, which a scene does not read.
        own = (f"stream.{self.agent}.mouth", f"stream.{self.agent}.clock_anchor")
        return [s for s in self.scenes.subscriptions() if s not in own] + [f"event.{self.agent}.{Ack.TYPE}",
                                                                           f"error.{self.agent}."]

    # --- what the pipeline submits (any thread) ---------------------------------------------------

    def submit_audio(self, pcm: np.ndarray, sample_rate: int, pushed_ns: int, new_utterance: bool) -> None:
        """A TTS frame (mono int16) the pipeline pushed to its output at `pushed_ns`."""
        self._submit(("audio", pcm, sample_rate, pushed_ns, new_utterance))

    def submit_end_of_speech(self) -> None:
        self._submit(("end",))

    def submit_interrupt(self, now_ns: int, reason: str) -> None:
        self._submit(("interrupt", now_ns, reason))

    def submit_user_speaking(self, speaking: bool) -> None:
        self._submit(("user", speaking))

    def submit_command(self, msg: Message) -> concurrent.futures.Future[Ack | Error | None]:
        """A command for the agent, sent with a fresh request id until acknowledged; the future gets the
        Ack, the Error that refused it, or None when nothing answered within the command timeout.
        Raises ProtocolError here when the command itself is malformed (the codec's own check)."""
        encode(msg)
        future: concurrent.futures.Future[Ack | Error | None] = concurrent.futures.Future()
        self._submit(("command", msg, future))
        return future

    def report_push_latency(self, latency_ns: int) -> None:
        """From the pipeline: how long a picture took from its composition to its push (an average is kept)."""
        if 0 <= latency_ns < NS_PER_S:
            self.push_latency_ns += (latency_ns - self.push_latency_ns) // 8

    def _submit(self, item: tuple[Any, ...]) -> None:
        if self.closed:  # the thread is gone: a command gets its answer (none) at once
            if item[0] == "command":
                item[2].set_result(None)
            return
        if len(self._inbox) >= MAX_INBOX:
            self.dropped += 1
            if item[0] == "command":
                item[2].set_result(None)
            return
        self._inbox.append(item)
        self.wake()

    def wake(self) -> None:
        if not self._woken.is_set():
            self._woken.set()
            try:
                os.write(self._wake_write, b"w")
            except OSError:
                pass  # the pipe is full (the thread is awake anyway) or closed (it is gone)

    # --- start and stop ---------------------------------------------------------------------------

    def setup(self) -> None:
        assert self.sub is not None
        self._poller.register(self.sub.socket, zmq.POLLIN)
        self._poller.register(self._wake_read, zmq.POLLIN)
        if self.options.video:
            size = (self.options.width, self.options.height)
            self._canvas = OffscreenCanvas(size)
            self._stage = Stage(make_drawer(self._canvas.ctx, size, self.options.face), self.scenes.views,
                                fps=self.options.fps)
            self._schedule = FrameSchedule(self.clock, self.options.fps)

    def teardown(self) -> None:
        self.closed = True
        self._stage = None
        if self._canvas is not None:
            self._canvas.close()
            self._canvas = None
        for pending in self._pending.values():
            pending.done(None)
        self._pending.clear()
        while self._inbox:  # commands that never went out are answered too
            item = self._inbox.popleft()
            if item[0] == "command":
                item[2].set_result(None)
        for fd in (self._wake_read, self._wake_write):
            try:
                os.close(fd)
            except OSError:
                pass

    # --- the loop ---------------------------------------------------------------------------------

    def run_once(self) -> None:
        assert self.sub is not None
        now = self.clock.now_ns()
        self.beat_if_due(now)
        self._take_inputs()
        self._resend_due(now)
        self._end_idle_say(now)
        schedule = self._schedule
        if schedule is not None and now >= schedule.due_ns:
            self.scenes.drain()
            self._take_inputs()  # audio pushed while the bus was read: its mouth belongs in this frame
            self._draw(self.clock.now_ns())
            schedule.advance()
            return
        due = schedule.due_ns if schedule is not None else now + 100_000_000
        for pending in self._pending.values():
            due = min(due, pending.next_send_ns)
        wait_ms = max(0, min(100, math.ceil((due - now) / 1e6)))
        ready = dict(self._poller.poll(wait_ms))
        if self._wake_read in ready:
            self._woken.clear()  # before reading: a wake written meanwhile writes a new byte
            try:
                while os.read(self._wake_read, 4096):
                    pass
            except BlockingIOError:
                pass
        if self.sub.socket in ready:
            self.scenes.drain()

    def _take_inputs(self) -> None:
        while self._inbox:
            item = self._inbox.popleft()
            kind = item[0]
            try:
                if kind == "audio":
                    self._on_audio(*item[1:])
                elif kind == "end":
                    self._on_end_of_speech()
                elif kind == "interrupt":
                    self._on_interrupt(*item[1:])
                elif kind == "user":
                    self._send_acked(UserSpeech(agent=self.agent, speaking=item[1], request_id=self._new_id()))
                elif kind == "command":
                    self._on_command(item[1], item[2])
            except Exception:  # one bad request must not stop the face
                log.exception("could not handle the pipeline's %s", kind)

    # --- the pipeline's voice ---------------------------------------------------------------------

    def _on_audio(self, pcm: np.ndarray, sample_rate: int, pushed_ns: int, new_utterance: bool) -> None:
        new = new_utterance or self._new_utterance or sample_rate != self._say_rate
        self._new_utterance = False
        heard_ns = self.voice.add(pcm, sample_rate, pushed_ns, new_utterance=new)
        say = self._say
        if new or (say is not None and say.ended and not say.interrupted):
            # A new utterance, or eca stopped this one while the pipeline goes on talking (a barge-in that
            # the pipeline does not treat as an interruption): eca voices the rest as a say of its own.
            if say is not None:
                self._send_last_chunk(say)
            say = self._say = self._open_say(sample_rate, heard_ns)
            self._say_rate = sample_rate
        if say is None or say.interrupted:
            return
        data = pcm.astype("<i2", copy=False).tobytes()
        for start in range(0, len(data), MAX_CHUNK_BYTES):
            self._send_chunk(say, data[start:start + MAX_CHUNK_BYTES], last=False)
        say.heard_end_ns = self.voice.playout_end_ns

    def _open_say(self, sample_rate: int, heard_ns: int) -> _Say | None:
        if not 8000 <= sample_rate <= 192_000:
            self._warn(f"TTS audio at {sample_rate} Hz: eca takes 8000-192000 Hz, so eca does not voice it "
                       "(the face in the pipeline still follows it)")
            return None
        say = _Say(self._new_id(), sample_rate, heard_ns)
        self._says[say.rid] = say
        self.says_sent += 1
        self._send_acked(Say(agent=self.agent, request_id=say.rid, streamed=True, sample_rate=sample_rate),
                         lambda answer: self._on_say_answer(say, answer))
        return say

    def _send_chunk(self, say: _Say, pcm: bytes, last: bool) -> None:
        say.chunks.append(pcm)
        say.last_sent = last
        say.last_chunk_ns = self.clock.now_ns()
        self.publish(SpeechChunk(agent=self.agent, request_id=say.rid, index=len(say.chunks) - 1, pcm=pcm,
                                 last=last))

    def _send_last_chunk(self, say: _Say) -> None:
        if not say.last_sent and not say.ended and not say.interrupted:
            self._send_chunk(say, b"", last=True)

    def _on_end_of_speech(self) -> None:
        self.voice.finish(self.clock.now_ns())
        self._new_utterance = True
        if self._say is not None:
            self._send_last_chunk(self._say)
            self._say = None

    def _end_idle_say(self, now: int) -> None:
        """No stop frame after the audio has all been heard (some TTS services send theirs late, or never):
        the say ends, so eca's role is not left `talking` through the silence; more audio opens a new one."""
        say = self._say
        idle_ns = round(IDLE_END_S * NS_PER_S)
        if say is None or not say.chunks or now - say.heard_end_ns < idle_ns or now - say.last_chunk_ns < idle_ns:
            return
        self._on_end_of_speech()

    def _on_interrupt(self, now_ns: int, reason: str) -> None:
        self.interrupts_seen += 1
        self.voice.cut(now_ns)
        self._new_utterance = True
        self._say = None
        for say in list(self._says.values()):
            if not say.ended and not say.interrupted:
                say.interrupted = True
                say.chunks.clear()
                self._interrupt_on_eca(say, reason)

    def _interrupt_on_eca(self, say: _Say, reason: str) -> None:
        def answered(answer: Ack | Error | None) -> None:
            if isinstance(answer, Ack):
                say.interrupt_acked = True
            elif answer is None and not say.ended:
                self._warn(f"eca did not acknowledge the interrupt of {say.rid}")
            # An Error: eca did not know the say yet (it was lost, or is still on its way); when its
            # acknowledgement comes, _on_say_answer sends the interrupt again.
            self._forget_ended()

        self._send_acked(Interrupt(agent=self.agent, request_id=say.rid, reason=reason[:200]), answered)

    def _on_say_answer(self, say: _Say, answer: Ack | Error | None) -> None:
        if isinstance(answer, Ack):
            say.acked = True
            if say.interrupted and not say.interrupt_acked and not say.ended \
                    and ("interrupt", say.rid) not in self._pending:
                self._interrupt_on_eca(say, "interrupted in the pipeline")
        else:
            say.ended = True
            say.chunks.clear()
            why = answer.reason if isinstance(answer, Error) else "no acknowledgement (is eca's dialogue running?)"
            self._warn(f"eca did not take the say {say.rid}: {why}")
        self._forget_ended()

    # --- commands and their acknowledgements ----------------------------------------------------------

    def _new_id(self) -> str:
        self._sent += 1
        return f"{self._ids}-{self._sent}"

    def _on_command(self, msg: Message, future: concurrent.futures.Future[Ack | Error | None]) -> None:
        rid = getattr(msg, "request_id", "") or self._new_id()
        command = replace(msg, agent=self.agent, request_id=rid)  # type: ignore[call-arg]
        self._send_acked(command, lambda answer: future.done() or future.set_result(answer))

    def _send_acked(self, msg: Message, done: Callable[[Ack | Error | None], Any] | None = None) -> None:
        now = self.clock.now_ns()
        rid: str = getattr(msg, "request_id", "")
        try:
            self.publish(msg)
        except ProtocolError as exc:  # a malformed command: answered at once, like a refusal
            if done is not None:
                done(Error(agent=self.agent, reason=str(exc)[:2000], kind=exc.kind, request_id=rid[:64],
                           service=self.name))
            return
        interval = round(RESEND_FIRST_S * NS_PER_S)
        self._pending[(msg.TYPE, rid)] = _Pending(msg, now + round(self.options.command_timeout_s * NS_PER_S),
                                                  now + interval, interval, done or (lambda answer: None))

    def _resend_due(self, now: int) -> None:
        for key, pending in list(self._pending.items()):
            if now >= pending.deadline_ns:
                del self._pending[key]
                pending.done(None)
            elif now >= pending.next_send_ns:
                self.publish(pending.msg)  # the same request id: a repeat is acknowledged, not applied twice
                pending.interval_ns = min(2 * pending.interval_ns, round(RESEND_MAX_S * NS_PER_S))
                pending.next_send_ns = now + pending.interval_ns
        overdue_ns = round(CHUNK_OVERDUE_S * NS_PER_S)
        for say in self._says.values():
            if (say.acked and not say.ended and not say.interrupted and say.confirmed < len(say.chunks)
                    and now - say.last_chunk_ns >= overdue_ns):
                last = len(say.chunks) - 1
                for index in range(say.confirmed, len(say.chunks)):  # lost on the way (a broker restart)
                    self.publish(SpeechChunk(agent=self.agent, request_id=say.rid, index=index,
                                             pcm=say.chunks[index], last=say.last_sent and index == last))
                say.last_chunk_ns = now

    def _answer(self, command: str, request_id: str, answer: Ack | Error) -> None:
        pending = self._pending.pop((command, request_id), None)
        if pending is not None:
            pending.done(answer)

    def _on_ack(self, msg: Ack) -> None:
        self._answer(msg.command, msg.request_id, msg)

    def _on_error(self, msg: Error) -> None:
        # The refused command's type is the last part of its topic (cmd.<agent>.<type>). Errors about
        # chunks sent again after the dialogue service had counted them carry no pending command.
        if msg.request_id:
            self._answer(msg.topic.rsplit(".", 1)[-1], msg.request_id, msg)

    def _on_speech_state(self, msg: SpeechState) -> None:
        for rid, next_chunk in zip(msg.request_ids, msg.next_chunk, strict=False):
            say = self._says.get(rid)
            if say is not None and next_chunk > say.confirmed:
                for index in range(say.confirmed, min(next_chunk, len(say.chunks))):
                    say.chunks[index] = b""  # forwarded: never sent again, so not kept
                say.confirmed = next_chunk
        for rid in msg.ended_ids:
            say = self._says.get(rid)
            if say is not None:
                say.ended = True
                say.chunks.clear()
        self._forget_ended()

    def _on_speech_event(self, msg: Message) -> None:
        say = self._says.get(getattr(msg, "request_id", ""))
        if say is None:
            return
        if isinstance(msg, SpeechStarted):
            if msg.dac_time_ns:
                self.eca_offsets_s.append((msg.dac_time_ns - say.heard0_ns) / 1e9)
            return
        say.ended = True
        say.chunks.clear()
        self._forget_ended()

    def _forget_ended(self) -> None:
        for rid in [r for r, s in self._says.items() if s.ended and s is not self._say
                    and not any(key[1] == r for key in self._pending)]:
            del self._says[rid]

    def _warn(self, text: str) -> None:
        if self.closed:
            return  # what the end of the pipeline left unanswered is no news
        self.warnings.append(text)
        log.warning(text)

    # --- drawing ----------------------------------------------------------------------------------

    def _draw(self, now: int) -> None:
        assert self._stage is not None and self._canvas is not None
        # The moment this picture will be pushed (plus the lead): the mouth of what the transport plays then,
        # silence included where the pushed audio has run out (it plays silence there too). But a TTS that
        # streams in real time pushes each frame just as it is due: when the moment is only a little past the
        # audio pushed so far and the utterance goes on, that audio is about to come, and the newest mouth
        # known is the better guess.
        target_ns = now + self.push_latency_ns + round(self.options.video_lead_s * NS_PER_S)
        covered = self.voice.covered_until_ns()
        if covered is not None and covered <= target_ns <= covered + self.push_latency_ns + _DUE_SOON_NS:
            target_ns = covered - 1
        faces = self._stage.compose(target_ns)
        screen = self._canvas.screen
        self._stage.draw(faces, screen)
        rgb = read_rgb(screen)
        mouth = {name: float(faces[0].frame.get(name)) for name in MOUTH_FLEXORS}
        self.frames_drawn += 1
        if self.on_picture is not None:
            self.on_picture(Picture(target_ns, rgb.tobytes(), self.options.width, self.options.height, mouth, now,
                                    self.interrupts_seen))


class LinkThread:
    """Runs a FaceLink's loop on a thread of its own; `start` returns once it is connected to the bus
    (both readiness barriers passed) or raises why it could not."""

    def __init__(self, link: FaceLink) -> None:
        self.link = link
        self._thread = threading.Thread(target=self._run, daemon=True, name=f"eca-face-{link.agent}")
        self._ready = threading.Event()
        self._timeout_s = 10.0
        self.error: BaseException | None = None

    def _run(self) -> None:
        link = self.link
        try:
            link.connect(timeout_s=self._timeout_s)
            self._ready.set()
            while not link.stopping:
                link.run_once()
        except BaseException as exc:  # surfaced by start(), or logged when it happens later
            self.error = exc
            if self._ready.is_set():
                log.exception("the eca face thread stopped")
            self._ready.set()
        finally:
            try:
                link.teardown()
            finally:
                link.close()

    def start(self, timeout_s: float = 10.0) -> LinkThread:
        self._timeout_s = timeout_s
        self._thread.start()
        self._ready.wait()
        if self.error is not None:
            self._thread.join(timeout=5.0)
            raise self.error
        return self

    def stop(self, timeout_s: float = 5.0) -> None:
        self.link.request_stop()
        self.link.wake()
        self._thread.join(timeout=timeout_s)

    @property
    def alive(self) -> bool:
        return self._thread.is_alive()
