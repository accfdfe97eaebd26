"""Head gestures on top of the scripted head: the turn toward the person attended and a listener's nods."""

from __future__ import annotations

import numpy as np
import pytest

from eca.agent.face.flexors import FLEXOR_INDEX
from eca.agent.face.model import FaceModel

S = 1_000_000_000
TURN, NOD = FLEXOR_INDEX["turn"], FLEXOR_INDEX["nod"]


def test_attention_adds_to_the_scripted_head_and_arrives_at_rest() -> None:
    face = FaceModel(idle_noise=False)
    face.move_head(0.2, 0.0, 0.0, 0.0, 0)
    face.attend(-12.0, 0.0, 0.6, S)
    assert face.frame_at(S).values[TURN] == pytest.approx(0.2)
    assert face.frame_at(2 * S).values[TURN] == pytest.approx(0.2 - 12.0 / face.units.turn_deg)
    halfway = face.frame_at(S + 300_000_000).values[TURN]
    assert 0.2 - 12.0 / face.units.turn_deg < halfway < 0.2


def test_a_nod_dips_the_chin_and_comes_back() -> None:
    face = FaceModel(idle_noise=False)
    face.move_head(0.0, 0.1, 0.0, 0.0, 0)
    face.nod(5.0, 0.5, S)
    depth = 5.0 / face.units.nod_deg
    samples = [face.frame_at(S + k * 50_000_000).values[NOD] for k in range(11)]
    assert samples[0] == pytest.approx(0.1) and samples[-1] == pytest.approx(0.1)
    assert min(samples) == pytest.approx(0.1 - depth) and int(np.argmin(samples)) == 5
    assert all(a >= b for a, b in zip(samples[:6], samples[1:6], strict=False))  # down, then up
    with pytest.raises(ValueError, match="depth"):
        face.nod(-3.0, 0.5, 2 * S)
    with pytest.raises(ValueError, match="seconds"):
        face.nod(3.0, 0.0, 2 * S)


def test_without_gestures_the_face_is_what_it_was() -> None:
    plain, gestured = FaceModel(seed=3), FaceModel(seed=3)
    gestured.attend(0.0, 0.0, 0.5, 0)
    for t in range(0, 3 * S, S // 7):
        np.testing.assert_array_equal(plain.frame_at(t).values, gestured.frame_at(t).values)
