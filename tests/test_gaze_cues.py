"""The gaze engine's cues for conversation: several gaze targets, forced gaze shifts, blinks on cue, turn
boundaries, and cues of one instant applied together before any decision."""

from __future__ import annotations

import math

import numpy as np
import pytest

from eca.agent.gaze.engine import BLINK_ONSET, NEXT_BLINK, GazeEngine
from eca.agent.gaze.params import KINDS, GazeParams

S = 1_000_000_000
MUTUAL, AWAY, HEAD = (KINDS.index(k) for k in ("mutual", "away", "head"))


@pytest.fixture(scope="module")
def params() -> GazeParams:
    return GazeParams.load()


def _onsets(engine: GazeEngine, until_ns: int, step_ns: int) -> dict[str, np.ndarray]:
    ticks = [engine.tick(t).saccades for t in range(engine.now_ns + step_ns, until_ns + 1, step_ns)]
    return {name: np.concatenate([getattr(o, name) for o in ticks]) for name in ticks[0].__dataclass_fields__}


def test_same_instant_cues_all_apply_before_the_decision(params: GazeParams) -> None:
    """After an angry turn (P(mutual) 0.75 + 0.25 = 1 while listening) the listener's next turn is natural:
    its first decision, at the turn boundary, must use the natural statistics whichever cue came first."""
    n = 40_000
    for mode in ("saccade+blink", "saccade+noise+blink"):
        engine = GazeEngine(n, seed=41, params=params, role="talking", mode=mode)
        everyone = np.arange(n)
        engine.set_emotion(everyone, "angry", 1.0, 0)
        engine.tick(3 * S)
        boundary = 3 * S + 500
        engine.set_role(everyone, "listening", boundary)  # the role first, as scripts and the bus order them
        engine.set_emotion(everyone, "natural", 1.0, boundary)
        s = engine.tick(3 * S + S // 60).saccades
        first = (s.onset_ns == boundary) & (s.kind <= HEAD)
        assert np.count_nonzero(first) == n
        away = np.mean(s.kind[first] == AWAY)
        assert away == pytest.approx(1.0 - params.roles["listening"].mutual_probability, abs=0.01)


def test_several_targets_are_chosen_by_their_weights(params: GazeParams) -> None:
    """A listener among two speakers looks at the one it listens to with the weight given (Vertegaal et al.
    2001: 88 %), the other for the rest; away saccades centre on the one chosen."""
    n = 600
    engine = GazeEngine(n, seed=42, params=params, role="talking", mode="saccade+noise+blink")
    for i in range(n):
        engine.set_targets(i, [-20.0, 15.0], [0.0, 2.0], [0.88, 0.12], 0)
    s = _onsets(engine, 60 * S, S)
    mutual = (s["kind"] == MUTUAL) & (s["onset_ns"] > 0)
    at_first = (s["to_yaw_deg"][mutual] == -20.0) & (s["to_pitch_deg"][mutual] == 0.0)
    at_second = (s["to_yaw_deg"][mutual] == 15.0) & (s["to_pitch_deg"][mutual] == 2.0)
    assert np.all(at_first | at_second)
    count = np.count_nonzero(mutual)
    assert abs(at_first.mean() - 0.88) < 4 * math.sqrt(0.88 * 0.12 / count)
    away = (s["kind"] == AWAY) & (s["onset_ns"] > 0)
    centre = np.stack([s["to_yaw_deg"][away], s["to_pitch_deg"][away]], axis=1)
    near_first = np.hypot(centre[:, 0] + 20.0, centre[:, 1]) <= s["magnitude_deg"][away] + 1e-6
    near_second = np.hypot(centre[:, 0] - 15.0, centre[:, 1] - 2.0) <= s["magnitude_deg"][away] + 1e-6
    assert np.all(near_first | near_second) and 0.8 < near_first.mean() < 0.95


def test_new_targets_turn_mutual_gaze_at_once(params: GazeParams) -> None:
    n = 2_000
    engine = GazeEngine(n, seed=43, params=params, role="listening", mode="saccade+noise+blink")
    engine.tick(20 * S)
    holding = np.array([engine.tick(20 * S).yaw_deg[i] for i in range(n)])  # eyes near 0: mutual, scanning
    turn = 20 * S + 1000
    for i in range(n):
        engine.set_targets(i, [25.0, -10.0], [0.0, 0.0], [0.88, 0.12], turn)
    s = engine.tick(turn + 1).saccades
    followed = s.agent[(s.onset_ns == turn) & (s.kind == MUTUAL)]
    mutual_before = np.abs(holding) < 6.0
    # Those holding mutual gaze turn now, to the new speaker mostly; those looking away keep their hold.
    assert followed.size > 0.8 * np.count_nonzero(mutual_before)
    to_new = s.to_yaw_deg[(s.onset_ns == turn) & (s.kind == MUTUAL)] == 25.0
    assert 0.84 < to_new.mean() < 0.92


def test_shift_gaze_forces_the_next_decision_now(params: GazeParams) -> None:
    """Kendon 1967: the speaker looks away as a long turn starts, back at the listener as it ends."""
    n = 3_000
    engine = GazeEngine(n, seed=44, params=params, role="talking", mode="saccade+noise+blink")
    engine.tick(5 * S)
    everyone = np.arange(n)
    engine.shift_gaze(everyone, "away", 5 * S + 10)
    s = engine.tick(5 * S + 20).saccades
    now = (s.onset_ns == 5 * S + 10) & (s.kind <= HEAD)
    assert np.count_nonzero(now) == n and np.all(s.kind[now] == AWAY)
    engine.shift_gaze(everyone, "mutual", 6 * S)
    s = engine.tick(6 * S + 1).saccades
    now = (s.onset_ns == 6 * S) & (s.kind <= HEAD)
    assert np.count_nonzero(now) == n and np.all(s.kind[now] == MUTUAL)
    # The cue is spent: later decisions are drawn again.
    later = _onsets(engine, 30 * S, S)
    kinds = later["kind"][later["kind"] <= HEAD]
    assert np.mean(kinds == MUTUAL) == pytest.approx(params.roles["talking"].mutual_probability, abs=0.03)
    with pytest.raises(ValueError, match="mutual, away"):
        engine.shift_gaze(0, "sideways", 31 * S)


def test_blink_at_pulls_a_due_blink_and_keeps_the_rate(params: GazeParams) -> None:
    n = 4_000
    engine = GazeEngine(n, seed=45, params=params, role="listening", mode="saccade+noise+blink")
    engine.tick(10 * S)
    due_soon = engine._rows[:, NEXT_BLINK] - 10 * S <= params.blink.pull_window_s * S
    blinked = engine.blink_at(np.arange(n), 10 * S + 7)
    assert set(blinked.tolist()) == set(np.flatnonzero(due_soon).tolist())
    assert np.all(engine._rows[blinked, BLINK_ONSET] == 10 * S + 7)
    tick = engine.tick(10 * S + 7 + 50_000_000)  # 50 ms later: the lids closed
    assert np.all(tick.lid[blinked] > 0.9)
    # Over minutes of feedback blinks at every pause, the rate is still the configured one.
    blinks = 0
    for second in range(11, 131):
        engine.blink_at(np.arange(n), second * S - S // 2)
        blinks += len(engine.tick(second * S).blinks)
    assert blinks / (n * 2.0) == pytest.approx(params.roles["listening"].blink_rate_per_min, rel=0.03)


def test_turn_boundaries_bring_blinks(params: GazeParams) -> None:
    """In the paper's recommendation a change of turn pulls a due blink to it with [blink] turn_probability
    at least; the paper's condition (d) keeps only gaze-evoked blinks."""
    shares = {}
    for mode in ("saccade+blink", "saccade+noise+blink"):
        n = 20_000
        engine = GazeEngine(n, seed=46, params=params, role="listening", mode=mode)
        engine.tick(10 * S)
        boundary = 10 * S + 3
        engine.set_role(np.arange(n), "talking", boundary)  # draws each next blink at the new role's rate
        due_soon = np.flatnonzero(engine._rows[:, NEXT_BLINK] - boundary <= params.blink.pull_window_s * S)
        blinks = engine.tick(boundary + 1).blinks
        at_turn = set(blinks.agent[blinks.onset_ns == boundary].tolist())
        shares[mode] = np.mean([a in at_turn for a in due_soon.tolist()])
    assert shares["saccade+noise+blink"] >= params.blink.turn_probability - 0.02
    assert shares["saccade+blink"] < params.blink.turn_probability - 0.1
