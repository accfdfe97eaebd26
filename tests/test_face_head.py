"""Head motion: timed, smooth, interruptible transitions of turn, nod and tilt."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from eca.agent.clock import nanoseconds
from eca.agent.face.flexors import FLEXOR_INDEX
from eca.agent.face.head import HeadMotion

S = nanoseconds
pose = st.tuples(st.floats(-1, 1), st.floats(-1, 1), st.floats(-1, 1))


@settings(max_examples=40, deadline=None)
@given(target=pose, duration_s=st.floats(0.05, 5.0), start_s=st.floats(0.0, 100.0))
def test_a_move_reaches_its_target_at_its_duration_and_stays(
    target: tuple[float, float, float], duration_s: float, start_s: float
) -> None:
    head = HeadMotion()
    t0 = S(start_s)
    head.move_to(target, duration_s, t0)
    np.testing.assert_allclose(head.pose_at(t0 + S(duration_s)), target, atol=1e-9)
    np.testing.assert_allclose(head.pose_at(t0 + S(duration_s + 3.0)), target, atol=1e-12)
    np.testing.assert_allclose(head.state_at(t0 + S(duration_s))[1], 0.0, atol=1e-6)


def test_a_move_from_rest_eases_in_and_out_and_passes_halfway_at_half_time() -> None:
    head = HeadMotion()
    head.move_to((1.0, 0.0, 0.0), 2.0, 0)
    turn = [head.pose_at(S(t))[0] for t in np.linspace(0, 2, 81)]
    assert np.all(np.diff(turn) >= 0)  # monotone, no overshoot
    assert head.pose_at(S(1.0))[0] == pytest.approx(0.5)
    assert head.state_at(S(0.0))[1][0] == 0.0  # starts at rest ...
    early, middle = head.state_at(S(0.1))[1][0], head.state_at(S(1.0))[1][0]
    assert 0 < early < middle  # ... speeds up, fastest mid-way (smoothstep peak speed 1.5 / duration)
    assert middle == pytest.approx(1.5 / 2.0)


@settings(max_examples=40, deadline=None)
@given(first=pose, second=pose, interrupt_s=st.floats(0.01, 0.99))
def test_an_interrupting_move_starts_where_the_head_is_with_its_velocity(
    first: tuple[float, float, float], second: tuple[float, float, float], interrupt_s: float
) -> None:
    head = HeadMotion()
    head.move_to(first, 1.0, 0)
    t = S(interrupt_s)
    position, velocity = head.state_at(t)
    head.move_to(second, 1.0, t)
    new_position, new_velocity = head.state_at(t)
    np.testing.assert_allclose(new_position, position, atol=1e-12)
    np.testing.assert_allclose(new_velocity, velocity, atol=1e-9)
    # still continuous a hair later: no jump in the pose actually shown
    assert np.max(np.abs(head.pose_at(t + 1000) - head.pose_at(t))) < 1e-4


def test_an_immediate_move_jumps_and_holds() -> None:
    head = HeadMotion()
    head.move_to((0.2, -0.3, 0.1), 0.0, S(1.0))
    np.testing.assert_allclose(head.pose_at(S(1.0)), (0.2, -0.3, 0.1))


def test_values_care_only_about_the_head_flexors() -> None:
    head = HeadMotion(start=(0.1, 0.2, 0.3))
    values = head.values_at(0)
    cared = {name for name, i in FLEXOR_INDEX.items() if not np.isnan(values[i])}
    assert cared == {"turn", "nod", "tilt"}
    assert values[FLEXOR_INDEX["nod"]] == pytest.approx(0.2)


def test_fast_reversal_is_kept_within_range() -> None:
    head = HeadMotion()
    head.move_to((1.0, 0.0, 0.0), 0.2, 0)
    head.move_to((1.0, 0.0, 0.0), 0.3, S(0.1))  # arrives moving fast toward +1
    for t in np.linspace(0.1, 0.4, 31):
        assert -1.0 <= head.pose_at(S(t))[0] <= 1.0


@pytest.mark.parametrize(
    ("target", "duration", "message"),
    [
        ((1.5, 0, 0), 1.0, "turn = 1.5 lies outside"),
        ((0, float("nan"), 0), 1.0, "nod = nan lies outside"),
        ((0, 0), 1.0, r"needs \(turn, nod, tilt\)"),
        ((0, 0, 0), -1.0, "duration must be"),
        ((0, 0, 0), float("inf"), "duration must be"),
    ],
)
def test_bad_moves_are_rejected_by_name(target: tuple, duration: float, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        HeadMotion().move_to(target, duration, 0)


def test_moves_may_not_start_in_the_past() -> None:
    head = HeadMotion()
    head.move_to((0.5, 0, 0), 1.0, S(2.0))
    with pytest.raises(ValueError, match="before the previous one"):
        head.move_to((0, 0, 0), 1.0, S(1.0))
