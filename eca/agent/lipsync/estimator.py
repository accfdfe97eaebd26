"""Causal lip-sync: audio in, one mouth key per 10 ms block out.

Each block's features (level, zero crossings, band balance, F1/F2) become soft memberships of five
visemes (open, rounded, spread, closed, fricative; "rest" is what is left). Memberships and the jaw
opening are smoothed with asymmetric one-pole filters (coarticulation), then mixed into the mouth
flexors through the viseme table. Nothing is ever an argmax, so the mouth never switches hard.

A key at sample position p describes the block [p, p + block): it is computed once that block has
arrived, so a player that has the block in hand can publish the key before its sound reaches the DAC.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from eca.agent.lipsync.config import MOUTH_FLEXORS, VISEMES, LipSyncConfig
from eca.agent.lipsync.features import BlockFeatures, FeatureExtractor

REST_WEIGHTS: dict[str, float] = dict.fromkeys(MOUTH_FLEXORS, 0.0)


@dataclass(frozen=True, slots=True)
class MouthKey:
    sample_index: int  # first sample of the block, counted from the utterance's first sample
    weights: dict[str, float]  # MOUTH_FLEXORS -> 0..1
    viseme: str = "rest"  # the dominant viseme, for display and validation only


@dataclass(frozen=True)
class MouthTrack:
    """Mouth keys of a whole clip; `weights_at` interpolates linearly between keys."""

    sample_rate: int
    keys: tuple[MouthKey, ...]
    _positions: np.ndarray = field(init=False, repr=False, compare=False)
    _matrix: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        positions = np.array([k.sample_index for k in self.keys], dtype=np.int64)
        matrix = np.array([[k.weights[f] for f in MOUTH_FLEXORS] for k in self.keys], dtype=float)
        object.__setattr__(self, "_positions", positions)
        object.__setattr__(self, "_matrix", matrix.reshape(len(self.keys), len(MOUTH_FLEXORS)))

    def weights_at(self, sample_index: float) -> dict[str, float]:
        """Weights at any sample position; before the first key and after the last the mouth rests."""
        pos = self._positions
        if len(pos) == 0 or sample_index < pos[0] or sample_index > pos[-1]:
            return dict(REST_WEIGHTS)
        j = int(np.searchsorted(pos, sample_index, side="right")) - 1
        if j >= len(pos) - 1:
            row = self._matrix[-1]
        else:
            frac = (sample_index - pos[j]) / (pos[j + 1] - pos[j])
            row = (1.0 - frac) * self._matrix[j] + frac * self._matrix[j + 1]
        return {f: float(v) for f, v in zip(MOUTH_FLEXORS, row, strict=True)}


def _sigmoid(x: float) -> float:
    # Exactly 0 far below the threshold (a 6e-6 step), so silence gives a mouth exactly at rest.
    if x < -12.0:
        return 0.0
    return 1.0 / (1.0 + math.exp(-x))


class LipSyncEstimator:
    """Streaming estimator: `push` any number of samples, get the keys of every completed block."""

    def __init__(self, sample_rate: int, config: LipSyncConfig | None = None) -> None:
        if sample_rate < 4000:
            raise ValueError(f"sample_rate must be >= 4000 Hz for lip-sync, got {sample_rate}")
        self.sample_rate = int(sample_rate)
        self.config = cfg = config if config is not None else LipSyncConfig.load()
        self._blocks_per_s = 1.0 / cfg.block_s
        self._features = FeatureExtractor(
            sample_rate, window_s=cfg.window_s, preemphasis=cfg.preemphasis, lpc_order=cfg.lpc_order,
            lpc_band_hz=min(cfg.lpc_band_hz, 0.5 * sample_rate), high_cut_hz=cfg.high_cut_hz,
            low_cut_hz=cfg.low_cut_hz, max_bandwidth_hz=cfg.max_bandwidth_hz, f1_range_hz=cfg.f1_range_hz,
            f2_range_hz=cfg.f2_range_hz, formant_gap_hz=cfg.formant_gap_hz, lag_window_hz=cfg.lag_window_hz,
            contour_bandwidth_hz=cfg.contour_bandwidth_hz)
        self._table = cfg.viseme_table  # visemes x flexors
        # The table's non-zero entries per flexor: the per-block mix touches only those.
        self._mix = tuple(tuple((v, row[i]) for v, row in enumerate(cfg.viseme_table) if row[i] != 0.0)
                          for i in range(len(MOUTH_FLEXORS)))
        dt = cfg.block_s
        self._a_jaw = (1.0 - math.exp(-dt / cfg.jaw_attack_s), 1.0 - math.exp(-dt / cfg.jaw_release_s))
        self._a_shape = (1.0 - math.exp(-dt / cfg.shape_attack_s), 1.0 - math.exp(-dt / cfg.shape_release_s))
        self._a_formant = 1.0 - math.exp(-dt / cfg.formant_tau_s)
        self._ref_decay_db = cfg.ref_decay_db_per_s * dt
        self._closure_hold_blocks = round(cfg.closure_hold_s / dt)
        self.reset()

    def reset(self) -> None:
        """Forget everything: the next sample pushed is sample 0 of a new utterance."""
        self._features.reset()
        self._pending = np.zeros(0)
        self._block_index = 0
        self._ref_db = self.config.initial_ref_dbfs
        self._f1 = math.nan
        self._f2 = math.nan
        self._blocks_since_speech = 1 << 30
        self._recent_levels = [-200.0] * max(1, round(self.config.closure_context_s / self.config.block_s))
        self._jaw = 0.0
        self._shape = [0.0] * len(VISEMES)

    @property
    def position(self) -> int:
        """Sample position of the next block's first sample."""
        return self._block_start(self._block_index)

    def _block_start(self, k: int) -> int:
        # Exact 10 ms blocks in time: at 22,050 Hz blocks hold 220 or 221 samples.
        return (k * self.sample_rate) // round(self._blocks_per_s)

    def push(self, samples: np.ndarray) -> list[MouthKey]:
        x = np.asarray(samples, dtype=float)
        if x.ndim == 2:
            x = x.mean(axis=1)
        elif x.ndim != 1:
            raise ValueError(f"samples must be 1-D (mono) or 2-D (frames x channels), got shape {x.shape}")
        buf = np.concatenate((self._pending, x)) if len(self._pending) else x
        # the blocks complete in hand, analysed together; then keyed one after another (the filters' state)
        first = self._block_index
        base = self._block_start(first)
        starts: list[int] = []
        end = 0
        while self._block_start(first + len(starts) + 1) - base <= len(buf):
            starts.append(end)
            end = self._block_start(first + len(starts)) - base
        keys: list[MouthKey] = []
        if starts:
            features = self._features.blocks(buf[:end], starts)
            for j, f in enumerate(features):
                keys.append(self._key(base + starts[j], f, j))
                self._block_index += 1
        self._pending = buf[end:].copy()
        return keys

    def flush(self) -> list[MouthKey]:
        """End of the utterance: analyse the partial last block (zero-padded) and close the mouth."""
        keys: list[MouthKey] = []
        if len(self._pending):
            length = self._block_start(self._block_index + 1) - self._block_start(self._block_index)
            keys.extend(self.push(np.zeros(length - len(self._pending))))
        keys.append(MouthKey(self.position, dict(REST_WEIGHTS), "rest"))
        return keys

    def _key(self, start: int, f: BlockFeatures, j: int) -> MouthKey:
        """The key of the block at `start`, whose features are `f`, block j of those analysed last."""
        # Five-element state in plain floats: numpy call overhead would dominate at this size.
        targets, jaw_target = self._targets(f, j)
        a = self._a_jaw[0] if jaw_target > self._jaw else self._a_jaw[1]
        self._jaw += a * (jaw_target - self._jaw)
        attack, release = self._a_shape
        shape = self._shape
        for v, target in enumerate(targets):
            shape[v] += (attack if target > shape[v] else release) * (target - shape[v])
        weights = [min(1.0, sum([shape[v] * w for v, w in entries])) for entries in self._mix]
        weights[0] *= self._jaw
        total = sum(shape)
        viseme = VISEMES[shape.index(max(shape))] if total >= self.config.rest_threshold else "rest"
        # Memberships and table entries are >= 0, so each weight already lies in [0, 1].
        return MouthKey(start, dict(zip(MOUTH_FLEXORS, weights, strict=True)), viseme)

    def _targets(self, f: BlockFeatures, j: int) -> tuple[list[float], float]:
        cfg = self.config
        level = f.level_db
        if level >= self._ref_db:
            self._ref_db = level
        else:
            self._ref_db = max(cfg.floor_dbfs, self._ref_db - self._ref_decay_db)
        rel = level - self._ref_db
        w = cfg.gate_width_db
        speech = _sigmoid((rel - cfg.speech_gate_db) / w) * _sigmoid((level - cfg.floor_dbfs) / w)
        audible = _sigmoid((rel - cfg.fricative_gate_db) / w) * _sigmoid((level - cfg.floor_dbfs) / w)
        fric = audible * _sigmoid((f.high_ratio - cfg.fricative_high_ratio) / cfg.fricative_width)
        # A nasal murmur (m, n) puts nearly all its power at the murmur's first resonance, 250-300 Hz,
        # with little between it and F2; a back rounded vowel such as /u/ (F1 300-450 Hz) has a large
        # share just above the cut-off, so the band balance tells them apart at any loudness. A front
        # vowel with a very low F1 (/i/, 270 Hz) can share that balance, but keeps a sharp F2 above
        # 1.8 kHz where the murmur's higher resonances are damped: such a block is no murmur. Nasal
        # damping also keeps a murmur below the voice's peak level, so a loud steady hum is no closure.
        self._recent_levels[self._block_index % len(self._recent_levels)] = level
        local_rel = level - max(self._recent_levels)
        nasal = (speech * (1.0 - fric) * _sigmoid((f.low_ratio - cfg.nasal_low_ratio) / cfg.nasal_width)
                 * _sigmoid((cfg.nasal_max_db - rel) / w))
        if nasal > 0.05:
            f2 = self._features.formants(j)[1]
            if not math.isnan(f2):
                nasal *= 1.0 - _sigmoid((f2 - cfg.spread_f2_hz) / cfg.f2_width_hz)
        if speech > 0.5:
            self._blocks_since_speech = 0
        else:
            self._blocks_since_speech += 1
        recent = 1.0 if self._blocks_since_speech <= self._closure_hold_blocks else 0.0
        # A lip closure (p, b, m) is silence soon after speech, or a sharp drop below the syllable just
        # before it: a voiced /b/ or a quiet /p/ closure need not reach silence.
        sharp_drop = _sigmoid((cfg.closure_dip_db - local_rel) / w)
        dip = max(1.0 - speech, sharp_drop) * (1.0 - fric) * recent
        closed = max(nasal, dip)
        vowel = speech * (1.0 - fric) * (1.0 - nasal)

        self._track_formants(j, vowel)
        f1 = self._f1 if not math.isnan(self._f1) else cfg.open_f1_hz
        f2 = self._f2 if not math.isnan(self._f2) else 0.5 * (cfg.rounded_f2_hz + cfg.spread_f2_hz)
        open_s = _sigmoid((f1 - cfg.open_f1_hz) / cfg.open_width_hz)
        round_s = _sigmoid((cfg.rounded_f2_hz - f2) / cfg.f2_width_hz)
        spread_s = _sigmoid((f2 - cfg.spread_f2_hz) / cfg.f2_width_hz)
        # A mid vowel (schwa: low F1, middle F2) gets a half-open jaw rather than no shape at all.
        neutral = max(0.0, 1.0 - round_s - spread_s)
        targets = [
            vowel * (open_s + 0.5 * (1.0 - open_s) * neutral),
            vowel * (1.0 - open_s) * round_s,
            vowel * (1.0 - open_s) * spread_s,
            closed,
            fric,
        ]
        jaw = speech * min(1.0, max(0.0, (rel - cfg.speech_gate_db) / cfg.jaw_range_db))
        return targets, jaw

    def _track_formants(self, j: int, vowel: float) -> None:
        # Only vowel-like blocks move the formant tracks; consonants and silence hold the last values
        # (and skip the LPC, the costly part).
        if vowel < 0.5:
            return
        a = self._a_formant
        f1, f2 = self._features.formants(j)
        if not math.isnan(f1):
            self._f1 = f1 if math.isnan(self._f1) else self._f1 + a * (f1 - self._f1)
        if not math.isnan(f2):
            self._f2 = f2 if math.isnan(self._f2) else self._f2 + a * (f2 - self._f2)


def mouth_track(samples: np.ndarray, sample_rate: int, config: LipSyncConfig | None = None) -> MouthTrack:
    """The whole clip at once; identical to pushing the same samples into a fresh estimator and flushing."""
    est = LipSyncEstimator(sample_rate, config)
    keys = est.push(samples)
    keys.extend(est.flush())
    return MouthTrack(sample_rate, tuple(keys))
