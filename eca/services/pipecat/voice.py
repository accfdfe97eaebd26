"""The pipeline's voice as its output transport plays it, and the mouth that goes with it.

A pipecat output transport plays the audio frames it is handed one after another, in real time, from
the moment the first of them arrives: a frame that comes while earlier audio still plays waits for it
(a TTS service that streams faster than real time fills the transport's queue), and a frame that comes
after the earlier audio has run out plays at once (a TTS that falls behind leaves a gap of silence).
So the moment sample s of an utterance is heard is known when its frame is pushed:

    heard(frame) = max(pushed(frame), end of the audio heard before it)

and sample s of that frame is heard s / rate later. `HeardVoice` keeps that timeline as clock anchors
of the face's live scene (one at the start of each run of audio, again after each gap), and computes
the mouth keys from the same samples with eca's own lip-sync estimator (agent/lipsync, the audio
service's algorithm and configuration), as the samples pass: a frame composed for time t shows the
mouth of the sample the transport plays at t, with no bus round trip between the sound and its mouth.

An interruption (`cut`) closes the mouth from that moment and forgets the queue: the transport drops
its queued audio on an interruption too.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from eca.agent.face.scene import LiveScene
from eca.agent.lipsync import LipSyncConfig, LipSyncEstimator
from eca.agent.lipsync.config import MOUTH_FLEXORS

NS_PER_S = 1_000_000_000
_GAP_NS = 1_000_000  # a frame heard more than 1 ms after the audio before it ends: a gap, a new anchor


@dataclass
class _Utterance:
    scene_id: str  # the utterance's id in the scene (not the eca request id: eca's own events never touch it)
    sample_rate: int
    estimator: LipSyncEstimator
    samples: int = 0  # pushed so far
    anchor_ns: int = 0  # the latest anchor: sample `anchor_sample` is heard at `anchor_ns`
    anchor_sample: int = 0
    finished: bool = False

    def heard_ns(self, sample: int) -> int:
        return self.anchor_ns + (sample - self.anchor_sample) * NS_PER_S // self.sample_rate


class HeardVoice:
    """Feeds `scene` the pipeline's utterances: clock anchors on the transport's timeline, mouth keys."""

    def __init__(self, scene: LiveScene, lipsync: LipSyncConfig | None = None) -> None:
        self.scene = scene
        self.lipsync = lipsync if lipsync is not None else LipSyncConfig.load()
        self.playout_end_ns = 0  # when the audio handed to the transport so far has all been played
        self._current: _Utterance | None = None
        self._count = 0

    @property
    def speaking(self) -> bool:
        """An utterance is open (audio came and neither its end nor an interruption has)."""
        return self._current is not None and not self._current.finished

    def add(self, samples: np.ndarray, sample_rate: int, pushed_ns: int, new_utterance: bool = False) -> int:
        """One frame of mono int16 samples handed to the transport at `pushed_ns`; returns when its first
        sample is heard. `new_utterance` (or another rate) starts a new utterance."""
        utt = self._current
        if utt is None or utt.finished or new_utterance or utt.sample_rate != sample_rate:
            if utt is not None and not utt.finished:
                self.finish(pushed_ns)
            self._count += 1
            utt = self._current = _Utterance(f"pipeline-{self._count}", sample_rate,
                                             LipSyncEstimator(sample_rate, self.lipsync))
            start_ns = max(pushed_ns, self.playout_end_ns)
            utt.anchor_ns, utt.anchor_sample = start_ns, 0
            self.scene.add_clock_anchor(utt.scene_id, 0, sample_rate, start_ns)
        else:
            start_ns = max(pushed_ns, utt.heard_ns(utt.samples))
            if start_ns - utt.heard_ns(utt.samples) > _GAP_NS:  # the transport ran dry: silence, then this
                utt.anchor_ns, utt.anchor_sample = start_ns, utt.samples
                self.scene.add_clock_anchor(utt.scene_id, utt.samples, sample_rate, start_ns)
        keys = utt.estimator.push(samples.astype(np.float32) / 32768.0)
        self._add_keys(utt, keys, start_ns)
        utt.samples += len(samples)
        self.playout_end_ns = utt.heard_ns(utt.samples)
        return start_ns

    def finish(self, now_ns: int) -> None:
        """The utterance's audio is complete: its last keys, then the mouth goes back to the emotion once
        its last sample has been heard."""
        utt = self._current
        if utt is None or utt.finished:
            return
        utt.finished = True
        self._add_keys(utt, utt.estimator.flush(), now_ns)
        self.scene.speech_ended(utt.scene_id, utt.samples / utt.sample_rate, now_ns)

    def cut(self, now_ns: int) -> None:
        """An interruption: the mouth closes at `now_ns` and what was queued is not heard."""
        if self._current is not None:
            self._current.finished = True
            self._current = None
        self.scene.add_mouth_keys("interrupted", 16_000, [], {}, reset=True, t_ns=now_ns)
        self.playout_end_ns = now_ns

    def covered_until_ns(self) -> int | None:
        """While an utterance is open (more audio may come): when the transport plays the first sample whose
        mouth key is not known yet; None otherwise."""
        utt = self._current
        if utt is None or utt.finished:
            return None
        return utt.heard_ns(utt.estimator.position)

    def _add_keys(self, utt: _Utterance, keys: list, t_ns: int) -> None:
        if not keys:
            return
        positions = [k.sample_index for k in keys]
        weights = {name: [k.weights[name] for k in keys] for name in MOUTH_FLEXORS}
        self.scene.add_mouth_keys(utt.scene_id, utt.sample_rate, positions, weights, t_ns=t_ns)
