"""Fixational eye movements of mode saccade+noise+blink, measured against their sourced constants.

Each statistic is measured on a crowd and compared with the constant in configs/gaze.toml it must follow;
the shipped constants are pinned to the ranges their sources give, so a wrong constant fails either here
or in the statistic.
"""

from __future__ import annotations

import math
from statistics import NormalDist

import numpy as np
import pytest
from scipy import stats

from eca.agent.gaze.engine import GazeEngine
from eca.agent.gaze.fixation import Fixations
from eca.agent.gaze.params import FACE_FEATURES, KINDS, ROLES, GazeParams

S = 1_000_000_000
MUTUAL, AWAY, HEAD, SCAN, MICRO = (KINDS.index(k) for k in ("mutual", "away", "head", "scan", "micro"))
MOUTH = FACE_FEATURES.index("mouth")


@pytest.fixture(scope="module")
def params() -> GazeParams:
    return GazeParams.load()


def _crowd(params: GazeParams, n: int, role: str, mutual: bool, seconds: float, scale: float = 1.0,
           seed: int = 3) -> dict[str, np.ndarray]:
    """Small saccades of `n` agents holding one fixation (on the gaze target at 0, 0) for `seconds`."""
    fixations = Fixations(params, seed)
    fixations.grow(n)
    agents = np.arange(n)
    fixations.start(agents, np.zeros(n, np.int64), np.zeros(n), np.zeros(n), np.full(n, int(mutual)),
                    np.full(n, ROLES.index(role)), np.full(n, scale))
    for t in range(S // 2, int(seconds * S) + 1, S // 2):
        fixations.advance(agents, t + 1)
    columns = ("agent", "onset_ns", "kind", "from_yaw", "from_pitch", "to_yaw", "to_pitch", "magnitude",
               "amplitude", "direction", "duration_s", "hold_s")
    chunks = fixations.take_onsets()
    merged = [np.concatenate([c[0] for c in chunks]), np.concatenate([c[1] for c in chunks]),
              np.concatenate([c[2] for c in chunks]), *np.concatenate([c[3] for c in chunks], axis=1)]
    order = np.lexsort((merged[1], merged[0]))  # by agent, then onset
    return {name: column[order] for name, column in zip(columns, merged, strict=True)}


def test_shipped_constants_are_the_sources_values(params: GazeParams) -> None:
    fix = params.fixation
    assert 1.0 <= fix.microsaccade_rate_hz <= 2.0  # Martinez-Conde et al. 2004: 1-2 per second
    assert 0.1 <= fix.microsaccade_median_deg <= 1.0 and fix.microsaccade_max_deg == 1.0  # ... 2009: up to 1 deg
    half_eyes = math.degrees(math.atan(0.0315 / 1.0))  # Dodgson 2004: 63 mm; Hall 1966: 1 m
    np.testing.assert_allclose(fix.features_deg[:2, 0], [-half_eyes, half_eyes])
    assert fix.features_deg[MOUTH, 1] == pytest.approx(-math.degrees(math.atan(0.07)))
    # Lansing & McConkie 2003: mouth drawn while the partner speaks, eyes first otherwise; below half the time
    # even in heavy noise (Vatikiotis-Bateson et al. 1998); scans suppressed during speech.
    assert fix.mouth_share["listening"] < 0.5
    assert fix.mouth_share["listening"] > fix.mouth_share["talking"] == fix.mouth_share["silence"]
    assert fix.scan_rate_hz["listening"] < fix.scan_rate_hz["talking"]
    assert params.default_mode == "saccade+noise+blink"


@pytest.mark.parametrize("role", ROLES)
def test_rates_of_scans_and_microsaccades_by_role(params: GazeParams, role: str) -> None:
    n, seconds = 8_000, 20.0
    fix = params.fixation
    for mutual in (True, False):
        crowd = _crowd(params, n, role, mutual, seconds)
        span = n * seconds
        micro_rate = np.count_nonzero(crowd["kind"] == MICRO) / span
        scan_rate = np.count_nonzero(crowd["kind"] == SCAN) / span
        assert micro_rate == pytest.approx(fix.microsaccade_rate_hz, rel=0.02)
        if mutual:
            assert scan_rate == pytest.approx(fix.scan_rate_hz[role], rel=0.02)
        else:
            assert scan_rate == 0.0  # away from the partner there is no face to scan


def test_intervals_are_a_refractory_gap_plus_an_exponential_stretched_by_emotion(params: GazeParams) -> None:
    fix = params.fixation
    for scale in (1.0, params.emotion("angry").interval_scale):
        crowd = _crowd(params, 3_000, "talking", True, 12.0, scale=scale)
        # Intervals starting in the last seconds are censored by the end of the run: leave those out.
        same_agent = (np.diff(crowd["agent"]) == 0) & (crowd["onset_ns"][:-1] < 8 * S)
        intervals = np.diff(crowd["onset_ns"])[same_agent] * 1e-9
        mean = scale / fix.event_rate_hz("talking", True)
        spread = mean - fix.refractory_s
        assert intervals.min() >= fix.refractory_s - 1e-9
        assert stats.kstest(intervals, lambda x, s=spread: stats.expon.cdf(x - fix.refractory_s, scale=s)).pvalue > 0.01
        # The hold reported with each small saccade is the time from its landing to the next one.
        landing = crowd["onset_ns"][:-1][same_agent] * 1e-9 + crowd["duration_s"][:-1][same_agent]
        np.testing.assert_allclose(crowd["hold_s"][:-1][same_agent],
                                   crowd["onset_ns"][1:][same_agent] * 1e-9 - landing, atol=2e-9)


def test_microsaccade_amplitudes_follow_the_truncated_log_normal(params: GazeParams) -> None:
    fix = params.fixation
    crowd = _crowd(params, 4_000, "silence", False, 10.0)
    amplitude = crowd["amplitude"][crowd["kind"] == MICRO]
    assert amplitude.max() <= fix.microsaccade_max_deg + 1e-9
    normal = NormalDist()
    top = normal.cdf(math.log(fix.microsaccade_max_deg / fix.microsaccade_median_deg) / fix.microsaccade_log_sd)

    def cdf(a: np.ndarray) -> np.ndarray:
        z = np.log(np.maximum(a, 1e-300) / fix.microsaccade_median_deg) / fix.microsaccade_log_sd
        return np.array([normal.cdf(float(v)) for v in z]) / top

    assert stats.kstest(amplitude[:20_000], cdf).pvalue > 0.01
    # Durations follow the main sequence, as for every saccade (Zuber, Stark & Cook 1965).
    np.testing.assert_allclose(crowd["duration_s"], params.d0_s + params.d_s_per_deg * crowd["amplitude"], atol=1e-9)


def test_microsaccades_head_back_toward_the_point_fixated(params: GazeParams) -> None:
    fix = params.fixation
    crowd = _crowd(params, 4_000, "silence", False, 10.0)  # away: the point is the fixation's base, 0, 0
    micro = crowd["kind"] == MICRO
    heading = np.deg2rad(crowd["direction"][micro])
    toward = np.arctan2(-crowd["from_pitch"][micro], -crowd["from_yaw"][micro])
    off = np.rad2deg(np.angle(np.exp(1j * (heading - toward))))
    spread = fix.correction_spread_deg
    assert np.abs(off).max() <= spread + 0.1  # within the spread, up to the angle table's step
    assert stats.kstest(off, stats.uniform(loc=-spread, scale=2 * spread).cdf).pvalue > 0.01


def test_drift_is_brownian_with_the_configured_diffusion(params: GazeParams) -> None:
    fix = params.fixation
    crowd = _crowd(params, 3_000, "silence", False, 10.0)
    same_agent = np.diff(crowd["agent"]) == 0
    landed_ns = crowd["onset_ns"][:-1] + np.rint(crowd["duration_s"][:-1] * S)
    elapsed = ((crowd["onset_ns"][1:] - landed_ns) * 1e-9)[same_agent]
    sigma = np.sqrt(2.0 * fix.drift_diffusion_deg2_per_s * elapsed)  # per axis
    for axis in ("yaw", "pitch"):
        drift = (crowd[f"from_{axis}"][1:] - crowd[f"to_{axis}"][:-1])[same_agent]
        z = drift / sigma
        # The angle table quantises the direction (4096 steps): far below what a KS test of this size sees.
        assert stats.kstest(z[:20_000], stats.norm.cdf).pvalue > 0.01


@pytest.mark.parametrize("role", ROLES)
def test_scans_share_the_time_on_the_face_as_configured(params: GazeParams, role: str) -> None:
    fix = params.fixation
    crowd = _crowd(params, 6_000, role, True, 20.0, seed=8)
    scans = crowd["kind"] == SCAN
    mouth = np.isclose(crowd["to_pitch"][scans], fix.features_deg[MOUTH, 1])
    share = fix.mouth_share[role]
    count = np.count_nonzero(scans)
    assert abs(mouth.mean() - share) < 4.0 * math.sqrt(share * (1 - share) / count)
    # Every scan lands exactly on a feature of the partner's face.
    targets = np.stack([crowd["to_yaw"][scans], crowd["to_pitch"][scans]], axis=1)
    distance = np.abs(targets[:, None, :] - fix.features_deg[None, :, :]).sum(axis=2).min(axis=1)
    assert distance.max() < 1e-12
    # Time share on the mouth, from each scan to the agent's next one.
    scan_rows = np.flatnonzero(scans)
    agent, onset = crowd["agent"][scan_rows], crowd["onset_ns"][scan_rows]
    follows = np.diff(agent) == 0
    held = np.diff(onset)[follows]
    on_mouth = mouth[:-1][follows]
    assert held[on_mouth].sum() / held.sum() == pytest.approx(share, abs=0.02)
    # Each agent prefers one eye: its share of the time on the eyes.
    eyes = ~mouth
    right = crowd["to_yaw"][scans][eyes] < 0
    per_agent = np.bincount(crowd["agent"][scans][eyes], weights=right, minlength=6_000) / np.maximum(
        np.bincount(crowd["agent"][scans][eyes], minlength=6_000), 1)
    preferred = np.maximum(per_agent, 1 - per_agent)[np.bincount(crowd["agent"][scans][eyes]) >= 10]
    assert np.median(preferred) == pytest.approx(fix.preferred_eye_share, abs=0.06)


def test_engine_scans_only_in_mutual_gaze_and_keeps_eyes_alive_statistics(params: GazeParams) -> None:
    """In the engine, scans happen only while the agent's Eyes Alive gaze is mutual, microsaccades in every
    fixation, none while an Eyes Alive saccade is in flight; a listening face is alive."""
    n = 3_000
    engine = GazeEngine(n, seed=5, params=params, role="listening", mode="saccade+noise+blink")
    onsets = []
    for t in range(S // 30, 30 * S + 1, S // 30):
        s = engine.tick(t).saccades
        onsets.append(np.stack([s.agent, s.onset_ns, s.kind, np.rint(s.duration_s * S).astype(np.int64)]))
    rows = np.concatenate(onsets, axis=1)
    rows = rows[:, np.lexsort((rows[2] > HEAD, rows[1], rows[0]))]  # by agent, onset; an Eyes Alive one first
    agent, onset, kind, duration = rows
    main = kind <= HEAD
    latest_main = np.maximum.accumulate(np.where(main, np.arange(kind.size), -1))
    small = ~main & (latest_main >= 0) & (agent == agent[np.maximum(latest_main, 0)])
    context = kind[latest_main[small]]
    assert np.all(context[kind[small] == SCAN] == MUTUAL)
    assert np.count_nonzero((kind[small] == MICRO) & (context == AWAY)) > 100
    landed = onset[latest_main[small]] + duration[latest_main[small]]
    assert np.all(onset[small] >= landed + params.fixation.refractory_s * S - 1)
    # Today's listener makes about 0.07 Eyes Alive saccades per second; with the fixational movements its
    # eyes move a couple of times a second.
    assert np.count_nonzero(~main) / (n * 30.0) > 1.5
