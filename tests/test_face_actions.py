"""Actions: constant poses, keyframes, envelopes, idle noise."""

from __future__ import annotations

import numpy as np
import pytest

from eca.agent.clock import nanoseconds
from eca.agent.face.actions import Action, Envelope, Keyframes, Pose, ease
from eca.agent.face.flexors import FLEXOR_INDEX, N_FLEXORS
from eca.agent.face.head import HeadMotion
from eca.agent.face.idle import IdleNoise

S = nanoseconds
SMILE, BROW = FLEXOR_INDEX["smile_l"], FLEXOR_INDEX["brow_l"]


def test_poses_keyframes_envelopes_head_and_noise_are_all_actions() -> None:
    pose = Pose.from_dict({"smile_l": 0.3})
    for action in (
        pose,
        Keyframes.from_seconds([(0.0, {"smile_l": 0.0})]),
        Envelope(pose, 0, 0.1, 0.1, 0.1),
        HeadMotion(),
        IdleNoise(np.full(N_FLEXORS, 0.1), 0.5),
    ):
        assert isinstance(action, Action)
        assert action.values_at(S(0.05)).shape == (N_FLEXORS,)


def test_a_pose_is_constant_and_cares_only_about_what_it_names() -> None:
    pose = Pose.from_dict({"smile_l": 0.3})
    a, b = pose.values_at(0), pose.values_at(S(100))
    np.testing.assert_array_equal(a, b)
    assert a[SMILE] == 0.3 and np.count_nonzero(~np.isnan(a)) == 1


def test_keyframes_interpolate_between_keys_and_hold_outside() -> None:
    action = Keyframes.from_seconds(
        [(0.0, {"smile_l": 0.0}), (1.0, {"smile_l": 1.0}), (2.0, {"smile_l": 0.5})],
        start_ns=S(10),
        easing="linear",
    )
    assert action.values_at(S(5))[SMILE] == 0.0
    assert action.values_at(S(10.25))[SMILE] == pytest.approx(0.25)
    assert action.values_at(S(11.5))[SMILE] == pytest.approx(0.75)
    assert action.values_at(S(99))[SMILE] == 0.5


def test_smooth_keyframes_ease_in_and_out() -> None:
    action = Keyframes.from_seconds([(0.0, {"brow_l": 0.0}), (1.0, {"brow_l": 1.0})])
    assert action.values_at(S(0.1))[BROW] < 0.1  # slow start
    assert action.values_at(S(0.5))[BROW] == pytest.approx(0.5)
    assert action.values_at(S(0.9))[BROW] > 0.9  # slow finish


def test_keyframes_do_not_care_where_a_key_does_not_care() -> None:
    action = Keyframes.from_seconds([(0.0, {"smile_l": 0.0}), (1.0, {"smile_l": 1.0, "brow_l": 1.0})])
    assert np.isnan(action.values_at(S(0.5))[BROW])
    assert action.values_at(S(1.5))[BROW] == 1.0


def test_step_keyframes_hold_until_the_next_key() -> None:
    action = Keyframes.from_seconds([(0.0, {"smile_l": 0.0}), (1.0, {"smile_l": 1.0})], easing="step")
    assert action.values_at(S(0.999))[SMILE] == 0.0
    assert action.values_at(S(1.0))[SMILE] == 1.0


def test_bad_keyframes_are_rejected() -> None:
    with pytest.raises(ValueError, match="increase strictly"):
        Keyframes.from_seconds([(1.0, {}), (1.0, {})])
    with pytest.raises(ValueError, match="at least one key"):
        Keyframes((), np.empty((0, N_FLEXORS)))
    with pytest.raises(ValueError, match="unknown easing 'bouncy'"):
        Keyframes.from_seconds([(0.0, {})], easing="bouncy")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="unknown flexor 'grin'"):
        Keyframes.from_seconds([(0.0, {"grin": 1.0})])
    with pytest.raises(ValueError, match="outside"):
        Keyframes((0,), np.full((1, N_FLEXORS), 3.0))


def test_an_envelope_swells_holds_fades_and_then_stops_caring() -> None:
    flash = Envelope(Pose.from_dict({"brow_l": 0.8}), start_ns=S(1.0), attack_s=0.2, hold_s=0.3, release_s=0.2)
    assert np.isnan(flash.values_at(S(0.9))[BROW])
    assert flash.values_at(S(1.1))[BROW] == pytest.approx(0.4)
    assert flash.values_at(S(1.35))[BROW] == pytest.approx(0.8)
    assert flash.values_at(S(1.6))[BROW] == pytest.approx(0.4)
    assert np.isnan(flash.values_at(S(1.8))[BROW])
    with pytest.raises(ValueError, match="attack_s"):
        Envelope(Pose.from_dict({}), 0, -1.0, 0.0, 0.0)


def test_ease_curves_start_at_zero_and_end_at_one() -> None:
    for easing in ("linear", "smooth", "step"):
        assert ease(0.0, easing) == 0.0 and ease(1.0, easing) == 1.0  # type: ignore[arg-type]


def test_idle_noise_is_small_smooth_seeded_and_cares_only_where_it_has_amplitude() -> None:
    amplitude = np.zeros(N_FLEXORS)
    amplitude[[FLEXOR_INDEX["nod"], FLEXOR_INDEX["brow_l"], FLEXOR_INDEX["brow_r"]]] = 0.05
    noise = IdleNoise(amplitude, rate_hz=0.5, seed=3)
    times = [S(t) for t in np.arange(0.0, 10.0, 1 / 60)]
    samples = np.array([noise.values_at(t) for t in times])
    assert np.all(np.isnan(samples[:, FLEXOR_INDEX["smile_l"]]))
    nod = samples[:, FLEXOR_INDEX["nod"]]
    assert np.max(np.abs(nod)) <= 0.05 + 1e-12 and np.std(nod) > 0.003  # alive, but small
    assert np.max(np.abs(np.diff(nod))) < 0.01  # smooth at 60 frames/s
    np.testing.assert_array_equal(samples[:, BROW], samples[:, FLEXOR_INDEX["brow_r"]])  # pairs move together
    np.testing.assert_array_equal(IdleNoise(amplitude, 0.5, seed=3).values_at(S(4.2)), noise.values_at(S(4.2)))
    other = IdleNoise(amplitude, 0.5, seed=4).values_at(S(4.2))
    assert other[FLEXOR_INDEX["nod"]] != noise.values_at(S(4.2))[FLEXOR_INDEX["nod"]]


def test_idle_noise_with_kept_gradients_is_perlin1d_frame_after_frame_and_after_a_jump() -> None:
    """The gradients kept between frames (stepped from cell to cell, hashed anew after a jump) give exactly
    agent.noise.perlin1d of each flexor's phase."""
    from eca.agent.face.idle import _PHASE, _STREAMS
    from eca.agent.noise import perlin1d

    amplitude = np.full(N_FLEXORS, 0.05)
    noise = IdleNoise(amplitude, rate_hz=0.7, seed=9)
    for t_s in [*np.arange(0.0, 12.0, 1 / 30), 500.0, 500.1, 3.0]:
        phase = 0.7 * (S(t_s) / 1e9) + _PHASE[_STREAMS]
        np.testing.assert_array_equal(noise.values_at(S(t_s)), amplitude * perlin1d(phase, 9, _STREAMS))
