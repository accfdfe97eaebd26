"""FaceModel: emotions, head, eyes and mouth in; deterministic, continuous flexor frames out."""

from __future__ import annotations

import numpy as np
import pytest

from eca.agent.clock import nanoseconds
from eca.agent.face.composed import ComposedFace, EyeAngles
from eca.agent.face.emotions import load_emotion_table
from eca.agent.face.flexors import FLEXOR_INDEX, N_FLEXORS
from eca.agent.face.model import FaceModel

S = nanoseconds
TABLE = load_emotion_table()


def _quiet() -> FaceModel:
    return FaceModel(idle_noise=False)


def _settled(model: FaceModel, t_s: float = 30.0) -> np.ndarray:
    return model.frame_at_s(t_s).values


def test_a_new_face_is_natural_and_relaxed() -> None:
    np.testing.assert_array_equal(_settled(_quiet(), 0.0), np.zeros(N_FLEXORS))


@pytest.mark.parametrize("emotion", ["happy", "angry", "half-angry", "frightened", "arrogant"])
def test_an_emotion_settles_to_its_table_pose(emotion: str) -> None:
    model = _quiet()
    model.set_emotion(emotion, 1.0, None, S(1.0))
    pose = TABLE.pose(emotion)
    cared = ~np.isnan(pose)
    np.testing.assert_allclose(_settled(model)[cared], pose[cared], atol=1e-9)
    assert model.emotion == (emotion, 1.0)


def test_half_intensity_lies_between_natural_and_the_full_emotion() -> None:
    full, half = _quiet(), _quiet()
    full.set_emotion("surprised", 1.0, None, 0)
    half.set_emotion("surprised", 0.5, None, 0)
    full_values, half_values = _settled(full), _settled(half)
    moved = np.abs(full_values) > 0.05
    assert moved.sum() >= 4
    np.testing.assert_allclose(half_values[moved], 0.5 * full_values[moved], atol=1e-9)


def test_returning_to_natural_relaxes_flexors_only_the_old_emotion_set() -> None:
    model = _quiet()
    model.set_emotion("disappointed", 1.0, 0.5, 0)
    model.set_emotion("natural", 1.0, 0.5, S(2.0))
    np.testing.assert_allclose(_settled(model), np.zeros(N_FLEXORS), atol=1e-9)


def test_transition_time_sets_when_the_emotion_is_95_percent_there() -> None:
    model = _quiet()
    model.set_emotion("happy", 1.0, 2.0, S(1.0))
    smile = FLEXOR_INDEX["smile_l"]
    assert model.frame_at_s(3.0).values[smile] == pytest.approx(0.95 * TABLE.pose("happy")[smile])


def test_emotion_transitions_never_jump_even_when_interrupted() -> None:
    model = _quiet()
    model.set_emotion("angry", 1.0, None, 0)
    model.set_emotion("happy", 1.0, None, S(0.15))  # interrupts the anger mid-way
    model.set_emotion("frightened", 0.7, 0.4, S(0.3))
    model.move_head(0.6, -0.2, 0.1, 0.5, S(0.2))
    model.move_head(-0.4, 0.3, 0.0, 0.5, S(0.45))
    frames = np.array([model.frame_at(t).values for t in range(0, S(1.5), S(0.001))])
    # at 1 ms per frame, no flexor moves more than a few thousandths: nothing jumps
    assert np.max(np.abs(np.diff(frames, axis=0))) < 0.02


def test_emotion_head_posture_adds_to_head_moves() -> None:
    model = _quiet()
    model.set_emotion("arrogant", 1.0, 0.1, 0)
    model.move_head(0.5, 0.2, 0.0, 1.0, 0)
    frame = model.frame_at_s(5.0)
    assert frame.get("turn") == pytest.approx(0.5)
    assert frame.get("nod") == pytest.approx(0.2 + TABLE.pose("arrogant")[FLEXOR_INDEX["nod"]])


def test_head_reaches_its_target_at_the_duration() -> None:
    model = _quiet()
    model.move_head(-0.5, 0.3, 0.2, 1.5, S(2.0))
    frame = model.frame_at_s(3.5)
    assert (frame.get("turn"), frame.get("nod"), frame.get("tilt")) == pytest.approx((-0.5, 0.3, 0.2))
    face = model.compose(S(3.5))
    assert (face.head_yaw_deg, face.head_pitch_deg, face.head_roll_deg) == pytest.approx((-20.0, 7.5, 4.0))


def test_head_moves_in_degrees_use_the_flexor_units() -> None:
    model = _quiet()
    model.move_head_deg(20.0, -5.0, 10.0, 0.0, 0)
    face = model.compose(0)
    assert (face.head_yaw_deg, face.head_pitch_deg, face.head_roll_deg) == pytest.approx((20.0, -5.0, 10.0))


def test_eyes_convert_degrees_to_look_flexors_and_clip_at_the_eye_range() -> None:
    model = _quiet()
    model.set_eyes(15.0, -6.0, lid=0.25)
    frame = model.frame_at_s(1.0)
    assert frame.get("look_x") == pytest.approx(0.5) and frame.get("look_y") == pytest.approx(-0.2)
    assert frame.get("blink_l") == frame.get("blink_r") == 0.25
    face = model.compose(S(1.0), role="talking")
    assert face.left_eye == face.right_eye == EyeAngles(15.0, -6.0) and face.lid == 0.25
    assert face.role == "talking" and face.emotion == "natural" and face.flexors is face.frame.values
    model.set_eyes(80.0, None)
    frame = model.frame_at_s(1.0)
    assert frame.get("look_x") == 1.0 and frame.get("look_y") == 0.0 and frame.get("blink_l") == 0.0


def test_gaze_is_shown_as_given_without_extra_settling() -> None:
    model = _quiet()
    model.set_eyes(-30.0, 30.0)
    frame = model.frame_at_s(0.0)
    assert (frame.get("look_x"), frame.get("look_y")) == (-1.0, 1.0)


def test_the_mouth_layer_overrides_the_emotions_mouth_while_it_cares() -> None:
    model = _quiet()
    model.set_emotion("surprised", 1.0, 0.1, 0)
    open_jaw = TABLE.pose("surprised")[FLEXOR_INDEX["say_ah"]]
    assert model.frame_at_s(5.0).get("say_ah") == pytest.approx(open_jaw)
    model.set_mouth({"say_oo": 0.7})
    frame = model.frame_at_s(5.0)
    assert frame.get("say_oo") == 0.7 and frame.get("say_ah") == 0.0  # unnamed shapes close
    model.set_mouth({})
    assert model.frame_at_s(5.0).get("say_ah") == pytest.approx(open_jaw)


def test_the_same_inputs_give_the_same_frames_and_the_seed_changes_only_the_noise() -> None:
    def run(seed: int) -> np.ndarray:
        model = FaceModel(seed=seed, idle_noise=True)
        model.set_emotion("annoyed", 0.8, None, S(0.2))
        model.move_head(0.3, 0.0, -0.1, 0.8, S(0.5))
        return np.array([model.frame_at(t).values for t in range(0, S(2.0), S(1 / 30))])

    a, b, other = run(7), run(7), run(8)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, other)
    assert np.max(np.abs(a - other)) < 0.2  # the noise is small


def test_frames_do_not_depend_on_the_frame_rate() -> None:
    def run(fps: int) -> dict[int, np.ndarray]:
        model = FaceModel(seed=1)
        commands = [
            (S(0.1), lambda t: model.set_emotion("happy", 1.0, None, t)),
            (S(0.4), lambda t: model.move_head(0.4, 0.1, 0.0, 0.6, t)),
            (S(0.6), lambda t: model.set_emotion("surprised", 0.6, 0.3, t)),
        ]
        frames = {}
        for k in range(2 * fps + 1):
            t = S(k / fps)
            while commands and commands[0][0] <= t:
                t_cmd, command = commands.pop(0)
                command(t_cmd)
            frames[t] = model.frame_at(t).values
        return frames

    slow, fast = run(25), run(100)
    shared = sorted(set(slow) & set(fast))
    assert len(shared) == 51
    for t in shared:
        np.testing.assert_array_equal(slow[t], fast[t])


def test_bad_commands_get_clear_errors() -> None:
    model = _quiet()
    with pytest.raises(ValueError, match="unknown emotion 'sad'; known emotions: natural"):
        model.set_emotion("sad", 1.0, None, 0)
    with pytest.raises(ValueError, match="intensity"):
        model.set_emotion("happy", 2.0, None, 0)
    with pytest.raises(ValueError, match="transition"):
        model.set_emotion("happy", 1.0, -1.0, 0)
    with pytest.raises(ValueError, match="unknown mouth shape 'say_uh'; mouth shapes: say_ah"):
        model.set_mouth({"say_uh": 0.3})
    with pytest.raises(ValueError, match="lid closure"):
        model.set_eyes(0.0, 0.0, lid=-0.5)
    with pytest.raises(ValueError, match="gaze yaw"):
        model.set_eyes(float("nan"), 0.0)
    assert model.emotion == ("natural", 1.0)  # nothing half-applied


def test_a_raw_expression_settles_like_an_emotion_and_leaves_dont_care_flexors_alone() -> None:
    model = _quiet()
    model.set_emotion("happy", 1.0, 0.1, 0)
    pose = np.full(N_FLEXORS, np.nan)
    pose[FLEXOR_INDEX["brow_l"]] = -0.6
    model.set_expression(pose, 1.0, S(1.0))
    assert model.frame_at_s(2.0).get("brow_l") == pytest.approx(
        0.95 * -0.6 + 0.05 * TABLE.pose("happy")[FLEXOR_INDEX["brow_l"]]
    )
    assert model.frame_at_s(9.0).get("smile_l") == pytest.approx(0.0, abs=1e-6)  # happy is gone: natural again


def test_the_composed_face_keeps_the_gaze_unclipped_and_converts_flexors_once() -> None:
    """The eyes are the gaze model's angles (beyond the drawn range too: a rig has its own); the head's
    angles are the flexors times the units, and a frame alone gives the eyes from its look flexors."""
    model = _quiet()
    model.set_eyes(40.0, 5.0, lid=0.0)
    face = model.compose(S(1.0))
    assert face.left_eye.yaw_deg == 40.0 and face.frame.get("look_x") == 1.0
    alone = ComposedFace.from_frame(face.frame, model.units)
    assert alone.left_eye == EyeAngles(30.0, pytest.approx(5.0))
    turned = face.with_flexors(face.frame.with_values(turn=0.5).values, model.units)
    assert turned.head_yaw_deg == pytest.approx(20.0) and turned.left_eye == face.left_eye


def test_eyes_that_hold_the_attention_make_up_for_the_head_shown() -> None:
    """Aimed from the head turned toward the person attended, the eyes are counter-rotated by what the head
    shown lacks of that turn (on its way there), so eyes + head point where the gaze aims."""
    model = _quiet()
    model.attend(20.0, 0.0, 1.0, 0)  # the head turns 20 degrees over a second
    model.set_eyes(0.0, 0.0, 0.0)
    face = model.compose(S(0.5), eyes_hold_attention=True)
    assert 0.0 < face.head_yaw_deg < 20.0
    assert face.left_eye.yaw_deg + face.head_yaw_deg == pytest.approx(20.0)
    assert face.frame.get("look_x") == pytest.approx(face.left_eye.yaw_deg / model.units.look_x_deg)
