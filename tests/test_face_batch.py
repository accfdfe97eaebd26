"""Many faces composed together (agent/face/batch.py) against each composed alone (LiveScene.compose): the same
flexors and angles at every frame (to the last bits: numpy may take another vector path for a longer array), and
whether each is voiced, through emotions, head moves, gestures, expressions, gaze, blinks and speech,
agents coming and going, and stacks the batch cannot share (no idle noise, another amplitude)."""

from __future__ import annotations

import numpy as np
import pytest

from eca.agent.face.batch import FaceBatch
from eca.agent.face.emotions import PAPER_EMOTIONS
from eca.agent.face.idle import IdleNoise
from eca.agent.face.model import FaceModel
from eca.agent.face.scene import LiveScene

FRAME_NS = 1_000_000_000 // 30


def _busy(scene: LiveScene, rng: np.random.Generator, t: int) -> None:
    """Random inputs of every kind a live scene takes, some of the time."""
    if rng.random() < 0.03:
        scene.set_emotion(str(rng.choice(PAPER_EMOTIONS)), float(rng.uniform(0.2, 1.0)), float(rng.uniform(0, 0.8)),
                          t)
    if rng.random() < 0.03:
        turn, nod, tilt = (float(v) for v in rng.uniform(-0.6, 0.6, 3))
        scene.move_head(turn, nod, tilt, float(rng.uniform(0.1, 1.0)), t)
    if rng.random() < 0.02:
        scene.attend(float(rng.uniform(-20, 20)), float(rng.uniform(-5, 5)), 0.4, t)
    if rng.random() < 0.02:
        scene.nod(t, float(rng.uniform(2, 8)), 0.5)
    if rng.random() < 0.02:
        scene.expression(f"x{t}", t, t + 100_000_000, t + 400_000_000, t + 600_000_000,
                         {"smile_l": 0.6, "smile_r": 0.6, "brows_knit": -0.3, "say_ah": 0.4})
    if rng.random() < 0.5:
        scene.add_eye_sample(t, float(rng.uniform(-15, 15)), float(rng.uniform(-8, 8)),
                             float(rng.random() < 0.05), "saccade+blink")


def _speak(scene: LiveScene, request_id: str, t: int, seconds: float) -> None:
    scene.speech_started(request_id, t)
    scene.add_clock_anchor(request_id, 0, 16_000, t)
    positions = list(range(0, int(16_000 * seconds), 160))
    weights = [0.5 + 0.5 * np.sin(j * 0.3) for j in range(len(positions))]
    scene.add_mouth_keys(request_id, 16_000, positions, {"say_ah": weights, "say_oo": weights[::-1]}, False, t)


def _alone(scenes: list[LiveScene], t: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    faces = [scene.compose(t) for scene in scenes]
    return (np.stack([f.frame.values for f in faces]),
            np.array([[f.left_eye.yaw_deg, f.left_eye.pitch_deg, f.right_eye.yaw_deg, f.right_eye.pitch_deg]
                      for f in faces]),
            np.array([[f.head_yaw_deg, f.head_pitch_deg, f.head_roll_deg] for f in faces]))


def _check(batch: FaceBatch, scenes: list[LiveScene], t: int) -> None:
    together = batch.compose(scenes, t)
    assert batch.voiced == [scene.voiced_at(t) for scene in scenes]
    alone = _alone(scenes, t)
    for got, want, what in zip(together, alone, ("flexors", "eyes", "head"), strict=True):
        assert got.shape == want.shape, what
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-12, err_msg=f"{what} at t={t}")


def test_many_faces_together_are_each_face_alone() -> None:
    rng = np.random.default_rng(7)
    scenes = [LiveScene(seed=i) for i in range(12)]
    batch = FaceBatch()
    for i, scene in enumerate(scenes[::3]):
        _speak(scene, f"r{i}", 0, 4.0)
    for k in range(400):  # 13 s: lattice cells of the idle noise crossed many times, emotions settling and changing
        t = k * FRAME_NS
        for scene in scenes:
            _busy(scene, rng, t)
        if k == 150:
            _speak(scenes[1], "late", t, 2.0)
        _check(batch, scenes, t)
        for scene in scenes:
            scene.prune(t)


def test_agents_coming_and_going_and_a_jump_in_time() -> None:
    rng = np.random.default_rng(3)
    scenes = [LiveScene(seed=i) for i in range(5)]
    batch = FaceBatch()
    t = 0
    for k in range(120):
        t = k * FRAME_NS
        for scene in scenes:
            _busy(scene, rng, t)
        if k == 40:
            scenes.append(LiveScene(seed=99))  # a conversation begins
        if k == 80:
            del scenes[1]  # and one ends
        _check(batch, scenes, t)
    _check(batch, scenes, t + 37 * 10**9)  # far ahead: every lattice cell jumps, not steps
    flexors, eyes, head = batch.compose([], t)
    assert (flexors.shape, eyes.shape, head.shape) == ((0, 21), (0, 4), (0, 3))


@pytest.mark.parametrize("odd", ["no idle noise", "other amplitudes", "a flat face"])
def test_faces_the_batch_cannot_share_are_composed_alone_with_the_same_result(odd: str) -> None:
    rng = np.random.default_rng(11)
    scenes = [LiveScene(seed=i) for i in range(4)]
    if odd == "no idle noise":
        scenes.append(LiveScene(seed=4, idle_noise=False))
    elif odd == "other amplitudes":
        model = FaceModel(seed=4)
        model.idle = IdleNoise(model.idle.amplitude * 2.0, model.idle.rate_hz, seed=4)
        model.compositor.set_action("idle", model.idle)
        scenes.append(LiveScene(model=model))
    else:
        scenes = [LiveScene(seed=i, idle_noise=False) for i in range(4)]  # all alike: batched, nothing on top
    batch = FaceBatch()
    for k in range(90):
        t = k * FRAME_NS
        for scene in scenes:
            _busy(scene, rng, t)
        _check(batch, scenes, t)
