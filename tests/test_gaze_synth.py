"""The Saccade Synthesizer: paper eq. 3 integrated exactly, landing at t0 + D, peak velocity mid-flight."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from eca.agent.gaze.synth import eye_position_at, eye_position_one, saccade_progress, saccade_velocity


def _closed_form(tau: float) -> float:
    # The running integral of 14 exp(-(pi/4)(X - 3)^2) over X in [0, 6 tau], divided by the whole area.
    k = math.sqrt(math.pi) / 2.0
    return (math.erf(k * (6.0 * tau - 3.0)) + math.erf(3.0 * k)) / (2.0 * math.erf(3.0 * k))


def test_progress_matches_the_erf_closed_form() -> None:
    tau = np.random.default_rng(0).random(20_000)
    expected = np.array([_closed_form(t) for t in tau])
    np.testing.assert_allclose(saccade_progress(tau), expected, atol=1e-10)


def test_progress_is_the_running_integral_of_eq_3() -> None:
    x = np.linspace(0.0, 6.0, 600_001)
    v = 14.0 * np.exp(-(math.pi / 4.0) * (x - 3.0) ** 2)
    running = np.concatenate([[0.0], np.cumsum((v[1:] + v[:-1]) / 2.0 * np.diff(x))])
    np.testing.assert_allclose(saccade_progress(x / 6.0), running / running[-1], atol=1e-9)
    assert abs(running[-1] - 28.0) < 0.01  # the paper's eq. 3: its area is 28


def test_lands_exactly_at_onset_plus_duration() -> None:
    onset_ns, duration_s = 1_000_000_000, 0.049
    start, end = (2.0, -1.0), (-8.0, 5.0)
    end_ns = onset_ns + round(duration_s * 1e9)
    assert tuple(eye_position_at(end_ns, onset_ns, start, end, duration_s)) == end
    assert tuple(eye_position_at(end_ns + 10**9, onset_ns, start, end, duration_s)) == end
    assert tuple(eye_position_at(onset_ns, onset_ns, start, end, duration_s)) == start
    assert tuple(eye_position_at(onset_ns - 10**6, onset_ns, start, end, duration_s)) == start
    just_before = eye_position_at(end_ns - 1_000_000, onset_ns, start, end, duration_s)
    assert np.all(just_before != np.asarray(end))


def test_peak_velocity_is_mid_flight_and_bell_shaped() -> None:
    onset_ns, duration_s = 0, 0.073
    times = np.arange(0, 73_000_001, 10_000)
    yaw = eye_position_at(times, onset_ns, (0.0, 0.0), (20.0, 0.0), duration_s)[:, 0]
    speed = np.diff(yaw) / np.diff(times)
    peak_time = times[np.argmax(speed)] + 5_000
    assert abs(peak_time - 36_500_000) <= 10_000
    assert np.all(speed >= 0.0)
    assert speed[0] < 0.01 * speed.max() and speed[-1] < 0.01 * speed.max()
    assert float(saccade_velocity(0.5)) == max(float(saccade_velocity(t)) for t in np.linspace(0, 1, 101))


def test_any_frame_rate_samples_the_same_trajectory() -> None:
    onset_ns, duration_s = 123_456_789, 0.06
    at_60 = np.arange(onset_ns, onset_ns + 70_000_000, 1_000_000_000 // 600)
    at_every_ns = eye_position_at(at_60, onset_ns, (1.0, 2.0), (-3.0, 4.0), duration_s)
    one_by_one = np.array([eye_position_at(int(t), onset_ns, (1.0, 2.0), (-3.0, 4.0), duration_s) for t in at_60])
    np.testing.assert_array_equal(at_every_ns, one_by_one)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(min_value=-0.5, max_value=1.5, allow_nan=False), min_size=2, max_size=50))
def test_progress_is_monotone_and_bounded(taus: list[float]) -> None:
    tau = np.sort(np.asarray(taus))
    p = saccade_progress(tau)
    assert np.all(np.diff(p) >= -1e-15)
    assert np.all((p >= 0.0) & (p <= 1.0))
    assert np.all(p[tau <= 0.0] == 0.0) and np.all(p[tau >= 1.0] == 1.0)


@settings(max_examples=300, deadline=None)
@given(
    t_ns=st.integers(-(10**12), 10**12),
    onset_ns=st.integers(-(10**12), 10**12),
    angles=st.tuples(*[st.floats(-90.0, 90.0, allow_nan=False)] * 4),
    duration_s=st.one_of(st.just(0.0), st.floats(1e-4, 0.5)),
    near=st.booleans(),
)
def test_one_eye_in_plain_floats_is_the_array_version_bit_for_bit(
    t_ns: int, onset_ns: int, angles: tuple[float, ...], duration_s: float, near: bool
) -> None:
    if near:  # most draws land far from any saccade: put half of them inside one
        t_ns = onset_ns + t_ns % max(1, round(duration_s * 1.2e9))
    start, end = angles[:2], angles[2:]
    expected = eye_position_at(t_ns, onset_ns, start, end, duration_s)
    assert eye_position_one(t_ns, onset_ns, start, end, duration_s) == (float(expected[0]), float(expected[1]))
