"""LiveScene: the latest bus inputs composed into the face at a display time."""

from __future__ import annotations

import numpy as np
import pytest

from eca.agent.face.emotions import load_emotion_table
from eca.agent.face.flexors import FLEXOR_INDEX, FLEXOR_NAMES
from eca.agent.face.scene import LiveScene
from eca.agent.face.settings import load_flexor_units
from eca.agent.gaze.synth import eye_position_at

S = 1_000_000_000
MS = 1_000_000
UNITS = load_flexor_units()
EMOTIONS = load_emotion_table()
GAZE_AND_SPEECH = {"look_x", "look_y", "blink_l", "blink_r", "say_ah", "say_oo", "say_ee", "say_mm", "say_ff"}


def scene() -> LiveScene:
    return LiveScene(idle_noise=False)


def look(frame) -> tuple[float, float]:  # noqa: ANN001
    return frame.get("look_x") * UNITS.look_x_deg, frame.get("look_y") * UNITS.look_y_deg


def test_emotion_runs_from_its_own_timestamp_so_a_late_start_is_already_settled() -> None:
    sc = scene()
    sc.set_emotion("surprised", 1.0, 0.4, t_ns=5 * S)
    target = EMOTIONS.pose("surprised", 1.0)
    cares = [i for i, v in enumerate(target) if not np.isnan(v) and FLEXOR_NAMES[i] not in GAZE_AND_SPEECH]
    assert cares, "surprised sets some expression flexors"
    before = sc.frame_at(5 * S).values
    halfway = sc.frame_at(5 * S + 400 * MS).values  # one settle time: 95% of the way
    late = sc.frame_at(60 * S).values  # a renderer that started long after the change
    for i in cares:
        assert late[i] == pytest.approx(target[i], abs=1e-9), FLEXOR_NAMES[i]
        if abs(target[i]) > 0.2:
            assert before[i] == pytest.approx(0.0, abs=1e-9)
            assert (halfway[i] - target[i]) == pytest.approx(-0.05 * target[i], abs=1e-6)
    assert sc.emotion == ("surprised", 1.0)


def test_an_older_state_never_moves_time_backwards() -> None:
    sc = scene()
    sc.set_emotion("happy", 1.0, 0.0, t_ns=10 * S)
    sc.set_emotion("angry", 1.0, 0.0, t_ns=9 * S)  # out of order: applied at the later time
    assert sc.frame_at(10 * S).get("brows_knit") == pytest.approx(EMOTIONS.pose("angry")[FLEXOR_INDEX["brows_knit"]])
    sc.move_head(0.5, 0.0, 0.0, 1.0, t_ns=10 * S)
    sc.move_head(-0.5, 0.0, 0.0, 1.0, t_ns=3 * S)
    assert sc.frame_at(11 * S).get("turn") == pytest.approx(-0.5)
    assert sc.head == (-0.5, 0.0, 0.0)


def test_eyes_follow_the_exact_saccade_trajectory_at_the_frame_time_not_the_last_sample() -> None:
    sc = scene()
    for k in range(10):  # 60 Hz samples, fixating (0, 0)
        sc.add_eye_sample(k * 16_666_667, 0.0, 0.0, 0.0, "saccade+blink")
    onset = 150 * MS
    sc.add_saccade(onset, (0.0, 0.0), (12.0, -6.0), 0.054)
    for t in (onset - MS, onset + 10 * MS, onset + 27 * MS, onset + 40 * MS, onset + 54 * MS, onset + 400 * MS):
        want = eye_position_at(t, onset, (0.0, 0.0), (12.0, -6.0), 0.054)
        yaw, pitch = look(sc.frame_at(t))
        assert (yaw, pitch) == pytest.approx((want[0], want[1]), abs=1e-9)
    mid = look(sc.frame_at(onset + 27 * MS))
    assert 0.5 < mid[0] < 11.5  # mid-flight, not the last sample (0) and not the landing (12)
    # a later saccade takes over from its own onset
    sc.add_saccade(onset + 500 * MS, (12.0, -6.0), (-3.0, 2.0), 0.05)
    assert look(sc.frame_at(onset + 499 * MS)) == pytest.approx((12.0, -6.0))
    assert look(sc.frame_at(onset + 600 * MS)) == pytest.approx((-3.0, 2.0))


def test_static_and_noise_modes_interpolate_eye_samples_and_ignore_stale_saccades() -> None:
    sc = scene()
    sc.add_eye_sample(0, 0.0, 0.0, 0.0, "saccade")
    sc.add_saccade(10 * MS, (0.0, 0.0), (10.0, 0.0), 0.05)
    sc.add_eye_sample(1 * S, 4.0, 2.0, 0.2, "noise")
    sc.add_eye_sample(1 * S + 20 * MS, 6.0, 0.0, 0.6, "noise")
    yaw, pitch = look(sc.frame_at(1 * S + 5 * MS))
    assert (yaw, pitch) == pytest.approx((4.5, 1.5))
    assert sc.frame_at(1 * S + 5 * MS).get("blink_l") == pytest.approx(0.3)
    assert look(sc.frame_at(2 * S)) == pytest.approx((6.0, 0.0))  # held past the newest sample
    # back to saccade mode: the old saccade (before the noise run) must not pull the eyes to 10 deg
    sc.add_eye_sample(3 * S, 6.0, 0.0, 0.0, "saccade")
    assert look(sc.frame_at(3 * S + 5 * MS)) == pytest.approx((6.0, 0.0))
    sc.add_saccade(3 * S, (6.0, 0.0), (-8.0, 0.0), 0.06)
    assert look(sc.frame_at(3 * S + 100 * MS)) == pytest.approx((-8.0, 0.0))
    assert sc.eye_mode == "saccade"


def test_nothing_known_leaves_eyes_and_lids_to_the_face() -> None:
    frame = scene().frame_at(S)
    assert frame.get("look_x") == 0.0 and frame.get("blink_l") == 0.0


def _speaking_scene() -> LiveScene:
    sc = scene()
    rate = 16_000
    # keys every 160 samples (10 ms); say_ah ramps 0, 0.5, 1.0, ...
    sc.add_mouth_keys("u1", rate, [0, 160, 320, 480], {"say_ah": [0.0, 0.5, 1.0, 0.2], "say_oo": [0.1] * 4},
                      t_ns=0)
    sc.add_clock_anchor("u1", 0, rate, dac_time_ns=2 * S)
    return sc


def test_mouth_shows_the_sample_at_the_dac_at_the_frame_time() -> None:
    sc = _speaking_scene()
    assert sc.mouth_at(2 * S - MS) is None  # before the first sample reaches the DAC
    assert sc.frame_at(2 * S - MS).get("say_ah") == 0.0
    # 15 ms after the anchor: sample 240, halfway between the keys at 160 (0.5) and 320 (1.0)
    assert sc.mouth_at(2 * S + 15 * MS)["say_ah"] == pytest.approx(0.75)
    assert sc.frame_at(2 * S + 15 * MS).get("say_ah") == pytest.approx(0.75)
    assert sc.frame_at(2 * S + 15 * MS).get("say_oo") == pytest.approx(0.1)
    # a later anchor corrects the DAC clock: sample 320 at 2.025 s (the device ran 5 ms late)
    sc.add_clock_anchor("u1", 320, 16_000, dac_time_ns=2 * S + 25 * MS)
    assert sc.mouth_at(2 * S + 25 * MS)["say_ah"] == pytest.approx(1.0)
    # past the last key's block the keys have not come: closed, not frozen open
    assert sc.mouth_at(2 * S + 80 * MS)["say_ah"] == 0.0


def test_mouth_closes_at_the_played_end_and_after_a_reset() -> None:
    sc = _speaking_scene()
    sc.speech_ended("u1", played_s=0.015, t_ns=3 * S)  # interrupted after 240 samples
    assert sc.mouth_at(2 * S + 10 * MS) is not None
    assert sc.mouth_at(2 * S + 16 * MS) is None
    sc = _speaking_scene()
    sc.add_mouth_keys("u1", 16_000, [], {}, reset=True, t_ns=2 * S + 12 * MS)
    assert sc.mouth_at(2 * S + 11 * MS)["say_ah"] == 0.0  # the keys were dropped: closed
    assert sc.mouth_at(2 * S + 20 * MS) is None
    assert sc.frame_at(2 * S + 20 * MS).get("say_ah") == 0.0


def test_voiced_at_says_whether_the_mouth_follows_an_utterance() -> None:
    sc = _speaking_scene()
    times = [2 * S + k * MS for k in range(-5, 90, 3)]
    said = [sc.voiced_at(t) for t in times]
    assert said == [sc.mouth_row_at(t) is not None for t in times]
    assert True in said and False in said
    sc.add_mouth_keys("u1", 16_000, [], {}, reset=True, t_ns=2 * S + 12 * MS)  # closed from then on
    assert sc.voiced_at(2 * S + 11 * MS) and not sc.voiced_at(2 * S + 20 * MS)


def test_a_finished_utterance_stays_silent_until_a_new_anchor_moves_its_end() -> None:
    # A scene skips an utterance it has found silent past its last anchor. The same inputs given to a fresh scene
    # at each time (no history) must agree at every time, before and after an anchor that moves the end later.
    inputs: list[tuple[str, tuple[object, ...]]] = [("add_mouth_keys", ("u1", 16_000, list(range(0, 32_000, 160)),
                                                                     {"say_ah": [0.5] * 200}))]
    inputs += [("add_clock_anchor", ("u1", k * 1600, 16_000, 2 * S + k * 100 * MS)) for k in range(5)]
    inputs.append(("speech_ended", ("u1", 0.5, 3 * S)))  # 8000 samples: silent from 2.5 s

    def fresh() -> LiveScene:
        scene = LiveScene(seed=3)
        for name, args in inputs:
            getattr(scene, name)(*args)
        return scene

    kept = fresh()
    times = [2 * S + k * 50 * MS for k in range(0, 30)] + [2 * S + 300 * MS, 4 * S]  # and back in time
    for t in times:
        assert kept.voiced_at(t) == fresh().voiced_at(t), t
    assert kept.voiced_at(2 * S + 450 * MS) and not kept.voiced_at(2 * S + 600 * MS)
    # the device ran late: sample 6400 reached the DAC at 2.9 s, so the voice plays on until 3.0 s
    late = ("add_clock_anchor", ("u1", 6400, 16_000, 2 * S + 900 * MS))
    kept.add_clock_anchor(*late[1])  # type: ignore[arg-type]
    inputs.append(late)
    for t in times:
        assert kept.voiced_at(t) == fresh().voiced_at(t), t
        assert (kept.mouth_row_at(t) is None) == (fresh().mouth_row_at(t) is None), t
    assert kept.voiced_at(2 * S + 950 * MS) and not kept.voiced_at(3 * S + 50 * MS)


def test_speech_started_times_the_utterance_until_anchors_arrive() -> None:
    sc = scene()
    sc.speech_started("u2", dac_time_ns=1 * S)  # heard of before its keys
    sc.add_mouth_keys("u2", 8_000, [0, 80], {"say_ee": [0.4, 0.8]}, t_ns=0)
    assert sc.mouth_at(1 * S + 5 * MS)["say_ee"] == pytest.approx(0.6)
    sc.add_clock_anchor("u2", 0, 8_000, dac_time_ns=1 * S + 10 * MS)  # the measured start replaces it
    assert sc.mouth_at(1 * S + 5 * MS) is None
    assert sc.mouth_at(1 * S + 15 * MS)["say_ee"] == pytest.approx(0.6)


def test_frames_depend_on_the_inputs_and_the_time_only() -> None:
    def feed(sc: LiveScene, frame_times: list[int]) -> dict[int, np.ndarray]:
        sc.set_emotion("happy", 0.7, 0.5, t_ns=100 * MS)
        sc.move_head(0.3, -0.2, 0.1, 0.8, t_ns=200 * MS)
        for k in range(60):
            sc.add_eye_sample(k * 16_666_667, 1.0, 0.0, (k % 20) / 20, "saccade+blink")
        sc.add_saccade(300 * MS, (1.0, 0.0), (-9.0, 4.0), 0.05)
        return {t: sc.frame_at(t).values for t in frame_times}

    fine = feed(LiveScene(seed=3), list(range(0, S, 5 * MS)))
    coarse = feed(LiveScene(seed=3), list(range(0, S, 40 * MS)))
    for t, values in coarse.items():
        np.testing.assert_array_equal(values, fine[t])


def test_bad_inputs_are_refused_with_reasons() -> None:
    sc = scene()
    with pytest.raises(ValueError, match="say_xx"):
        sc.add_mouth_keys("u", 16_000, [0], {"say_xx": [0.1]})
    with pytest.raises(ValueError, match="2 weights for 1 keys"):
        sc.add_mouth_keys("u", 16_000, [0], {"say_ah": [0.1, 0.2]})
    with pytest.raises(ValueError, match="eye mode"):
        sc.add_eye_sample(0, 0.0, 0.0, 0.0, "wobbly")
    with pytest.raises(ValueError, match="role"):
        sc.set_role("dancing", 0)
    with pytest.raises(ValueError):
        sc.set_emotion("bored-to-tears", 1.0, 0.5, 0)
    with pytest.raises(ValueError, match="finite"):
        sc.add_saccade(0, (0.0, float("nan")), (1.0, 1.0), 0.05)
    assert sc.frame_at(S).get("say_ah") == 0.0  # nothing half-applied


def test_prune_keeps_what_later_frames_need() -> None:
    sc = LiveScene(idle_noise=False, history_s=1.0)
    for k in range(600):
        sc.add_eye_sample(k * 10 * MS, 2.0, 0.0, 0.0, "saccade")
    sc.add_saccade(100 * MS, (2.0, 0.0), (7.0, 1.0), 0.04)  # the one in force for the rest of the run
    sc.prune(6 * S)
    assert len(sc._samples) < 150
    assert look(sc.frame_at(6 * S)) == pytest.approx((7.0, 1.0))


def test_attention_turns_the_head_on_top_of_the_scripted_head_and_nods_dip_the_chin() -> None:
    sc = scene()
    sc.move_head(0.25, 0.0, 0.0, 0.0, 0)
    sc.attend(-12.0, 0.0, 0.5, S)
    assert sc.frame_at(S).get("turn") == pytest.approx(0.25)  # the turn starts at its own time
    settled = sc.frame_at(2 * S).get("turn")
    assert settled == pytest.approx(0.25 - 12.0 / UNITS.turn_deg, abs=1e-6)
    sc.attend(0.0, 0.0, 0.5, S // 2)  # an older message never moves time back: runs from 1 s
    assert sc.frame_at(3 * S).get("turn") == pytest.approx(0.25, abs=1e-6)
    sc.nod(4 * S, 5.0, 0.5)
    middle = sc.frame_at(4 * S + S // 4).get("nod")
    assert middle == pytest.approx(-5.0 / UNITS.nod_deg, abs=1e-6)
    assert sc.frame_at(5 * S).get("nod") == pytest.approx(0.0, abs=1e-9)
    with pytest.raises(ValueError, match="finite"):
        sc.attend(float("nan"), 0.0, 0.5, 6 * S)
    with pytest.raises(ValueError, match="depth"):
        sc.nod(6 * S, 90.0, 0.5)  # beyond the head's range
    for k in range(1000):  # a flood of nods keeps a bounded list
        sc.nod(7 * S + k, 1.0, 0.2)
    assert len(sc.model.gestures) <= 32
