"""The player: one agent's queue of utterances played through a sink; the master clock of speech.

Three threads touch it, and each owns its part:
- the caller (the service loop) prepares audio: decode, convert to the device rate, compute mouth
  keys; it appends finished chunks to a track and tracks to the queue (deque/list appends are atomic);
- the sink's callback only copies prepared samples and appends small records (what it copied, and the
  block's timing stamp) to a deque; it takes no lock, logs nothing, and never waits;
- the publisher (`pump`, a thread for real-time sinks, the sink's own step for the fake sink) turns
  records into events: DAC times mapped to the monotonic clock, lifecycle, clock anchors. All events
  reach `on_event` from this one thread, in order.
"""

from __future__ import annotations

import logging
import threading
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from agent.clock import Clock, MonotonicClock
from agent.lipsync import LipSyncConfig, LipSyncEstimator, MouthKey
from services.audio.config import AudioConfig
from services.audio.events import (
    AudioEvent,
    ClockAnchor,
    MouthKeys,
    MouthReset,
    SpeechFailed,
    SpeechFinished,
    SpeechInterrupted,
    SpeechStarted,
)
from services.audio.resample import Resampler
from services.audio.sinks import Sink

log = logging.getLogger(__name__)

_FILE_CHUNK_FRAMES = 1 << 16  # files are converted and analysed in pieces of this many source frames

# Record kinds appended by the callback.
_BUFFER, _PLAY, _END, _CUT = range(4)


class _Track:
    """One utterance. Chunks are appended by the caller; the cursor is owned by the callback."""

    __slots__ = ("uid", "chunks", "fed", "complete", "cut", "played", "chunk_i", "chunk_off",
                 "resampler", "estimator", "started", "closed", "failed")

    def __init__(self, uid: str, resampler: Resampler | None, estimator: LipSyncEstimator | None) -> None:
        self.uid = uid
        self.chunks: list[np.ndarray] = []
        self.fed = 0  # samples appended so far (published after the chunk itself)
        self.complete = False  # no more chunks will come
        self.cut = False  # interrupted: the callback drops it at its next block
        self.played = 0  # samples handed to the DAC (callback only)
        self.chunk_i = 0
        self.chunk_off = 0
        self.resampler = resampler
        self.estimator = estimator
        self.started = False  # publisher only
        self.closed = False  # caller only: a terminal outcome is decided, feeds are ignored
        self.failed = False  # its terminal event (SpeechFailed) is already out: the cut reports nothing

    def append(self, samples: np.ndarray) -> None:
        if len(samples):
            self.chunks.append(samples)
            self.fed += len(samples)


class Player:
    """Plays one agent's utterances in order and reports them through `on_event`.

    Requests: `say_file`, `say_pcm`, `say_stream` + `feed`; `interrupt` stops the voice within one
    block. Every request ends in exactly one of SpeechFinished, SpeechInterrupted, SpeechFailed.
    Utterance ids must be unique among the requests still in flight (a repeat raises ValueError).
    """

    def __init__(self, sink: Sink, on_event: Callable[[AudioEvent], None], *, agent_id: str = "agent",
                 clock: Clock | None = None, config: AudioConfig | None = None,
                 lipsync_config: LipSyncConfig | None = None) -> None:
        self.sink = sink
        self.on_event = on_event
        self.agent_id = agent_id
        self.clock = clock if clock is not None else MonotonicClock()
        self.config = config if config is not None else AudioConfig()
        self.lipsync_config = lipsync_config if lipsync_config is not None else LipSyncConfig.load()
        self.sample_rate = sink.sample_rate
        self._tracks: deque[_Track] = deque()  # queue in play order; the callback pops the head
        self._active: dict[str, _Track] = {}  # caller side: requests without a terminal outcome yet
        self._records: deque[tuple[Any, ...]] = deque()  # callback -> publisher
        self._outbox: deque[AudioEvent] = deque()  # caller -> publisher (keys, failures)
        self._buffer_dac_ns = 0
        self._latest: tuple[_Track, int, int, int] | None = None  # track, sample, dac_ns, count
        self._next_anchor_ns: int | None = None
        self._anchor_period_ns = round(1e9 / self.config.anchor_hz)
        self._lock = threading.Lock()  # caller-side bookkeeping only; never taken by the callback
        self._stop = threading.Event()
        self._publisher: threading.Thread | None = None
        self._started = False

    # ------------------------------------------------------------------ life cycle

    def start(self) -> Player:
        if self._started:
            return self
        self._started = True
        self.sink.start(self._render, None if self.sink.realtime else self.pump)
        if self.sink.realtime:
            self._publisher = threading.Thread(target=self._publish_loop, name=f"audio-publisher-{self.agent_id}",
                                               daemon=True)
            self._publisher.start()
        return self

    def close(self) -> None:
        self._stop.set()
        if self._publisher is not None:
            self._publisher.join(timeout=2.0)
            self._publisher = None
        if self._started:
            self.sink.stop()
            self._started = False

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

    def say_file(self, utterance_id: str, path: str | Path) -> None:
        """Play an audio file (WAV, FLAC, OGG... through soundfile); mouth keys are computed ahead."""
        self._check_new(utterance_id)
        try:
            import soundfile as sf

            if not Path(path).is_file():
                raise FileNotFoundError(str(path))
            info = sf.info(str(path))
            if info.frames / info.samplerate > self.config.max_utterance_s:
                raise ValueError(f"longer than {self.config.max_utterance_s:g} s")
            track = self._new_track(utterance_id, info.samplerate)
            keys: list[MouthKey] = []
            with sf.SoundFile(str(path)) as fh:
                while True:
                    block = fh.read(_FILE_CHUNK_FRAMES, dtype="float32", always_2d=True)
                    if len(block) == 0:
                        break
                    keys += self._ingest(track, block.mean(axis=1), last=False, publish_keys=False)
            keys += self._ingest(track, np.zeros(0, np.float32), last=True, publish_keys=False)
        except Exception as exc:  # any unreadable input fails this request only
            self._fail(utterance_id, f"cannot play {Path(path).name!r}: {_describe(exc)}")
            return
        # The whole track in one event, ahead of playback.
        self._outbox.append(MouthKeys(self.agent_id, utterance_id, self.sample_rate, tuple(keys)))
        self._enqueue(track)

    def say_pcm(self, utterance_id: str, samples: np.ndarray, sample_rate: int) -> None:
        """Play PCM held in memory: float in [-1, 1] or int16, mono or frames x channels."""
        self._check_new(utterance_id)
        try:
            pcm = _as_mono_float(samples)
            if len(pcm) / sample_rate > self.config.max_utterance_s:
                raise ValueError(f"longer than {self.config.max_utterance_s:g} s")
            track = self._new_track(utterance_id, sample_rate)
            self._ingest(track, pcm, last=True)
        except ValueError as exc:
            self._fail(utterance_id, f"bad PCM: {exc}")
            return
        self._enqueue(track)

    def say_stream(self, utterance_id: str, sample_rate: int) -> None:
        """Open an utterance whose PCM arrives later through `feed` (streaming TTS). It takes its place
        in the queue now; if its chunks arrive late, the output waits in silence for them."""
        self._check_new(utterance_id)
        try:
            track = self._new_track(utterance_id, sample_rate)
        except ValueError as exc:
            self._fail(utterance_id, f"bad stream: {exc}")
            return
        self._enqueue(track)

    def feed(self, utterance_id: str, chunk: np.ndarray, last: bool = False) -> bool:
        """Append a chunk to a streamed utterance. Returns False (and ignores the chunk) when the
        utterance is no longer in flight, e.g. after an interruption."""
        with self._lock:
            track = self._active.get(utterance_id)
        if track is None or track.closed or track.complete:
            return False
        try:
            pcm = _as_mono_float(chunk)
            if (track.fed + len(pcm)) / self.sample_rate > self.config.max_utterance_s:
                raise ValueError(f"stream longer than {self.config.max_utterance_s:g} s")
        except ValueError as exc:
            self._fail_stream(track, f"bad chunk: {exc}")
            return False
        self._ingest(track, pcm, last=last)
        return True

    def interrupt(self, utterance_id: str | None = None) -> list[str]:
        """Stop the voice within one block. None: the current utterance and every queued one (barge-in);
        an id: only that utterance. Returns the ids cut. The callback reports how much was played."""
        with self._lock:
            # list() copies the deque in one C call, so the callback cannot mutate it mid-iteration.
            cut = [t for t in list(self._tracks)
                   if not t.cut and not t.failed and (utterance_id is None or t.uid == utterance_id)]
            for track in cut:
                track.closed = True
                track.cut = True  # seen by the callback at its next block
        return [t.uid for t in cut]

    @property
    def idle(self) -> bool:
        """Nothing queued or playing, and every terminal event has been emitted."""
        with self._lock:
            return not self._active

    # ------------------------------------------------------------------ preparation helpers

    def _check_new(self, utterance_id: str) -> None:
        if not isinstance(utterance_id, str) or not utterance_id:
            raise ValueError("utterance_id must be a non-empty string")
        with self._lock:
            if utterance_id in self._active:
                raise ValueError(f"utterance {utterance_id!r} is already in flight")

    def _new_track(self, utterance_id: str, sample_rate: int) -> _Track:
        if not isinstance(sample_rate, int | np.integer) or not 4000 <= int(sample_rate) <= 384_000:
            raise ValueError(f"sample rate must be an integer in [4000, 384000], got {sample_rate!r}")
        resampler = None if int(sample_rate) == self.sample_rate else Resampler(int(sample_rate), self.sample_rate)
        return _Track(utterance_id, resampler, LipSyncEstimator(self.sample_rate, self.lipsync_config))

    def _ingest(self, track: _Track, pcm: np.ndarray, last: bool, publish_keys: bool = True) -> list[MouthKey]:
        """Convert to the device rate, compute mouth keys, then make the samples playable.

        With `publish_keys` the keys go out at once, before the samples become playable, so they always
        precede their sound; otherwise they are returned for the caller to send.
        """
        out = track.resampler.process(pcm) if track.resampler is not None else pcm.astype(np.float32)
        if last and track.resampler is not None:
            out = np.concatenate((out, track.resampler.flush()))
        assert track.estimator is not None
        keys = track.estimator.push(out)
        if last:
            keys.extend(track.estimator.flush())
        if keys and publish_keys:
            self._outbox.append(MouthKeys(self.agent_id, track.uid, self.sample_rate, tuple(keys)))
        track.append(np.clip(out, -1.0, 1.0).astype(np.float32, copy=False))
        if last:
            track.complete = True
            track.resampler = None
            track.estimator = None
        return keys

    def _enqueue(self, track: _Track) -> None:
        with self._lock:
            self._active[track.uid] = track
            self._tracks.append(track)

    def _fail(self, utterance_id: str, reason: str) -> None:
        self._outbox.append(SpeechFailed(self.agent_id, utterance_id, reason))

    def _fail_stream(self, track: _Track, reason: str) -> None:
        # A broken stream ends as failed; the callback drops it like an interruption but reports nothing.
        with self._lock:
            track.closed = True
            track.failed = True
        self._outbox.append(SpeechFailed(self.agent_id, track.uid, reason))
        track.cut = True

    # ------------------------------------------------------------------ the callback (real-time thread)

    def _render(self, out: np.ndarray, stamp: Any) -> None:
        records = self._records
        records.append((_BUFFER, stamp))
        tracks = self._tracks
        n = len(out)
        pos = 0
        while pos < n and tracks:
            t = tracks[0]
            if t.cut:
                records.append((_CUT, t, t.played, pos))
                tracks.popleft()
                continue
            if t.played >= t.fed:
                if t.complete:
                    records.append((_END, t, t.played, pos))
                    tracks.popleft()
                    continue
                break  # a stream waiting for its next chunk: silence until it arrives
            chunk = t.chunks[t.chunk_i]
            take = min(n - pos, len(chunk) - t.chunk_off)
            out[pos : pos + take] = chunk[t.chunk_off : t.chunk_off + take]
            records.append((_PLAY, t, t.played, pos, take))
            t.played += take
            t.chunk_off += take
            if t.chunk_off == len(chunk):
                t.chunk_i += 1
                t.chunk_off = 0
            pos += take
            if t.complete and t.played >= t.fed:
                records.append((_END, t, t.played, pos))
                tracks.popleft()
        if pos < n:
            out[pos:] = 0.0

    # ------------------------------------------------------------------ the publisher

    def pump(self) -> None:
        """Turn what the callback recorded into events. Runs on one thread only."""
        emit = self.on_event
        outbox = self._outbox
        while outbox:
            emit(outbox.popleft())
        sr = self.sample_rate
        records = self._records
        while records:
            rec = records.popleft()
            kind = rec[0]
            if kind == _BUFFER:
                self._buffer_dac_ns = self.sink.dac_time_ns(rec[1])
                continue
            track: _Track = rec[1]
            dac_ns = self._buffer_dac_ns + (rec[3] * 1_000_000_000) // sr
            if kind == _PLAY:
                if not track.started:
                    track.started = True
                    emit(SpeechStarted(self.agent_id, track.uid, sr, dac_ns))
                self._latest = (track, rec[2], dac_ns, rec[4])
            elif kind == _END:
                if not track.started:  # an empty utterance still starts before it finishes
                    track.started = True
                    emit(SpeechStarted(self.agent_id, track.uid, sr, dac_ns))
                # Reported when the last sample is handed over (with the time it leaves the DAC), so a
                # queue's events stay in order: this one finishes before the next one starts.
                self._terminate(track)
                emit(SpeechFinished(self.agent_id, track.uid, rec[2] / sr, dac_ns))
            else:  # _CUT
                self._terminate(track)
                if self._latest is not None and self._latest[0] is track:
                    self._latest = None
                if track.started:
                    emit(MouthReset(self.agent_id, track.uid, dac_ns))
                if not track.failed:
                    played_s = rec[2] / sr if track.started else 0.0
                    emit(SpeechInterrupted(self.agent_id, track.uid, played_s, dac_ns))
        self._emit_anchor()

    def _terminate(self, track: _Track) -> None:
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
        if track.closed and now > block_end_ns:
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
        self.on_event(ClockAnchor(self.agent_id, track.uid, sample + k, self.sample_rate,
                                  dac_ns + (k * 1_000_000_000) // self.sample_rate))


def _as_mono_float(samples: np.ndarray) -> np.ndarray:
    x = np.asarray(samples)
    if x.ndim not in (1, 2):
        raise ValueError(f"PCM must be 1-D or frames x channels, got shape {x.shape}")
    if x.dtype == np.int16:
        x = x.astype(np.float32) / 32768.0
    elif x.dtype.kind != "f":
        raise ValueError(f"PCM must be float or int16, got {x.dtype}")
    if x.ndim == 2:
        x = x.mean(axis=1)
    if not np.all(np.isfinite(x)):
        raise ValueError("PCM holds NaN or infinity")
    return x.astype(np.float32, copy=False)


def _describe(exc: BaseException) -> str:
    if isinstance(exc, FileNotFoundError):
        return "file not found"
    text = str(exc).strip() or type(exc).__name__
    return text.splitlines()[0][:200]
