"""The lip-sync estimator on synthetic sounds: streaming = offline, timing within one video frame,
bounded weights, smooth motion, formant picking."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.signal import lfilter

from eca.agent.config import ConfigError, load_toml
from eca.agent.lipsync import MOUTH_FLEXORS, LipSyncConfig, LipSyncEstimator, MouthTrack, mouth_track
from eca.agent.lipsync.features import FeatureExtractor, SpectrumPeaks, formants, levinson, lpc_solve

FRAME_S = 1.0 / 60.0  # one video frame


def vowel(f1: float, f2: float, seconds: float, sr: int, f0: float = 120.0, amp: float = 0.3) -> np.ndarray:
    """A sustained vowel from the source-filter model: a pulse train with a -6 dB/octave tilt through
    two formant resonators (bandwidths 80 and 100 Hz) and a fixed F3 at 2700 Hz."""
    n = round(seconds * sr)
    source = np.zeros(n)
    source[:: max(1, round(sr / f0))] = 1.0
    y = lfilter([1.0], [1.0, -0.9], source)
    for fc, bw in ((f1, 80.0), (f2, 100.0), (2700.0, 150.0)):
        r = math.exp(-math.pi * bw / sr)
        y = lfilter([1.0 - r], [1.0, -2.0 * r * math.cos(2.0 * math.pi * fc / sr), r * r], y)
    return amp * y / np.max(np.abs(y))


def hiss(seconds: float, sr: int, amp: float = 0.05, seed: int = 0) -> np.ndarray:
    """High-passed noise, like /s/: first difference of white noise."""
    noise = np.random.default_rng(seed).standard_normal(round(seconds * sr) + 1)
    return amp * np.diff(noise) / 2.0


@pytest.fixture(scope="module")
def cfg() -> LipSyncConfig:
    return LipSyncConfig.load()


def test_streaming_in_random_chunks_equals_offline(cfg: LipSyncConfig) -> None:
    sr = 22_050
    x = np.concatenate([np.zeros(2000), vowel(750, 1200, 0.3, sr), hiss(0.15, sr), vowel(300, 2200, 0.2, sr),
                        np.zeros(1234)])
    track = mouth_track(x, sr, cfg)
    est = LipSyncEstimator(sr, cfg)
    keys = []
    rng = np.random.default_rng(3)
    pos = 0
    while pos < len(x):
        n = int(rng.integers(1, 900))
        keys.extend(est.push(x[pos : pos + n]))
        pos += n
    keys.extend(est.flush())
    assert tuple(keys) == track.keys


def test_keys_are_10ms_blocks_at_any_rate(cfg: LipSyncConfig) -> None:
    for sr in (16_000, 22_050, 44_100, 48_000):
        track = mouth_track(np.zeros(sr), sr, cfg)
        positions = [k.sample_index for k in track.keys]
        assert positions[:101] == [(k * sr) // 100 for k in range(101)]
        assert all(set(k.weights) == set(MOUTH_FLEXORS) for k in track.keys)


def test_silence_is_rest(cfg: LipSyncConfig) -> None:
    track = mouth_track(np.zeros(48_000), 48_000, cfg)
    assert all(max(k.weights.values()) == 0.0 and k.viseme == "rest" for k in track.keys)


@pytest.mark.parametrize("sr", [16_000, 48_000])
def test_mouth_opens_and_closes_within_one_video_frame(cfg: LipSyncConfig, sr: int) -> None:
    onset_s, offset_s = 0.2037, 0.6113  # not on block boundaries
    x = np.zeros(sr)
    on, off = round(onset_s * sr), round(offset_s * sr)
    x[on:off] = vowel(750, 1200, (off - on) / sr, sr)
    track = mouth_track(x, sr, cfg)
    steady = track.weights_at(round(0.5 * sr))["say_ah"]
    assert steady > 0.6
    # Keys describe whole 10 ms blocks and the renderer interpolates between them, so the lips may
    # lead the sound by up to two blocks (lips lead speech in people too), never more.
    assert track.weights_at(on - round(0.021 * sr))["say_ah"] == 0.0
    assert track.weights_at(on + round(FRAME_S * sr))["say_ah"] >= 0.5 * steady
    after = track.weights_at(off + round(FRAME_S * sr))
    assert after["say_ah"] <= 0.15 * steady
    assert max(after[f] for f in ("say_oo", "say_ee", "say_ff")) <= 0.5


def test_weights_bounded_and_shapes_never_jump(cfg: LipSyncConfig) -> None:
    sr = 22_050
    x = np.concatenate([vowel(750, 1200, 0.2, sr), hiss(0.1, sr), vowel(300, 2300, 0.2, sr, amp=0.9),
                        np.zeros(800), vowel(350, 900, 0.2, sr), np.zeros(3000)])
    keys = mouth_track(x, sr, cfg).keys
    w = np.array([[k.weights[f] for f in MOUTH_FLEXORS] for k in keys])
    assert w.min() >= 0.0 and w.max() <= 1.0
    # Lip shapes move at most one attack step (the largest one-pole gain) per 10 ms block.
    max_step = 1.0 - math.exp(-cfg.block_s / min(cfg.shape_attack_s, cfg.shape_release_s))
    assert np.abs(np.diff(w[:, 1:], axis=0)).max() <= max_step + 1e-9


@pytest.mark.parametrize(
    ("sound", "expected"),
    [
        ("open", "open"),
        ("rounded", "rounded"),
        ("spread", "spread"),
        ("hiss", "fricative"),
    ],
)
def test_sustained_sounds_get_their_viseme(cfg: LipSyncConfig, sound: str, expected: str) -> None:
    sr = 22_050
    x = {
        "open": vowel(780, 1250, 0.5, sr),
        "rounded": vowel(320, 850, 0.5, sr),
        "spread": vowel(280, 2300, 0.5, sr),
        "hiss": hiss(0.5, sr),
    }[sound]
    keys = mouth_track(x, sr, cfg).keys[5:-3]  # skip the attack and the flush
    share = sum(k.viseme == expected for k in keys) / len(keys)
    assert share >= 0.9, [k.viseme for k in keys]


def test_quiet_dip_between_vowels_is_a_lip_closure(cfg: LipSyncConfig) -> None:
    sr = 16_000
    x = np.concatenate([vowel(750, 1200, 0.25, sr), np.zeros(round(0.06 * sr)), vowel(750, 1200, 0.25, sr)])
    track = mouth_track(x, sr, cfg)
    mid = track.weights_at(round(0.28 * sr))
    assert mid["say_mm"] > 0.5 and mid["say_ah"] < 0.2


def test_weights_at_interpolates_between_keys(cfg: LipSyncConfig) -> None:
    sr = 16_000
    track = mouth_track(np.concatenate([np.zeros(800), vowel(750, 1200, 0.3, sr)]), sr, cfg)
    a, b = track.keys[6], track.keys[7]
    mid = track.weights_at((a.sample_index + b.sample_index) / 2)
    for f in MOUTH_FLEXORS:
        assert mid[f] == pytest.approx((a.weights[f] + b.weights[f]) / 2)
    assert track.weights_at(-5) == dict.fromkeys(MOUTH_FLEXORS, 0.0)
    assert MouthTrack(sr, ()).weights_at(0) == dict.fromkeys(MOUTH_FLEXORS, 0.0)


def test_lpc_roots_recover_known_resonances() -> None:
    # An all-pole filter with poles at 700 Hz and 1200 Hz (80 Hz bandwidth) at 10 kHz.
    rate = 10_000.0
    poly = np.array([1.0])
    for f, bw in ((700.0, 80.0), (1200.0, 80.0)):
        r = math.exp(-math.pi * bw / rate)
        poly = np.convolve(poly, [1.0, -2 * r * math.cos(2 * math.pi * f / rate), r * r])
    rng = np.random.default_rng(0)
    excitation = rng.standard_normal(20_000)
    y = lfilter([1.0], poly, excitation)
    r = np.array([np.dot(y[: len(y) - k], y[k:]) for k in range(5)])
    a, err = levinson(r, 4)
    assert err > 0
    assert np.allclose(a, poly, atol=0.05)
    peaks = formants(a, rate, 300.0)
    assert peaks == pytest.approx([700.0, 1200.0], abs=15.0)
    # the normal equations give the same predictor, and the spectrum peaks the same resonances as the roots
    toeplitz = np.abs(np.arange(4)[:, None] - np.arange(4)[None, :])
    assert np.allclose(lpc_solve(r, toeplitz), a)
    for contour_hz in (0.0, 150.0):
        assert SpectrumPeaks(4, rate, 3000.0, 25.0, 300.0, contour_hz)(a) == pytest.approx(peaks, abs=10.0)
    # a resonance wider than the limit is no peak
    assert SpectrumPeaks(4, rate, 3000.0, 25.0, 60.0, 0.0)(a) == []


def test_blocks_refuse_bounds_that_are_no_blocks(cfg: LipSyncConfig) -> None:
    features = FeatureExtractor(16_000, window_s=cfg.window_s, preemphasis=cfg.preemphasis, lpc_order=cfg.lpc_order,
                                lpc_band_hz=cfg.lpc_band_hz, high_cut_hz=cfg.high_cut_hz, low_cut_hz=cfg.low_cut_hz,
                                max_bandwidth_hz=cfg.max_bandwidth_hz, f1_range_hz=cfg.f1_range_hz,
                                f2_range_hz=cfg.f2_range_hz, formant_gap_hz=cfg.formant_gap_hz,
                                lag_window_hz=cfg.lag_window_hz)
    x = vowel(700, 1200, 0.05, 16_000)
    for starts in ([], [10, 160], [0, 800], [0, 320, 160], [0, 160, 160]):
        with pytest.raises(ValueError, match="starts"):
            features.blocks(x, starts)
    assert len(features.blocks(x, [0, 160, 320])) == 3


def test_config_errors_name_the_key() -> None:
    data = load_toml("lipsync")
    del data["classes"]["open_f1_hz"]
    with pytest.raises(ConfigError, match="open_f1_hz"):
        LipSyncConfig.from_dict(data)
    data = load_toml("lipsync")
    data["visemes"]["open"]["say_xx"] = 1.0
    with pytest.raises(ConfigError, match="say_xx"):
        LipSyncConfig.from_dict(data)
    data = load_toml("lipsync")
    data["smoothing"]["jaw_attack_s"] = 0.0
    with pytest.raises(ConfigError, match="jaw_attack_s"):
        LipSyncConfig.from_dict(data)
