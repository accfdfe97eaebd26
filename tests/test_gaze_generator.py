"""The Eyes Alive Parameter Generator against its analytic distributions (>= 100,000 draws each)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import integrate, stats

from eca.agent.gaze.generator import (
    direction_from_uniform,
    magnitude_cdf,
    magnitude_from_uniform,
    saccade_duration_s,
)
from eca.agent.gaze.params import GazeParams

N_DRAWS = 200_000


@pytest.fixture(scope="module")
def params() -> GazeParams:
    return GazeParams.load()


def _uniforms(seed: int, n: int = N_DRAWS) -> np.ndarray:
    return np.random.default_rng(seed).random(n)


def _rejection_reference_cdf(a: np.ndarray, limit: float) -> np.ndarray:
    """CDF of A = -6.9 ln(P / 15.7), P ~ U(0, 15], conditioned on A <= limit, derived by hand."""
    # P(A <= a) = P(P >= 15.7 exp(-a / 6.9)) = (15 - 15.7 exp(-a/6.9)) / 15 for a >= the minimum.
    unconditional = np.clip((15.0 - 15.7 * np.exp(-a / 6.9)) / 15.0, 0.0, 1.0)
    at_limit = (15.0 - 15.7 * math.exp(-limit / 6.9)) / 15.0
    return np.minimum(unconditional / at_limit, 1.0)


@pytest.mark.parametrize(("role", "limit"), [("talking", 27.5), ("listening", 22.7)])
def test_magnitude_is_the_truncated_shifted_exponential(params: GazeParams, role: str, limit: float) -> None:
    assert params.roles[role].max_magnitude_deg == limit
    a = magnitude_from_uniform(_uniforms(1), params, limit)
    assert a.min() >= -6.9 * math.log(15.0 / 15.7) - 1e-12  # the minimum, 0.315 deg
    assert a.max() <= limit
    result = stats.kstest(a, lambda x: _rejection_reference_cdf(np.asarray(x), limit))
    assert result.pvalue > 0.01, result


def test_magnitude_matches_literal_redraw_sampling(params: GazeParams) -> None:
    # The literal procedure: draw P uniform on (0, 15], redraw while A exceeds the limit.
    rng = np.random.default_rng(7)
    p = 15.0 * (1.0 - rng.random(N_DRAWS))
    a = -6.9 * np.log(p / 15.7)
    while np.any(a > 22.7):
        over = a > 22.7
        a[over] = -6.9 * np.log(15.0 * (1.0 - rng.random(over.sum())) / 15.7)
    ours = magnitude_from_uniform(_uniforms(2), params, 22.7)
    assert stats.ks_2samp(a, ours).pvalue > 0.01
    # And magnitude_cdf agrees with the hand-derived CDF.
    grid = np.linspace(0.0, 30.0, 301)
    np.testing.assert_allclose(magnitude_cdf(grid, params, 22.7), _rejection_reference_cdf(grid, 22.7), atol=1e-12)


def test_magnitude_scale_multiplies_and_keeps_the_limit(params: GazeParams) -> None:
    u = _uniforms(3)
    plain = magnitude_from_uniform(u, params, 27.5)
    np.testing.assert_allclose(magnitude_from_uniform(u, params, 27.5, 0.5), 0.5 * plain)
    assert magnitude_from_uniform(u, params, 27.5, 1.6).max() <= 27.5


def test_direction_frequencies_match_the_table_within_half_a_point(params: GazeParams) -> None:
    expected = {0: 15.54, 45: 6.46, 90: 17.69, 135: 7.44, 180: 16.80, 225: 7.89, 270: 20.38, 315: 7.79}
    directions = direction_from_uniform(_uniforms(4), params)
    for angle, percent in expected.items():
        observed = 100.0 * np.mean(directions == angle)
        assert abs(observed - percent) < 0.5, (angle, observed, percent)
    assert set(np.unique(directions)) == {float(a) for a in expected}


def test_direction_bias_tilts_toward_its_direction(params: GazeParams) -> None:
    u = _uniforms(5)
    down = direction_from_uniform(u, params, 270.0, 1.2)
    plain = direction_from_uniform(u, params)
    assert np.mean(down == 270.0) > np.mean(plain == 270.0) + 0.15
    assert np.mean(down == 90.0) < np.mean(plain == 90.0)


def test_duration_is_exactly_the_main_sequence(params: GazeParams) -> None:
    amplitude = np.random.default_rng(6).uniform(0.0, 60.0, N_DRAWS)
    np.testing.assert_allclose(saccade_duration_s(amplitude, params), 0.025 + 0.0024 * amplitude, rtol=0, atol=1e-15)
    assert float(saccade_duration_s(10.0, params)) == pytest.approx(0.049, abs=1e-15)


def _polynomial_cdf(coeffs: list[float], lo: float, hi: float):
    poly = np.polynomial.Polynomial(coeffs)
    area = integrate.quad(poly, lo, hi)[0]

    def cdf(x_s: np.ndarray) -> np.ndarray:
        frames = np.clip(np.asarray(x_s) * 30.0, lo, hi)
        return np.array([integrate.quad(poly, lo, f)[0] for f in np.atleast_1d(frames)]) / area

    return cdf


@pytest.mark.parametrize(
    ("kind", "coeffs", "hi", "mean_frames"),
    [
        ("mutual", [32.2815, -0.1763, 2.5524e-4], 345.0, 100.0),
        ("away", [78.831, -6.7021, 0.2262, -0.0034, 1.8798e-5], 61.0, 12.0),
    ],
)
def test_talking_intervals_follow_eq_4_and_5(
    params: GazeParams, kind: str, coeffs: list[float], hi: float, mean_frames: float
) -> None:
    distribution = getattr(params.roles["talking"], f"{kind}_interval")
    holds = distribution.sample_s(_uniforms(8))
    assert holds.min() >= 1.0 / 30.0 and holds.max() <= hi / 30.0
    reference = _polynomial_cdf(coeffs, 1.0, hi)
    # KS against the CDF integrated independently with scipy (vectorised through a fine grid).
    grid = np.linspace(1.0 / 30.0, hi / 30.0, 2001)
    table = reference(grid)
    result = stats.kstest(holds, lambda x: np.interp(x, grid, table))
    assert result.pvalue > 0.01, result
    assert holds.mean() * 30.0 == pytest.approx(mean_frames, rel=0.1)  # the fits' implied means: about 100 / 12 frames


@pytest.mark.parametrize(("kind", "mean", "sd"), [("mutual", 237.5, 47.1), ("away", 13.0, 7.1)])
def test_listening_intervals_are_positive_gaussians(params: GazeParams, kind: str, mean: float, sd: float) -> None:
    distribution = getattr(params.roles["listening"], f"{kind}_interval")
    holds = distribution.sample_s(_uniforms(9))
    assert holds.min() > 0.0
    reference = stats.truncnorm(a=(0.0 - mean) / sd, b=np.inf, loc=mean / 30.0, scale=sd / 30.0)
    result = stats.kstest(holds, reference.cdf)
    assert result.pvalue > 0.01, result
    assert distribution.mean_s == pytest.approx(reference.mean(), rel=1e-9)


def test_silence_uses_the_listening_statistics_and_the_resting_blink_rate(params: GazeParams) -> None:
    silence, listening = params.roles["silence"], params.roles["listening"]
    assert params.silence_like == "listening"
    assert silence.mutual_interval is listening.mutual_interval
    assert silence.max_magnitude_deg == listening.max_magnitude_deg
    assert silence.blink_rate_per_min == 17.0 and listening.blink_rate_per_min == 26.0
