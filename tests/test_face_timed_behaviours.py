"""Head gestures (nod, shake, tilt with repetitions) and timed facial expressions: where their strokes and
envelopes fall on the clock, how one replaces another of the same id, and that the composed face shows them."""

from __future__ import annotations

import numpy as np
import pytest

from eca.agent.face.expressions import Expressions
from eca.agent.face.flexors import FLEXOR_INDEX
from eca.agent.face.gestures import HeadGestures
from eca.agent.face.scene import LiveScene

MS = 1_000_000
NOD, TURN, TILT = FLEXOR_INDEX["nod"], FLEXOR_INDEX["turn"], FLEXOR_INDEX["tilt"]


def trace(action: HeadGestures | Expressions, index: int, start_ns: int, end_ns: int, step_ns: int = MS) -> np.ndarray:
    times = np.arange(start_ns, end_ns, step_ns)
    return np.array([[t, np.nan_to_num(action.values_at(int(t))[index])] for t in times])


@pytest.mark.parametrize("repetitions", [1, 2, 3])
def test_each_nod_is_deepest_at_its_stroke(repetitions: int) -> None:
    g = HeadGestures()
    g.add("nod", 1000 * MS, 0.4, 0.9, repetitions)
    values = trace(g, NOD, 900 * MS, 2000 * MS)
    assert np.all(values[values[:, 0] < 1000 * MS, 1] == 0) and np.all(values[values[:, 0] >= 1900 * MS, 1] == 0)
    period = 900 * MS // repetitions
    for i in range(repetitions):
        inside = values[(values[:, 0] >= 1000 * MS + i * period) & (values[:, 0] < 1000 * MS + (i + 1) * period)]
        deepest = inside[np.argmin(inside[:, 1])]
        assert abs(deepest[0] - (1000 * MS + i * period + period // 2)) <= MS  # the chin lowest at the stroke
        assert deepest[1] == pytest.approx(-0.4, abs=1e-3)


def test_a_shake_turns_both_ways_and_a_tilt_leans() -> None:
    g = HeadGestures()
    g.add("shake", 0, 0.3, 1.0, 2)
    g.add("tilt", 0, 0.2, 1.0, 1)
    turn = trace(g, TURN, 0, 1000 * MS)[:, 1]
    tilt = trace(g, TILT, 0, 1000 * MS)[:, 1]
    assert turn.max() == pytest.approx(0.3, abs=1e-3) and turn.min() == pytest.approx(-0.3, abs=1e-3)
    assert tilt.max() == pytest.approx(0.2, abs=1e-3) and tilt.min() >= 0


def test_a_gesture_with_an_id_replaces_the_one_before_and_duration_zero_ends_it() -> None:
    g = HeadGestures()
    g.add("nod", 0, 0.5, 1.0, 1, gesture_id="b1:h1")
    g.add("nod", 0, 0.1, 1.0, 1, gesture_id="b1:h1")
    assert g.values_at(500 * MS)[NOD] == pytest.approx(-0.1)
    g.add("nod", 400 * MS, 0.0, 0.0, 1, gesture_id="b1:h1")
    assert np.isnan(g.values_at(500 * MS)[NOD])


@pytest.mark.parametrize("bad", [dict(depth=0.0), dict(depth=2.0), dict(duration_s=-1.0), dict(repetitions=0),
                                 dict(repetitions=21), dict(depth=float("nan"))])
def test_bad_gestures_are_refused(bad: dict[str, float]) -> None:
    args = {"depth": 0.3, "duration_s": 1.0, "repetitions": 1} | bad
    with pytest.raises(ValueError):
        HeadGestures().add("nod", 0, args["depth"], args["duration_s"], int(args["repetitions"]))


def test_an_expression_rises_to_its_peak_holds_and_is_gone_at_its_end() -> None:
    e = Expressions()
    e.set("b1:f1", 100 * MS, 300 * MS, 600 * MS, 800 * MS, {"brow_l": 0.6, "brow_r": 0.6})
    brow = trace(e, FLEXOR_INDEX["brow_l"], 0, 900 * MS)
    at = dict(zip(brow[:, 0].astype(int), brow[:, 1], strict=True))
    assert at[50 * MS] == 0 and at[200 * MS] == pytest.approx(0.3)  # half way up at the middle of the attack
    assert at[300 * MS] == pytest.approx(0.6) and at[599 * MS] == pytest.approx(0.6)
    assert at[700 * MS] == pytest.approx(0.3) and at[850 * MS] == 0
    assert np.all(np.diff(brow[brow[:, 0] < 300 * MS, 1]) >= 0)  # rising without a step back
    assert np.isnan(e.values_at(400 * MS)[FLEXOR_INDEX["smile_l"]])  # what it does not move, it leaves alone


def test_an_expression_replaced_by_id_ends_early_and_bad_ones_are_refused() -> None:
    e = Expressions()
    e.set("x", 0, 100 * MS, 900 * MS, 1000 * MS, {"smile_l": 0.5})
    e.set("x", 0, 100 * MS, 200 * MS, 300 * MS, {"smile_l": 0.5})
    assert e.values_at(250 * MS)[FLEXOR_INDEX["smile_l"]] < 0.5 and len(e) == 1
    assert np.isnan(e.values_at(400 * MS)[FLEXOR_INDEX["smile_l"]]) and len(e) == 0
    for flexors, times in [({"nose": 0.1}, (0, 1, 2, 3)), ({"smile_l": 2.0}, (0, 1, 2, 3)),
                           ({"smile_l": 0.1}, (5, 1, 2, 3))]:
        with pytest.raises(ValueError):
            e.set("y", *times, flexors)


def test_the_composed_face_shows_a_gesture_and_an_expression_at_their_times() -> None:
    scene = LiveScene(seed=1, idle_noise=False)
    scene.head_gesture("b:h", "nod", 1000 * MS, 15.0, 0.5, 1)
    scene.expression("b:f", 1000 * MS, 1100 * MS, 1400 * MS, 1500 * MS, {"brow_l": 0.5, "brow_r": 0.5})
    before, stroke = scene.compose(900 * MS), scene.compose(1250 * MS)
    assert stroke.frame.get("nod") < before.frame.get("nod") - 0.5  # 15 deg of 25 per unit: 0.6 down
    assert stroke.frame.get("brow_l") == pytest.approx(before.frame.get("brow_l") + 0.5, abs=1e-6)
    after = scene.compose(1600 * MS)
    assert after.frame.get("brow_l") == pytest.approx(before.frame.get("brow_l"), abs=1e-6)
