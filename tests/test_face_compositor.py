"""Layered compositing: "do not care", layer order, blend modes, settle times, continuity, determinism."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from eca.agent.clock import nanoseconds
from eca.agent.face.actions import Pose
from eca.agent.face.compositor import DEFAULT_LAYERS, Blend, Compositor, LayerSpec, blend_onto
from eca.agent.face.flexors import FLEXOR_INDEX, N_FLEXORS
from eca.agent.face.frame import DONT_CARE, FlexorFrame
from eca.agent.face.scene import LiveScene
from eca.agent.face.settling import LN_20, Settler

SMILE, BROW, NOD, LOOK_X = (FLEXOR_INDEX[n] for n in ("smile_l", "brow_l", "nod", "look_x"))
S = nanoseconds


def _instant() -> Compositor:
    """A compositor whose settled layers jump at once, to look at the layering alone."""
    return Compositor(settle_s=0.0)


def test_a_layer_that_does_not_care_leaves_the_flexor_to_the_layer_below() -> None:
    comp = _instant()
    comp.set_pose("base", Pose.from_dict({"smile_l": 0.2, "brow_l": 0.3}), 0)
    comp.set_pose("emotion", Pose.from_dict({"smile_l": 0.8}), 0)
    values = comp.compose(S(1))
    assert values[SMILE] == pytest.approx(0.8)  # the emotion cares: it wins
    assert values[BROW] == pytest.approx(0.3)  # it does not: the base shows through


def test_higher_replace_layers_win_over_lower_ones() -> None:
    comp = _instant()
    comp.set_pose("emotion", Pose.from_dict({"look_x": 0.5, "blink_l": 0.2}), 0)
    comp.set_action("gaze", Pose.from_dict({"look_x": -0.4}))
    comp.set_action("blink", Pose.from_dict({"blink_l": 1.0}))
    values = comp.compose(0)
    assert values[LOOK_X] == pytest.approx(-0.4)
    assert values[FLEXOR_INDEX["blink_l"]] == 1.0


def test_swapping_the_order_of_two_layers_swaps_the_winner() -> None:
    low, high = Pose.from_dict({"look_x": 0.1}), Pose.from_dict({"look_x": 0.9})
    for order, expected in ((("a", "b"), 0.9), (("b", "a"), 0.1)):
        comp = Compositor(0.0, [LayerSpec(name) for name in order])
        comp.set_action("a", low)
        comp.set_action("b", high)
        assert comp.compose(0)[LOOK_X] == pytest.approx(expected)


def test_an_additive_layer_offsets_what_lies_below_and_ignores_what_it_does_not_care_about() -> None:
    comp = _instant()
    comp.set_pose("emotion", Pose.from_dict({"nod": 0.3, "smile_l": 0.5}), 0)
    comp.set_action("head", Pose.from_dict({"nod": -0.1}))
    values = comp.compose(0)
    assert values[NOD] == pytest.approx(0.2)
    assert values[SMILE] == pytest.approx(0.5)


def test_nothing_cares_means_relaxed() -> None:
    assert np.array_equal(_instant().compose(S(3)), np.zeros(N_FLEXORS))


def test_output_is_clipped_to_the_flexor_range() -> None:
    comp = _instant()
    comp.set_pose("emotion", Pose.from_dict({"nod": 0.9}), 0)
    comp.set_action("head", Pose.from_dict({"nod": 0.9}))
    assert comp.compose(0)[NOD] == 1.0


def test_frames_hold_the_clipped_composite_and_are_read_only() -> None:
    comp = _instant()
    comp.set_pose("emotion", Pose.from_dict({"nod": 0.9, "smile_l": -0.7}), 0)
    comp.set_action("head", Pose.from_dict({"nod": 0.9}))
    frame = comp.frame_at(S(2))
    np.testing.assert_array_equal(frame.values, comp.compose(S(2)))
    assert frame.t_ns == S(2) and frame.values[NOD] == 1.0
    np.testing.assert_array_equal(FlexorFrame(frame.values, frame.t_ns).values, frame.values)  # a valid frame
    with pytest.raises(ValueError):
        frame.values[NOD] = 0.0


def test_blend_onto_keeps_dont_care_below_when_the_layer_does_not_care() -> None:
    below = np.full(N_FLEXORS, DONT_CARE)
    assert np.all(np.isnan(blend_onto(below, np.full(N_FLEXORS, DONT_CARE), Blend.REPLACE)))
    assert np.all(np.isnan(blend_onto(below, np.full(N_FLEXORS, DONT_CARE), Blend.ADD)))


def test_settle_time_is_95_percent_of_the_way() -> None:
    settle = np.full(N_FLEXORS, 0.5)
    settle[BROW] = 0.2
    comp = Compositor(settle)
    comp.set_pose("emotion", Pose.from_dict({"smile_l": 1.0, "brow_l": -1.0}), S(2.0))
    at_settle = comp.compose(S(2.5))
    assert at_settle[SMILE] == pytest.approx(0.95, abs=1e-9)
    assert comp.compose(S(2.2))[BROW] == pytest.approx(-0.95, abs=1e-9)
    halfway = comp.compose(S(2.25))[SMILE]
    assert 0.5 < halfway < 0.95  # exponential: more than half the way at half the settle time
    assert comp.compose(S(2.0))[SMILE] == 0.0  # nothing moves before the change


def test_each_flexor_keeps_its_own_settle_time() -> None:
    settle = np.linspace(0.1, 1.0, N_FLEXORS)
    settler = Settler(settle)
    settler.retarget(np.ones(N_FLEXORS), 0)
    for i in range(N_FLEXORS):
        assert settler.value_at(S(settle[i]))[i] == pytest.approx(0.95)


def test_an_explicit_transition_time_overrides_the_settle_times_for_that_change() -> None:
    comp = Compositor(np.full(N_FLEXORS, 0.5))
    comp.set_pose("emotion", Pose.from_dict({"smile_l": 1.0}), 0, settle_s=2.0)
    assert comp.compose(S(2.0))[SMILE] == pytest.approx(0.95)


def test_unchanged_flexors_keep_running_their_transition_when_another_flexor_changes() -> None:
    comp = Compositor(np.full(N_FLEXORS, 1.0))
    comp.set_pose("emotion", Pose.from_dict({"smile_l": 1.0}), 0)
    reference = comp.compose(S(0.8))[SMILE]
    comp.set_pose("emotion", Pose.from_dict({"smile_l": 1.0, "brow_l": 0.5}), S(0.3))
    assert comp.compose(S(0.8))[SMILE] == pytest.approx(reference)


@settings(max_examples=40, deadline=None)
@given(
    first=st.floats(-1, 1),
    second=st.floats(-1, 1),
    interrupt_s=st.floats(0.0, 1.0),
    settle_s=st.floats(0.05, 1.0),
)
def test_an_interrupting_target_continues_from_the_current_value(
    first: float, second: float, interrupt_s: float, settle_s: float
) -> None:
    settler = Settler(settle_s)
    settler.retarget(np.full(N_FLEXORS, first), 0)
    t = S(interrupt_s)
    before = settler.value_at(t)
    settler.retarget(np.full(N_FLEXORS, second), t)
    np.testing.assert_allclose(settler.value_at(t), before, atol=1e-12)
    # one microsecond on it has moved no faster than the exponential's initial speed: no jump
    step = np.abs(settler.value_at(t + 1000) - before)
    fastest = np.abs(second - before) * LN_20 / settle_s * 1e-6
    assert np.all(step <= fastest * 1.001 + 1e-12)


def test_composite_is_frame_rate_independent() -> None:
    """The same commands sampled at 24, 60 or 1000 frames/s agree wherever the sample times coincide."""

    def run(fps: int) -> dict[int, np.ndarray]:
        comp = Compositor(np.full(N_FLEXORS, 0.4))
        commands = [(S(0.1), {"smile_l": 0.7}), (S(0.5), {"smile_l": -0.3, "brow_l": 0.6})]
        frames: dict[int, np.ndarray] = {}
        for k in range(fps + 1):  # one second of frames, commands applied as their time comes
            t = S(k / fps)
            while commands and commands[0][0] <= t:
                t_cmd, pose = commands.pop(0)
                comp.set_pose("emotion", Pose.from_dict(pose), t_cmd)
            frames[t] = comp.compose(t)
        return frames

    slow, fast = run(20), run(1000)
    shared = sorted(set(slow) & set(fast))
    assert len(shared) >= 10
    for t in shared:
        np.testing.assert_array_equal(slow[t], fast[t])


def test_compose_is_deterministic_and_does_not_depend_on_being_called() -> None:
    def build() -> Compositor:
        comp = Compositor(np.full(N_FLEXORS, 0.3))
        comp.set_pose("emotion", Pose.from_dict({"smile_l": 0.9}), S(0.0))
        return comp

    a, b = build(), build()
    for t in np.linspace(0, 1, 7):
        a.compose(S(t))  # a is sampled often, b never before the change
    a.set_pose("emotion", Pose.from_dict({"smile_l": -0.5}), S(0.5))
    b.set_pose("emotion", Pose.from_dict({"smile_l": -0.5}), S(0.5))
    for t in (0.5, 0.6, 1.3):
        np.testing.assert_array_equal(a.compose(S(t)), b.compose(S(t)))


def test_changes_may_not_go_back_in_time() -> None:
    comp = Compositor(0.5)
    comp.set_pose("emotion", Pose.from_dict({"smile_l": 0.5}), S(1.0))
    with pytest.raises(ValueError, match="before the previous change"):
        comp.set_pose("emotion", Pose.from_dict({"smile_l": 0.1}), S(0.5))


def test_layer_misuse_gets_clear_errors() -> None:
    comp = _instant()
    with pytest.raises(ValueError, match="unknown layer 'face'; layers: base, emotion, head"):
        comp.set_pose("face", None, 0)
    with pytest.raises(ValueError, match="use set_pose"):
        comp.set_action("emotion", Pose.from_dict({}))
    with pytest.raises(ValueError, match="set_action"):
        comp.set_pose("gaze", None, 0)
    with pytest.raises(TypeError, match="values_at"):
        comp.set_action("gaze", 3)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="outside"):
        comp.set_pose("emotion", np.full(N_FLEXORS, 2.0), 0)


def test_layer_stacks_are_checked() -> None:
    with pytest.raises(ValueError, match="unique"):
        Compositor(0.0, [LayerSpec("a"), LayerSpec("a")])
    with pytest.raises(ValueError, match="bottom of the stack"):
        Compositor(0.0, [LayerSpec("gaze"), LayerSpec("emotion", settles=True)])
    with pytest.raises(ValueError, match="settle time for 'turn'"):
        Compositor(-1.0)


def test_the_default_stack_puts_emotion_under_head_gaze_mouth_and_blink() -> None:
    names = [spec.name for spec in DEFAULT_LAYERS]
    assert names.index("base") < names.index("emotion") < names.index("head")
    assert names.index("emotion") < names.index("mouth") and names.index("gaze") < names.index("blink")
    assert names[-1] == "idle"


class _FullVectorsOnly:
    """An action seen only through values_at: what the compositor does with any action from outside."""

    def __init__(self, action: object) -> None:
        self.action = action

    def values_at(self, t_ns: int) -> np.ndarray:
        return self.action.values_at(t_ns)  # type: ignore[attr-defined, no-any-return]


def _busy_scenes(seed: int) -> list[LiveScene]:
    """Two live scenes given the same inputs: every layer of the face busy, speech on, eyes sampled."""
    scenes = [LiveScene(seed=seed), LiveScene(seed=seed)]
    for scene in scenes:
        scene.speech_started("r", 0)
        scene.add_clock_anchor("r", 0, 16_000, 0)
        positions = list(range(0, 16_000 * 2, 160))
        scene.add_mouth_keys("r", 16_000, positions, {"say_ah": [0.5 + 0.5 * np.sin(j * 0.3) for j in
                                                                range(len(positions))]}, False, 0)
    return scenes


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 2**31 - 1))
def test_layers_that_say_only_what_they_care_about_compose_the_same_face_as_their_full_vectors(seed: int) -> None:
    sparse, full = _busy_scenes(seed)
    comp = full.model.compositor
    for spec in DEFAULT_LAYERS:
        if not spec.settles and comp.action(spec.name) is not None:
            comp.set_action(spec.name, _FullVectorsOnly(comp.action(spec.name)))
    for k in range(1, 240):
        t = k * 16_666_667
        for scene in (sparse, full):
            r = np.random.default_rng([seed, k])  # the same inputs to both
            if r.random() < 0.02:
                scene.set_emotion(str(r.choice(["happy", "angry", "surprised", "natural"])), 1.0, 0.3, t)
            if r.random() < 0.02:
                scene.move_head(float(r.uniform(-0.5, 0.5)), 0.2, -0.1, float(r.uniform(0, 0.6)), t)
            if r.random() < 0.02:
                scene.attend(float(r.uniform(-20, 20)), 4.0, 0.4, t)
            if r.random() < 0.02:
                scene.head_gesture(f"g{k}", str(r.choice(["nod", "shake", "tilt"])), t, 6.0, 0.5, 2)
            if r.random() < 0.02:
                scene.expression(f"e{k % 2}", t, t + S(0.1), t + S(0.2), t + S(0.4),
                                 {"brow_l": 0.4, "say_ah": 0.2})
            if r.random() < 0.7:
                lid = 1.0 if r.random() < 0.05 else 0.0
                scene.add_eye_sample(t, float(r.uniform(-15, 15)), float(r.uniform(-8, 8)), lid, "saccade+blink")
        a, b = sparse.compose(t), full.compose(t)
        assert np.array_equal(a.frame.values, b.frame.values), f"frame {k}"
        assert (a.head_yaw_deg, a.left_eye) == (b.head_yaw_deg, b.left_eye)


def test_each_face_layer_says_exactly_the_values_its_full_vector_holds() -> None:
    scene = _busy_scenes(7)[0]
    scene.head_gesture("g", "nod", S(0.1), 6.0, 1.0, 2)
    scene.head_gesture("h", "shake", S(0.2), 6.0, 1.0, 1)
    scene.expression("e", S(0.1), S(0.3), S(0.5), S(0.9), {"brow_l": 0.4, "smile_r": -0.3})
    scene.add_eye_sample(S(0.1), 5.0, -3.0, 0.4, "saccade+blink")
    comp = scene.model.compositor
    checked = 0
    for t in (S(0.05), S(0.25), S(0.4), S(0.7), S(1.5)):
        scene.compose(t)
        for spec in DEFAULT_LAYERS:
            action = None if spec.settles else comp.action(spec.name)
            if action is None:
                continue
            full = action.values_at(t)
            cared = action.sparse_at(t)  # type: ignore[attr-defined]
            want = np.flatnonzero(~np.isnan(full))
            if cared is None:
                assert want.size == 0, spec.name
                continue
            index, values = cared
            assert sorted(index.tolist()) == want.tolist(), spec.name
            assert np.array_equal(full[index], values), spec.name
            checked += 1
    assert checked >= 25  # head, attention, gestures, gaze, mouth, blink, expression and idle all said something
