"""The player: one agent's queue of utterances played through a sink; the master clock of speech.

Four threads touch it, and each owns its part:
- the caller (the service loop) only files requests: a track and its source (a file to open, PCM held
  in memory, a stream whose chunks it appends as they come) go into the queue, and an interruption
  marks tracks cut. Nothing it does grows with the length of the audio;
- the preparer (a thread for real-time sinks; for a sink the caller drives, a step before each block)
  turns sources into playable audio in slices of `prepare_slice_s` of source audio: decode, convert to
  the device rate, compute mouth keys, hand the keys to the publisher and only then append the samples
  those keys cover to the track, so keys always precede their sound. It serves the queue in order and
  pauses while what is prepared ahead of playback, up to and including the track at hand, reaches
  `read_ahead_s`, so a long file starts at once and never sits in memory whole. A failure it meets
  ends the track where its good audio ends; it lets go of a cut track's source at its next step;
- the sink's callback only copies prepared samples (dropping each chunk once played) and appends small
  records (what it copied, and the block's timing stamp) to a deque; it takes no lock, logs nothing,
  and never waits: when the next samples are not prepared yet it plays silence until they are, as for
  a late streamed chunk. With `publish_voice` it also records a copy of the whole block it filled
  (the sink reuses its buffer) and the utterance its first sample belongs to;
- the publisher (`pump`, a thread for real-time sinks, the sink's own step for the fake sink) turns
  records into events: DAC times mapped to the monotonic clock, lifecycle, clock anchors, and voice
  blocks (each recorded block as int16 with its DAC time and its index in the output). All events
  reach `on_event` from this one thread, in order; terminal events come only from the callback's
  records, so they follow the queue's order.
"""

from __future__ import annotations

import logging
import threading
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from eca.agent.clock import Clock, MonotonicClock
from eca.agent.lipsync import LipSyncConfig, LipSyncEstimator
from eca.services.processes.audio.config import AudioConfig
from eca.services.processes.audio.events import (
    AudioEvent,
    PlayerAnchor,
    PlayerFailed,
    PlayerFinished,
    PlayerInterrupted,
    PlayerMouthKeys,
    PlayerMouthReset,
    PlayerStarted,
    PlayerVoiceBlock,
)
from eca.services.processes.audio.files import AudioFileError, MonoReader, open_sound_file
from eca.services.processes.audio.resample import Resampler
from eca.services.processes.audio.sinks import Sink
from eca.services.processes.audio.tts import SpeechSynthesisError, TextToSpeech

log = logging.getLogger(__name__)

MIN_RATE, MAX_RATE = 4000, 384_000  # source sample rates the resampler is trusted with

# While the read-ahead is full: how often the preparer looks whether playback has made room (a new
# request or chunk wakes it at once).
_REFILL_POLL_S = 0.05
_IDLE_POLL_S = 1.0  # with nothing to prepare; a request, chunk, interruption or close wakes it anyway

# Record kinds appended by the callback.
_BUFFER, _PLAY, _END, _CUT, _VOICE = range(5)

# What one preparation step found.
_WORKED, _FULL, _NOTHING = range(3)


class _Source:
    """Where a track's audio comes from. Opened and read by the preparer only; `read` returns mono
    float32 at `sample_rate` and whether the source is done."""

    sample_rate = 0
    what = "audio"  # how a failure reason names it

    def failure_reason(self, exc: Exception) -> str:
        """The speech_failed reason for what went wrong while preparing it."""
        return f"bad {self.what}: {exc}"

    def open(self) -> None:
        """Called once, on the preparer, before the first read."""

    def ready(self) -> bool:
        """Whether a read now would give samples or the end."""
        return True

    def read(self, max_frames: int) -> tuple[np.ndarray, bool]:
        raise NotImplementedError

    def close(self) -> None:
        """Let go of what it holds (a file, samples); called once, on the preparer."""


class _FileSource(_Source):
    def __init__(self, path: str | Path, max_seconds: float) -> None:
        self.path = path
        self.max_seconds = max_seconds
        self.reader: MonoReader | None = None

    def open(self) -> None:
        self.reader = MonoReader(open_sound_file(self.path, self.max_seconds), self.path)
        rate = self.reader.sample_rate
        if not MIN_RATE <= rate <= MAX_RATE:
            raise AudioFileError(self.path, f"has a sample rate of {rate} Hz, outside {MIN_RATE}-{MAX_RATE} Hz")
        self.sample_rate = rate

    def read(self, max_frames: int) -> tuple[np.ndarray, bool]:
        assert self.reader is not None
        pcm = self.reader.read(max_frames)
        return pcm, self.reader.done

    def failure_reason(self, exc: Exception) -> str:
        if isinstance(exc, AudioFileError):
            return str(exc)
        return str(AudioFileError(self.path, f"could not be played: {exc}"))

    def close(self) -> None:
        if self.reader is not None:
            self.reader.close()
            self.reader = None


class _PcmSource(_Source):
    what = "PCM"

    def __init__(self, samples: np.ndarray, sample_rate: int) -> None:
        self.samples: np.ndarray | None = samples
        self.sample_rate = sample_rate
        self.position = 0

    def open(self) -> None:
        assert self.samples is not None
        # One vectorised pass over audio already in memory, so bad PCM fails before any of it plays.
        if self.samples.dtype.kind == "f" and not np.isfinite(self.samples).all():
            raise ValueError("PCM holds NaN or infinity")

    def read(self, max_frames: int) -> tuple[np.ndarray, bool]:
        assert self.samples is not None
        piece = self.samples[self.position : self.position + max_frames]
        self.position += len(piece)
        return _to_mono_float(piece), self.position >= len(self.samples)

    def close(self) -> None:
        self.samples = None


class _TextSource(_PcmSource):
    """Text voiced by a text-to-speech engine when the preparer opens it (the engine runs as its own
    process, off the service loop); then read like PCM held in memory."""

    what = "text"

    def __init__(self, text: str, tts: TextToSpeech, max_seconds: float) -> None:
        super().__init__(np.zeros(0, np.float32), 0)
        self.text, self.tts, self.max_seconds = text, tts, max_seconds

    def open(self) -> None:
        samples, rate = self.tts.speak(self.text)
        _check_rate(rate)
        if len(samples) / rate > self.max_seconds:
            raise ValueError(f"its speech lasts {len(samples) / rate:.0f} s, longer than {self.max_seconds:g} s")
        self.samples, self.sample_rate = samples, rate
        super().open()

    def failure_reason(self, exc: Exception) -> str:
        return f"the text could not be spoken: {exc}"


class _StreamSource(_Source):
    """Chunks appended by the caller (`feed`) as they arrive; the preparer takes them in order."""

    what = "chunk"

    def __init__(self, sample_rate: int) -> None:
        self.sample_rate = sample_rate
        self.pending: deque[np.ndarray] = deque()  # caller appends, preparer pops
        self.received = 0  # caller only: frames accepted so far
        self.last_received = False  # caller: the final chunk has been appended (set after it)
        self._head_offset = 0  # preparer only: frames of pending[0] already taken

    def ready(self) -> bool:
        return bool(self.pending) or self.last_received

    def read(self, max_frames: int) -> tuple[np.ndarray, bool]:
        # Read the end flag first: the caller sets it after appending the final chunk, so if it is set
        # now, an empty queue below really is the end.
        ending = self.last_received
        pieces: list[np.ndarray] = []
        want = max_frames
        while want > 0 and self.pending:
            head = self.pending[0]
            piece = head[self._head_offset : self._head_offset + want]
            pieces.append(piece)
            want -= len(piece)
            self._head_offset += len(piece)
            if self._head_offset >= len(head):
                self.pending.popleft()
                self._head_offset = 0
        # Each piece on its own: chunks of one stream may differ in sample type or channel count.
        pcm = np.concatenate([_to_mono_float(p) for p in pieces]) if pieces else np.zeros(0, np.float32)
        return pcm, ending and not self.pending

    def close(self) -> None:
        self.pending.clear()


class _Track:
    """One utterance. The preparer appends chunks; the callback owns the cursor and drops played chunks."""

    __slots__ = ("uid", "source", "chunks", "fed", "complete", "cut", "played", "chunk_off", "resampler",
                 "estimator", "held", "started", "closed", "failure", "ended", "start_ns")

    def __init__(self, uid: str, source: _Source | None, start_ns: int = 0) -> None:
        self.uid = uid
        self.start_ns = start_ns  # its first sample reaches the DAC no earlier (0: as soon as it can)
        self.source = source  # None: nothing to prepare (a request refused at once)
        self.chunks: deque[np.ndarray] = deque()
        self.fed = 0  # samples appended so far (published after the chunk itself)
        self.complete = source is None  # no more chunks will come (set after the last one is appended)
        self.cut = False  # interrupted: the callback drops it at its next block, the preparer its source
        self.played = 0  # samples handed to the DAC (callback only)
        self.chunk_off = 0  # callback only: samples of chunks[0] already played
        self.resampler: Resampler | None = None  # preparer only, from the source's first slice
        self.estimator: LipSyncEstimator | None = None
        self.held = np.zeros(0, np.float32)  # preparer only: converted samples whose key is not out yet
        self.started = False  # publisher only
        self.closed = False  # a terminal outcome is decided (under the lock): feeds are ignored
        self.failure: str | None = None  # set under the lock, before `complete`: it ends as PlayerFailed
        self.ended = False  # publisher only: its terminal event is out

    def append(self, samples: np.ndarray) -> None:
        if len(samples):
            self.chunks.append(samples)
            self.fed += len(samples)


class Player:
    """Plays one agent's utterances in order and reports them through `on_event`.

    Requests: `say_file`, `say_pcm`, `say_text`, `say_stream` + `feed`; each returns at once, the audio is prepared
    by the preparer. `interrupt` stops the voice within one block. Every request ends in exactly one of
    PlayerFinished, PlayerInterrupted, PlayerFailed, in queue order. Utterance ids must be unique among
    the requests still in flight (a repeat raises ValueError).

    With `publish_voice`, every block the sink takes that sounds is also reported as a PlayerVoiceBlock, in
    order, after the lifecycle events of that block: one track for outputs in other processes, on which a
    block of pure silence is the gap its successor's `first_sample` leaves.
    """

    def __init__(self, sink: Sink, on_event: Callable[[AudioEvent], None], *, agent_id: str = "agent",
                 clock: Clock | None = None, config: AudioConfig | None = None,
                 lipsync_config: LipSyncConfig | None = None, publish_voice: bool = False,
                 tts: TextToSpeech | None = None) -> None:
        self.sink = sink
        self.tts = tts  # voices say_text; None: a text request fails
        self.on_event = on_event
        self.agent_id = agent_id
        self.clock = clock if clock is not None else MonotonicClock()
        self.config = config if config is not None else AudioConfig()
        self.lipsync_config = lipsync_config if lipsync_config is not None else LipSyncConfig.load()
        self.sample_rate = sink.sample_rate
        # For a sink the caller drives: how many slices the step before each block may prepare (None: as
        # many as the read-ahead allows). A small number stands in for a machine too slow to keep up.
        self.driven_slices_per_block: int | None = None
        self._read_ahead = round(self.config.read_ahead_s * self.sample_rate)
        self._tracks: deque[_Track] = deque()  # queue in play order; the callback pops the head
        self._active: dict[str, _Track] = {}  # requests without a terminal event yet
        self._preparing: list[_Track] = []  # under the lock: tracks whose source the preparer still holds
        self._records: deque[tuple[Any, ...]] = deque()  # callback -> publisher
        self._outbox: deque[tuple[_Track, AudioEvent]] = deque()  # preparer -> publisher (mouth keys)
        self._buffer_dac_ns = 0
        self._publish_voice = publish_voice  # set once: the voice's sample count runs from the output's start
        self._voice_sample = 0  # publisher only: output index of the next voice block's first sample
        self._latest: tuple[_Track, int, int, int] | None = None  # track, sample, dac_ns, count
        self._next_anchor_ns: int | None = None
        self._anchor_period_ns = round(1e9 / self.config.anchor_hz)
        self._lock = threading.Lock()  # bookkeeping of the caller, preparer and publisher; never the callback
        self._stop = threading.Event()
        self._wake = threading.Event()  # a request, chunk or interruption for the preparer
        self._publisher: threading.Thread | None = None
        self._preparer: threading.Thread | None = None
        self._started = False

    # ------------------------------------------------------------------ life cycle

    def start(self) -> Player:
        if self._started:
            return self
        self._started = True
        self._stop.clear()
        if self.sink.realtime:
            # a sink whose thread is not a sound card's callback (the silent one) runs the publisher step itself,
            # after each block: no thread of its own per agent
            drives = getattr(self.sink, "drives_publisher", False)
            self.sink.start(self._render, self.pump if drives else None)
            self._preparer = threading.Thread(target=self._prepare_loop, name=f"audio-preparer-{self.agent_id}",
                                              daemon=True)
            self._preparer.start()
            if not drives:
                self._publisher = threading.Thread(target=self._publish_loop,
                                                   name=f"audio-publisher-{self.agent_id}", daemon=True)
                self._publisher.start()
        else:
            self.sink.start(self._render_driven, self.pump)
        return self

    def close(self) -> None:
        self._stop.set()
        self._wake.set()
        preparer, publisher = self._preparer, self._publisher
        self._preparer = self._publisher = None
        for thread in (preparer, publisher):
            if thread is not None:
                thread.join(timeout=2.0)
        if self._started:
            self.sink.stop()
            self._started = False
        if preparer is None or not preparer.is_alive():  # else it lets go of them when its slice ends
            self._release_sources(everything=True)

    def __enter__(self) -> Player:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _publish_loop(self) -> None:
        period = 1.0 / self.config.publisher_hz
        while not self._stop.wait(period):  # a paced loop, not synchronisation: it polls the records
            try:
                self.pump()
            except Exception:  # the publisher must outlive a bad event handler
                log.exception("audio publisher step failed")

    # ------------------------------------------------------------------ requests (caller thread)

    # Each say_* takes `start_ns`: its first sample reaches the DAC at that time (master clock), or as soon after
    # as the queue allows; the output plays silence until then (a BML block's speech lands on its schedule).

    def say_file(self, request_id: str, path: str | Path, start_ns: int = 0) -> None:
        """Play an audio file (WAV, FLAC, OGG... through soundfile). It is opened, decoded and analysed
        by the preparer, slice by slice ahead of playback; a file that cannot be read fails the request
        with a reason naming the file."""
        self._check_new(request_id)
        self._enqueue(_Track(request_id, _FileSource(path, self.config.max_utterance_s), start_ns))

    def say_pcm(self, request_id: str, samples: np.ndarray, sample_rate: int, start_ns: int = 0) -> None:
        """Play PCM held in memory: float in [-1, 1] or int16, mono or frames x channels. The player reads
        `samples` later, on the preparer: the array must not change until the request has ended."""
        self._check_new(request_id)
        try:
            _check_rate(sample_rate)
            pcm = _check_pcm(samples)
            if len(pcm) / sample_rate > self.config.max_utterance_s:
                raise ValueError(f"longer than {self.config.max_utterance_s:g} s")
        except ValueError as exc:
            self._enqueue_failed(request_id, f"bad PCM: {exc}")
            return
        self._enqueue(_Track(request_id, _PcmSource(pcm, int(sample_rate)), start_ns))

    def say_text(self, request_id: str, text: str, start_ns: int = 0) -> None:
        """Speak `text` through the player's text-to-speech engine; the engine runs on the preparer, and a
        missing or failing engine fails the request with its reason."""
        self._check_new(request_id)
        if self.tts is None:
            self._enqueue_failed(request_id, "the text could not be spoken: no text-to-speech engine is set up")
            return
        self._enqueue(_Track(request_id, _TextSource(text, self.tts, self.config.max_utterance_s), start_ns))

    def say_stream(self, request_id: str, sample_rate: int, start_ns: int = 0) -> None:
        """Open an utterance whose PCM arrives later through `feed` (streaming TTS). It takes its place
        in the queue now; if its chunks arrive late, the output waits in silence for them."""
        self._check_new(request_id)
        try:
            _check_rate(sample_rate)
        except ValueError as exc:
            self._enqueue_failed(request_id, f"bad stream: {exc}")
            return
        self._enqueue(_Track(request_id, _StreamSource(int(sample_rate)), start_ns))

    def feed(self, request_id: str, chunk: np.ndarray, last: bool = False) -> bool:
        """Append a chunk to a streamed utterance (read later, on the preparer: it must not change).
        Returns False (and ignores the chunk) when the utterance is no longer in flight, e.g. after an
        interruption, or takes no more chunks."""
        with self._lock:
            track = self._active.get(request_id)
        source = track.source if track is not None else None
        if track is None or track.closed or not isinstance(source, _StreamSource) or source.last_received:
            return False
        try:
            pcm = _check_pcm(chunk)
            if (source.received + len(pcm)) / source.sample_rate > self.config.max_utterance_s:
                raise ValueError(f"stream longer than {self.config.max_utterance_s:g} s")
        except ValueError as exc:
            self._fail_track(track, f"bad chunk: {exc}")
            return False
        if len(pcm):
            source.pending.append(pcm)
            source.received += len(pcm)
        if last:
            source.last_received = True
        self._wake.set()
        return True

    def interrupt(self, request_id: str | None = None) -> list[str]:
        """Stop the voice within one block. None: the current utterance and every queued one (barge-in);
        an id: only that utterance. Returns the ids that end as interrupted (one whose failure is already
        decided is silenced too, and still ends as failed). The callback reports how much was played."""
        with self._lock:
            stopped = []
            # list() copies the deque in one C call, so the callback cannot mutate it mid-iteration.
            for track in list(self._tracks):
                if track.cut or (request_id is not None and track.uid != request_id):
                    continue
                track.cut = True  # seen by the callback at its next block, by the preparer at its next step
                if track.failure is None:
                    track.closed = True
                    stopped.append(track.uid)
        self._wake.set()
        return stopped

    @property
    def idle(self) -> bool:
        """Nothing queued or playing, and every terminal event has been emitted."""
        with self._lock:
            return not self._active

    @property
    def prepared_ahead_s(self) -> float:
        """Seconds of audio prepared and not yet played, over the whole queue."""
        return sum(t.fed - t.played for t in list(self._tracks) if not t.cut) / self.sample_rate

    # ------------------------------------------------------------------ request helpers

    def _check_new(self, request_id: str) -> None:
        if not isinstance(request_id, str) or not request_id:
            raise ValueError("request_id must be a non-empty string")
        with self._lock:
            if request_id in self._active:
                raise ValueError(f"utterance {request_id!r} is already in flight")

    def _enqueue(self, track: _Track) -> None:
        with self._lock:
            self._active[track.uid] = track
            self._tracks.append(track)
            if track.source is not None:
                self._preparing.append(track)
        self._wake.set()

    def _enqueue_failed(self, request_id: str, reason: str) -> None:
        # It still takes its place in the queue, so its terminal event keeps the queue's order.
        track = _Track(request_id, None)
        track.failure = reason
        track.closed = True
        self._enqueue(track)

    def _fail_track(self, track: _Track, reason: str) -> None:
        """End a track as failed where its prepared audio ends (any thread but the callback's)."""
        with self._lock:
            if track.cut or track.failure is not None:
                return  # already interrupted, or failed: it ends that way
            track.failure = reason
            track.closed = True
        track.complete = True  # after `failure`: whoever sees it complete sees why

    # ------------------------------------------------------------------ the preparer

    def _prepare_loop(self) -> None:
        try:
            while not self._stop.is_set():
                self._wake.clear()  # before the step: a request filed during it wakes the wait below
                try:
                    found = self._prepare_step()
                except Exception:  # the preparer must outlive a bug in one step
                    log.exception("audio preparation step failed")
                    found = _FULL
                if found != _WORKED:
                    self._wake.wait(_REFILL_POLL_S if found == _FULL else _IDLE_POLL_S)
        finally:
            self._release_sources(everything=True)

    def _render_driven(self, out: np.ndarray, stamp: Any) -> None:
        """For a sink the caller drives: the preparer's steps due before this block, then the block."""
        budget = self.driven_slices_per_block
        done = 0
        while (budget is None or done < budget) and self._prepare_step() == _WORKED:
            done += 1
        self._render(out, stamp)

    def _prepare_step(self) -> int:
        """Prepare one slice of the first track, in queue order, that has something to prepare, while
        what is prepared ahead of playback up to and including it is under the read-ahead."""
        if not self._release_sources():
            return _NOTHING
        ahead = 0
        for track in list(self._tracks):
            if track.cut:
                continue
            ahead += track.fed - track.played
            if ahead >= self._read_ahead:
                return _FULL
            source = track.source
            if track.complete or source is None or not source.ready():
                continue
            self._prepare_slice(track, source)
            return _WORKED
        return _NOTHING  # what is left waits for chunks, and a chunk wakes the preparer

    def _prepare_slice(self, track: _Track, source: _Source) -> None:
        try:
            if track.estimator is None:  # the first slice: open the source, set up the converters
                source.open()
                rate = source.sample_rate
                track.resampler = None if rate == self.sample_rate else Resampler(rate, self.sample_rate)
                track.estimator = LipSyncEstimator(self.sample_rate, self.lipsync_config)
            frames = max(1, round(self.config.prepare_slice_s * source.sample_rate))
            pcm, last = source.read(frames)
            self._ingest(track, pcm, last)
        except Exception as exc:  # it fails this request only; the preparer goes on
            if not isinstance(exc, ValueError | SpeechSynthesisError):  # not bad input: a bug, keep its traceback
                log.exception("cannot prepare %s", track.uid)
            self._fail_track(track, source.failure_reason(exc))

    def _ingest(self, track: _Track, pcm: np.ndarray, last: bool) -> None:
        """Convert to the device rate and compute mouth keys; hand the keys to the publisher, then make
        playable the samples they cover. The samples of a block not analysed yet (its key comes with the
        next slice) wait in `held`, so every sample has its key out before it can play."""
        out = track.resampler.process(pcm) if track.resampler is not None else pcm.astype(np.float32)
        if last and track.resampler is not None:
            out = np.concatenate((out, track.resampler.flush()))
        estimator = track.estimator
        assert estimator is not None
        keys = estimator.push(out)
        if last:
            keys.extend(estimator.flush())
        if keys:
            self._outbox.append((track, PlayerMouthKeys(self.agent_id, track.uid, self.sample_rate, tuple(keys))))
        samples = np.concatenate((track.held, out)) if len(track.held) else out
        covered = len(samples) if last else estimator.position - track.fed
        track.held = samples[covered:]
        track.append(np.clip(samples[:covered], -1.0, 1.0).astype(np.float32, copy=False))
        if last:
            track.complete = True

    def _release_sources(self, everything: bool = False) -> bool:
        """Let go of the sources of tracks that are prepared, cut or failed (all of them with
        `everything`). Returns whether any source is still held."""
        with self._lock:
            held = self._preparing
            done = held if everything else [t for t in held if t.cut or t.complete]
            if done:
                self._preparing = [] if everything else [t for t in held if not (t.cut or t.complete)]
            still = bool(self._preparing)
        for track in done:
            assert track.source is not None
            track.source.close()
            track.resampler = None
            track.estimator = None
            track.held = np.zeros(0, np.float32)
        return still

    # ------------------------------------------------------------------ the callback (real-time thread)

    def _render(self, out: np.ndarray, stamp: Any) -> None:
        records = self._records
        block_dac_ns = self.sink.dac_time_ns(stamp)  # once per block (the clock map follows the blocks)
        records.append((_BUFFER, block_dac_ns))
        tracks = self._tracks
        n = len(out)
        pos = 0
        first_uid = ""  # the utterance whose sample starts the block, for the voice block
        while pos < n and tracks:
            t = tracks[0]
            if t.cut:
                records.append((_CUT, t, t.played, pos))
                tracks.popleft()
                continue
            complete = t.complete  # read before `fed`: once complete, `fed` is final
            if t.played >= t.fed:
                if complete:
                    records.append((_END, t, t.played, pos))
                    tracks.popleft()
                    continue
                break  # the next samples are not prepared (or not streamed) yet: silence until they are
            if t.played == 0 and t.start_ns:
                # Not yet due: silence up to the sample that reaches the DAC at its start time.
                wait = -(-(t.start_ns - block_dac_ns) * self.sample_rate // 1_000_000_000) - pos
                if wait > 0:
                    if pos + wait >= n:
                        break
                    out[pos : pos + wait] = 0.0
                    pos += wait
            chunk = t.chunks[0]
            take = min(n - pos, len(chunk) - t.chunk_off)
            out[pos : pos + take] = chunk[t.chunk_off : t.chunk_off + take]
            records.append((_PLAY, t, t.played, pos, take))
            if pos == 0:
                first_uid = t.uid
            t.played += take
            t.chunk_off += take
            if t.chunk_off == len(chunk):
                t.chunks.popleft()  # played: its memory goes back
                t.chunk_off = 0
            pos += take
            if t.complete and t.played >= t.fed:
                records.append((_END, t, t.played, pos))
                tracks.popleft()
        if pos < n:
            out[pos:] = 0.0
        if self._publish_voice:
            # a copy (the sink fills `out` again next block), and only of a block that sounds: silence is the gap
            # between blocks, so a listening agent costs the bus and its outputs nothing
            records.append((_VOICE, out.copy() if out.any() else None, first_uid, n))

    # ------------------------------------------------------------------ the publisher

    def pump(self) -> None:
        """Turn what the callback recorded into events. Runs on one thread only."""
        emit = self.on_event
        outbox = self._outbox
        records = self._records
        # Only records made before the keys drained next: their samples were prepared before, so their
        # keys are among them, and no DAC time goes out for a sample whose key has not.
        due = len(records)
        while outbox:
            owner, event = outbox.popleft()
            if not owner.ended:  # keys the preparer computed while the track was being cut are moot
                emit(event)
        sr = self.sample_rate
        for _ in range(due):
            rec = records.popleft()
            kind = rec[0]
            if kind == _BUFFER:
                self._buffer_dac_ns = rec[1]
                continue
            if kind == _VOICE:  # the block's last record: its _BUFFER set the DAC time above
                block = rec[1]
                if block is not None:
                    emit(PlayerVoiceBlock(self.agent_id, rec[2], self._voice_sample, sr, self._buffer_dac_ns,
                                          pcm16_bytes(block)))
                self._voice_sample += rec[3]
                continue
            track: _Track = rec[1]
            dac_ns = self._buffer_dac_ns + (rec[3] * 1_000_000_000) // sr
            if kind == _PLAY:
                if not track.started:
                    track.started = True
                    emit(PlayerStarted(self.agent_id, track.uid, sr, dac_ns))
                self._latest = (track, rec[2], dac_ns, rec[4])
            elif kind == _END:
                # Reported when the last sample is handed over (with the time it leaves the DAC), so a
                # queue's events stay in order: this one ends before the next one starts.
                self._terminate(track)
                if track.failure is not None:  # its good audio has played: now it fails
                    if track.started:
                        emit(PlayerMouthReset(self.agent_id, track.uid, dac_ns))
                    emit(PlayerFailed(self.agent_id, track.uid, track.failure))
                    continue
                if not track.started:  # an empty utterance still starts before it finishes
                    track.started = True
                    emit(PlayerStarted(self.agent_id, track.uid, sr, dac_ns))
                emit(PlayerFinished(self.agent_id, track.uid, rec[2] / sr, dac_ns))
            else:  # _CUT
                self._terminate(track)
                if self._latest is not None and self._latest[0] is track:
                    self._latest = None
                if track.started:
                    emit(PlayerMouthReset(self.agent_id, track.uid, dac_ns))
                if track.failure is not None:
                    emit(PlayerFailed(self.agent_id, track.uid, track.failure))
                else:
                    played_s = rec[2] / sr if track.started else 0.0
                    emit(PlayerInterrupted(self.agent_id, track.uid, played_s, dac_ns))
        self._emit_anchor()

    def _terminate(self, track: _Track) -> None:
        track.ended = True
        with self._lock:
            track.closed = True
            if self._active.get(track.uid) is track:
                del self._active[track.uid]

    def _emit_anchor(self) -> None:
        latest = self._latest
        if latest is None:
            return
        track, sample, dac_ns, count = latest
        now = self.clock.now_ns()
        block_end_ns = dac_ns + (count * 1_000_000_000) // self.sample_rate
        if track.ended and now > block_end_ns:
            self._latest = None  # the utterance's last sample has left the DAC: anchors stop
            return
        if self._next_anchor_ns is not None and now < self._next_anchor_ns:
            return
        # Anchors are due on a fixed schedule (anchor_hz on average whatever the publisher's phase); after
        # a stall the schedule restarts from now instead of bursting to catch up.
        due = self._next_anchor_ns if self._next_anchor_ns is not None else now
        self._next_anchor_ns = max(due + self._anchor_period_ns, now + self._anchor_period_ns // 2)
        # The sample at the DAC now, when it lies inside the latest copied block (else the block's start):
        # any point on the same line is an equally valid anchor, and "now" keeps anchors fresh.
        k = min(max(0, ((now - dac_ns) * self.sample_rate) // 1_000_000_000), count - 1)
        self.on_event(PlayerAnchor(self.agent_id, track.uid, sample + k, self.sample_rate,
                                  dac_ns + (k * 1_000_000_000) // self.sample_rate))


def pcm16_bytes(samples: np.ndarray) -> bytes:
    """Float samples in [-1, 1] as signed 16-bit little-endian PCM: x * 32768 rounded, clipped to the int16
    range, so int16 PCM the player took in (scaled by 1 / 32768) comes out bit-exact."""
    scaled = samples * np.float32(32768.0)
    np.rint(scaled, out=scaled)
    np.clip(scaled, -32768.0, 32767.0, out=scaled)
    return scaled.astype("<i2").tobytes()


def _check_rate(sample_rate: int) -> None:
    if not isinstance(sample_rate, int | np.integer) or not MIN_RATE <= int(sample_rate) <= MAX_RATE:
        raise ValueError(f"sample rate must be an integer in [{MIN_RATE}, {MAX_RATE}], got {sample_rate!r}")


def _check_pcm(samples: np.ndarray) -> np.ndarray:
    """The checks that cost nothing whatever the length: shape and sample type."""
    x = np.asarray(samples)
    if x.ndim not in (1, 2):
        raise ValueError(f"PCM must be 1-D or frames x channels, got shape {x.shape}")
    if x.dtype != np.int16 and x.dtype.kind != "f":
        raise ValueError(f"PCM must be float or int16, got {x.dtype}")
    return x


def _to_mono_float(x: np.ndarray) -> np.ndarray:
    """A slice of checked PCM as mono float32 (the preparer's side of `_check_pcm`)."""
    if x.dtype == np.int16:
        x = x.astype(np.float32) / 32768.0
    if x.ndim == 2:
        x = x.mean(axis=1)
    if not np.all(np.isfinite(x)):
        raise ValueError("PCM holds NaN or infinity")
    return x.astype(np.float32, copy=False)
