"""The pipecat face (services/pipecat) in pipecat's own test harness (`run_test`), against real eca services
on a private instance (broker, dialogue and audio with a silent sink, in threads): TTS audio in becomes a
streamed say that follows it sample for sample and ends once; the audio passes untouched; pictures come at
the configured rate with the mouth open where the audio is loud (composed flexors and pixels); the user's
turns reach eca, and an interruption stops the say and leaves no open mouth.
"""

from __future__ import annotations

import asyncio
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np
import pytest
import zmq

pytest.importorskip("pipecat.frames.frames", reason="pipecat is not installed: pip install 'eca[pipecat]'")

from pipecat.frames.frames import (  # noqa: E402
    ErrorFrame,
    Frame,
    InterruptionFrame,
    OutputImageRawFrame,
    TTSAudioRawFrame,
    TTSStartedFrame,
    TTSStoppedFrame,
    UserStartedSpeakingFrame,
    UserStoppedSpeakingFrame,
)
from pipecat.pipeline.pipeline import Pipeline  # noqa: E402
from pipecat.processors.frame_processor import FrameDirection, FrameProcessor  # noqa: E402
from pipecat.tests.utils import SleepFrame, run_test  # noqa: E402

from eca.protocol.bus import Subscriber  # noqa: E402
from eca.protocol.endpoints import BusConfig  # noqa: E402
from eca.protocol.messages import (  # noqa: E402
    Message,
    RoleState,
    Say,
    SpeechChunk,
    SpeechFailed,
    SpeechFinished,
    SpeechInterrupted,
    SpeechStarted,
    UserSpeech,
)
from eca.services.pipecat import EcaFaceParams, EcaVideoService  # noqa: E402
from eca.services.processes.audio.service import AudioService  # noqa: E402
from eca.services.processes.audio.sinks import NullSink  # noqa: E402
from eca.services.processes.dialogue import DialogueService  # noqa: E402
from tests.support.bus import BrokerThread, ServiceThread, private_bus_config  # noqa: E402

pytestmark = [pytest.mark.gl, pytest.mark.filterwarnings("ignore::DeprecationWarning")]  # pipecat's own
RATE = 16_000
FRAME = 320  # 20 ms


@contextmanager
def eca_instance() -> Iterator[tuple[BusConfig, Subscriber]]:
    """A private instance: the broker, the dialogue service and the audio service (a silent sink taking
    blocks 50 ms ahead, as `eca up` without a sound card), and a subscriber to what the face sends and gets."""
    with private_bus_config(services=["dialogue", "audio"]) as config, BrokerThread(config):
        ctx = zmq.Context()
        bus = Subscriber(ctx, config, ["cmd.ada.", "event.ada.", "state.ada.role"])
        bus.wait_ready()
        audio = AudioService(config, sink_factory=lambda: NullSink(48_000, 480, latency_s=0.05))
        try:
            with ServiceThread(DialogueService(config)), ServiceThread(audio):
                yield config, bus
        finally:
            bus.close()
            ctx.term()


class Stamper(FrameProcessor):
    """Notes when each frame arrives downstream of the face (direct mode: no queue, so at its push)."""

    def __init__(self) -> None:
        super().__init__(enable_direct_mode=True)
        self.seen: list[tuple[int, Frame]] = []

    async def process_frame(self, frame: Frame, direction: FrameDirection) -> None:
        await super().process_frame(frame, direction)
        if direction == FrameDirection.DOWNSTREAM:
            self.seen.append((time.monotonic_ns(), frame))
        await self.push_frame(frame, direction)


def face_for(config: BusConfig, **params: Any) -> EcaVideoService:
    return EcaVideoService(EcaFaceParams(instance=config.instance, config_path=config.config_path, **params))


def run(face: EcaVideoService, frames: list[Frame]) -> list[tuple[int, Frame]]:
    """Run the frames through [face, stamper] with pipecat's run_test; what came out, with push times."""
    stamper = Stamper()
    asyncio.run(run_test(Pipeline([face, stamper]), frames_to_send=frames, start_timeout=20.0))
    return stamper.seen


def voice(samples: int, loud: bool, phase: int = 0) -> bytes:
    """A vowel-like sound (a 140 Hz voice with harmonics), or silence."""
    t = (np.arange(samples) + phase) / RATE
    wave = sum(np.sin(2 * np.pi * f * t) / (k + 1) for k, f in enumerate((140, 280, 420, 700, 1100)))
    return (0.5 * loud * wave / 2.0 * 32767).astype("<i2").tobytes()  # peaks near half of full scale


def paced(chunks: list[bytes], context_id: str = "reply-1") -> tuple[list[Frame], list[TTSAudioRawFrame]]:
    """TTS frames of `chunks`, each followed by its own duration of waiting: a TTS streaming in real time."""
    audio = [TTSAudioRawFrame(c, RATE, 1, context_id=context_id) for c in chunks]
    frames: list[Frame] = [TTSStartedFrame(context_id=context_id)]
    for f in audio:
        frames += [f, SleepFrame(sleep=len(f.audio) / 2 / RATE)]
    return frames, audio


def messages(bus: Subscriber) -> list[Message]:
    return [got.message for got in bus.drain() if got.message is not None]


def ended(rid: str | None = None) -> Callable[[list[Message]], bool]:
    """Until a say (the one with `rid`, or any) has its terminal event."""
    terminal = SpeechFinished | SpeechInterrupted | SpeechFailed
    return lambda got: any(isinstance(m, terminal) and rid in (None, m.request_id) for m in got)


def user_speech_sent(heard: list[Message]) -> list[bool]:
    """The face's `user_speech` commands, once each (a repeat has the same request id; the dialogue service's
    event that re-publishes one has none)."""
    sent = {m.request_id: m.speaking for m in heard if isinstance(m, UserSpeech) and m.request_id}
    return list(sent.values())


def collect(bus: Subscriber, until: Callable[[list[Message]], bool], timeout_s: float = 5.0) -> list[Message]:
    """What the bus has brought so far and brings until `until` holds for all of it (or the timeout)."""
    got = messages(bus)
    deadline = time.monotonic() + timeout_s
    while not until(got) and (left := deadline - time.monotonic()) > 0:
        received = bus.recv(left)
        if received is not None and received.message is not None:
            got.append(received.message)
    return got + messages(bus)


def dark_mouth_pixels(frame: OutputImageRawFrame) -> int:
    """The open mouth's dark red inside, counted in a box around the mouth."""
    width, height = frame.size
    rgb = np.frombuffer(frame.image, np.uint8).reshape(height, width, 3).astype(int)
    box = rgb[int(0.6 * height):int(0.9 * height), int(0.35 * width):int(0.65 * width)]
    red, green = box[..., 0], box[..., 1]
    return int(((red - green > 70) & (green < 90)).sum())


def ah(frame: OutputImageRawFrame) -> float:
    return float(frame.metadata["eca_face"]["mouth"]["say_ah"])


def test_tts_audio_becomes_one_streamed_say_that_follows_it_and_ends_once() -> None:
    rng = np.random.default_rng(11)
    sizes = rng.integers(80, 800, size=60)  # 5-50 ms frames, as TTS services send them
    chunks = [voice(int(n), loud=True, phase=int(p)) for n, p in zip(sizes, np.cumsum(sizes), strict=True)]
    with eca_instance() as (config, bus):
        frames, audio = paced(chunks)
        seen = run(face_for(config, video=False), [*frames, TTSStoppedFrame(context_id="reply-1"),
                                                   SleepFrame(sleep=1.0)])
        heard = collect(bus, ended())
    out = [f for _, f in seen if isinstance(f, TTSAudioRawFrame)]
    assert out == audio and all(a is b for a, b in zip(out, audio, strict=True))  # the same frames, in order
    assert b"".join(f.audio for f in out) == b"".join(chunks)
    says = {m.request_id: m for m in heard if isinstance(m, Say)}
    assert len(says) == 1
    (rid, say), = says.items()
    assert say.streamed and say.sample_rate == RATE
    chunk_msgs = {m.index: m for m in heard if isinstance(m, SpeechChunk) and m.request_id == rid}
    assert sorted(chunk_msgs) == list(range(len(chunk_msgs)))
    assert b"".join(chunk_msgs[i].pcm for i in sorted(chunk_msgs)) == b"".join(chunks)  # the same samples
    assert chunk_msgs[max(chunk_msgs)].last and not any(m.last for i, m in chunk_msgs.items() if i != max(chunk_msgs))
    lifecycle = [type(m) for m in heard if isinstance(m, SpeechStarted | SpeechFinished | SpeechInterrupted
                                                      | SpeechFailed) and m.request_id == rid]
    assert lifecycle == [SpeechStarted, SpeechFinished]
    finished = next(m for m in heard if isinstance(m, SpeechFinished))
    assert finished.played_s == pytest.approx(sum(sizes) / RATE, abs=0.011)


def test_pictures_come_at_the_rate_with_the_mouth_open_where_the_audio_is_loud() -> None:
    loud_pattern = [(i // 15) % 2 == 0 for i in range(120)]  # 0.3 s of voice, 0.3 s of silence, ... (2.4 s)
    chunks = [voice(FRAME, loud, i * FRAME) for i, loud in enumerate(loud_pattern)]
    with eca_instance() as (config, _):
        frames, audio = paced(chunks)
        seen = run(face_for(config, width=320, height=240, fps=30.0),
                   [*frames, TTSStoppedFrame(context_id="reply-1"), SleepFrame(sleep=0.3)])
    audio_at = [(t, f) for t, f in seen if isinstance(f, TTSAudioRawFrame)]
    pictures = [(t, f) for t, f in seen if isinstance(f, OutputImageRawFrame)]
    start = audio_at[0][0]
    # over most of the voice (2.4 s): the pictures come at the rate (their median spacing is a frame's, which a wrong
    # pace shows and a few pictures a loaded machine draws late or drops do not), and none stalls for long
    span = [t for t, _ in pictures if start + 0.4e9 <= t < start + 2.3e9]
    spacing_ms = np.diff(span) / 1e6
    assert abs(np.median(spacing_ms) - 1000 / 30) <= 0.1 * 1000 / 30, f"median spacing {np.median(spacing_ms):.1f} ms"
    assert 0.75 * 30 * 1.9 <= len(span) <= 1.1 * 30 * 1.9, f"{len(span)} pictures in 1.9 s at 30 fps"
    assert all(f.size == (320, 240) and f.format == "RGB" and len(f.image) == 320 * 240 * 3 for _, f in pictures)

    # Each picture shows the moment it was composed for (frame_ns), which is when it was pushed, give or
    # take the loop's jitter ...
    late_ms = [(t - f.metadata["eca_face"]["frame_ns"]) / 1e6 for t, f in pictures]
    assert abs(np.median(late_ms)) <= 15.0 and np.percentile(np.abs(late_ms), 80) <= 33.0, sorted(late_ms)
    # ... and at that moment, the mouth of the sound the transport plays: open in the voice, shut in the
    # silence, but for the lip-sync's own attack and release (60 ms after each change). The transport plays
    # each frame from when it is pushed, or when the one before it ends if that is later (a frame that
    # comes late leaves a moment of silence). A picture composed before the audio it shows was pushed (a
    # loaded machine pushes the paced audio late) could only guess, and is not judged.
    heard = heard_intervals(audio_at)
    changes = [heard[i][0] for i in range(len(heard)) if i == 0 or loud_pattern[i] != loud_pattern[i - 1]]
    loud, quiet = [], []
    for _, picture in pictures:
        moment = picture.metadata["eca_face"]["frame_ns"]
        playing = [i for i, (a, b) in enumerate(heard) if a <= moment < b]
        if not playing or any(0 <= moment - change < 60e6 for change in changes):
            continue
        if picture.metadata["eca_face"]["drawn_ns"] < audio_at[playing[0]][0]:
            continue
        (loud if loud_pattern[playing[0]] else quiet).append(picture)
        picture.metadata["test"] = f"{(moment - start) / 1e6:.0f} ms in, audio frame {playing[0]}"
    assert len(loud) >= 20 and len(quiet) >= 20
    assert min(ah(p) for p in loud) > 0.15, [(p.metadata["test"], ah(p)) for p in loud if ah(p) <= 0.15]
    assert max(ah(p) for p in quiet) < 0.05, [(p.metadata["test"], ah(p)) for p in quiet if ah(p) >= 0.05]
    open_px = np.mean([dark_mouth_pixels(p) for p in loud])
    closed_px = np.mean([dark_mouth_pixels(p) for p in quiet])
    assert open_px > 2 * closed_px, (open_px, closed_px)


def heard_intervals(audio_at: list[tuple[int, TTSAudioRawFrame]]) -> list[tuple[int, int]]:
    """When the transport plays each audio frame: from its push, or from the end of the one before."""
    out: list[tuple[int, int]] = []
    end = 0
    for pushed, frame in audio_at:
        begin = max(pushed, end)
        end = begin + len(frame.audio) // 2 * 1_000_000_000 // frame.sample_rate
        out.append((begin, end))
    return out


def test_the_users_turn_and_an_interruption_stop_the_say_and_close_the_mouth() -> None:
    chunks = [voice(FRAME, True, i * FRAME) for i in range(50)]  # 1 s of the bot talking ...
    with eca_instance() as (config, bus):
        frames, audio = paced(chunks)
        user_starts = UserStartedSpeakingFrame()
        interruption = InterruptionFrame()
        seen = run(face_for(config, width=320, height=240, fps=30.0),
                   [*frames, user_starts, interruption, SleepFrame(sleep=1.0),  # ... then the user cuts in
                    UserStoppedSpeakingFrame(), SleepFrame(sleep=0.5)])
        heard = collect(bus, lambda got: ended()(got) and len(user_speech_sent(got)) == 2)
    says = [m.request_id for m in heard if isinstance(m, Say)]
    assert len(set(says)) == 1
    endings = [m for m in heard if isinstance(m, SpeechFinished | SpeechInterrupted | SpeechFailed)
               and m.request_id == says[0]]
    assert len(endings) == 1 and isinstance(endings[0], SpeechInterrupted), endings
    assert user_speech_sent(heard) == [True, False]
    roles = [m for m in heard if isinstance(m, RoleState)]
    assert roles and roles[-1].role == "listening" and roles[-1].speaker == "user"

    cut_at = next(t for t, f in seen if f is interruption)
    before = [f for t, f in seen if isinstance(f, OutputImageRawFrame) and cut_at - 0.6e9 < t < cut_at - 0.1e9]
    after = [f for t, f in seen if isinstance(f, OutputImageRawFrame) and t > cut_at]
    assert before and np.median([ah(f) for f in before]) > 0.15  # the mouth was open while the bot talked ...
    assert len(after) >= 30
    assert max(ah(f) for f in after) < 0.02, [round(ah(f), 3) for f in after[:10]]  # ... and shut at once
    assert max(dark_mouth_pixels(f) for f in after) < 0.75 * np.median([dark_mouth_pixels(f) for f in before])


def test_the_user_starting_to_speak_alone_interrupts_the_say_on_eca() -> None:
    """eca's own barge-in: in a pipeline that lets the user talk over the bot (no InterruptionFrame), the
    user's speech still stops eca's say (eca's reason for it) and makes the agent listen; the pipeline's
    audio passes untouched, and what the bot goes on saying is voiced as a say of its own."""
    chunks = [voice(FRAME, True, i * FRAME) for i in range(50)]  # 1 s of the bot talking
    with eca_instance() as (config, bus):
        first, audio = paced(chunks[:25])
        rest, more = paced(chunks[25:])
        seen = run(face_for(config, video=False),
                   [*first, UserStartedSpeakingFrame(), *rest[1:], TTSStoppedFrame(context_id="reply-1"),
                    SleepFrame(sleep=1.0)])
        heard = collect(bus, lambda got: sum(ended(rid)(got) for rid in {m.request_id for m in got
                                                                          if isinstance(m, Say)}) == 2)
    assert [f for _, f in seen if isinstance(f, TTSAudioRawFrame)] == audio + more
    says = list(dict.fromkeys(m.request_id for m in heard if isinstance(m, Say)))
    assert len(says) == 2, says
    endings = {m.request_id: m for m in heard if isinstance(m, SpeechFinished | SpeechInterrupted | SpeechFailed)}
    assert isinstance(endings[says[0]], SpeechInterrupted)
    assert endings[says[0]].reason == "the user started speaking"
    assert isinstance(endings[says[1]], SpeechFinished)
    assert user_speech_sent(heard) == [True]
    assert any(isinstance(m, RoleState) and m.role == "listening" and m.speaker == "user" for m in heard)


def test_a_say_and_its_chunks_lost_before_the_dialogue_service_came_up_are_sent_again() -> None:
    chunks = [voice(FRAME, True, i * FRAME) for i in range(25)]  # 0.5 s, all sent before eca can hear it
    with private_bus_config(services=["dialogue", "audio"]) as config, BrokerThread(config):
        ctx = zmq.Context()
        bus = Subscriber(ctx, config, ["event.ada."])
        bus.wait_ready()
        late = ServiceThread(DialogueService(config))
        comes_up = threading.Timer(1.0, late.__enter__)
        audio = AudioService(config, sink_factory=lambda: NullSink(48_000, 480, latency_s=0.05))
        try:
            with ServiceThread(audio):
                comes_up.start()
                frames, _ = paced(chunks)
                run(face_for(config, video=False), [*frames, TTSStoppedFrame(context_id="reply-1"),
                                                    SleepFrame(sleep=3.0)])
                heard = collect(bus, ended())
        finally:
            comes_up.join()
            late.__exit__(None, None, None)
            bus.close()
            ctx.term()
    lifecycle = [m for m in heard if isinstance(m, SpeechStarted | SpeechFinished | SpeechInterrupted | SpeechFailed)]
    assert [type(m) for m in lifecycle] == [SpeechStarted, SpeechFinished], lifecycle
    assert len({m.request_id for m in lifecycle}) == 1
    assert lifecycle[1].played_s == pytest.approx(0.5, abs=0.011)  # every chunk, none twice


def test_bad_parameters_are_refused_with_the_reason() -> None:
    for params, needle in ((dict(fps=0.0), "fps"), (dict(width=641), "even"), (dict(agent="a b"), "agent"),
                           (dict(video_lead_s=2.0), "video_lead_s"), (dict(width=8), "width")):
        with pytest.raises(ValueError, match=needle):
            EcaFaceParams(**params).check()  # type: ignore[arg-type]


def test_an_eca_that_cannot_be_reached_is_reported_and_the_voice_still_passes() -> None:
    """No broker on the instance: the setup fails with eca's reason as an error upstream (pipecat's default
    policy keeps the pipeline running), and the bot's audio goes on untouched, without a face."""
    with private_bus_config(services=["dialogue"]) as config:  # its broker never starts
        audio = TTSAudioRawFrame(voice(FRAME, True), RATE, 1)
        face = face_for(config, video=False, connect_timeout_s=0.3)
        down, up = asyncio.run(run_test(face, frames_to_send=[audio, SleepFrame(sleep=0.2)], start_timeout=10.0))
    assert [f for f in down if isinstance(f, TTSAudioRawFrame)] == [audio]
    errors = [f.error for f in up if isinstance(f, ErrorFrame)]
    assert len(errors) == 1 and "no broker answered at" in errors[0] and "eca up" in errors[0], errors
    assert face.face_link is None
