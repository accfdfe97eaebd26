"""How the gaze engine batches its work changes nothing but its speed.

The engine runs a tick's small saccades in batches of a bounded size, sorts a tick's onsets by buckets,
and writes eye positions as 16-byte pairs where the latest write to an agent must win. The reference
model (tests/test_gaze_reference.py) holds a handful of agents, too few to reach these paths; here the
engine is held to itself with the paths forced either way.
"""

from __future__ import annotations

import numpy as np
import pytest

from eca.agent.gaze import fixation
from eca.agent.gaze.engine import GazeEngine
from eca.agent.gaze.params import GazeParams
from eca.agent.gaze.rows import sort_onsets, write_eyes

S = 1_000_000_000
FRAME = S // 60


def _trajectory(params: GazeParams, ticks: list[int]) -> list[np.ndarray]:
    engine = GazeEngine(12_000, seed=5, params=params, role="talking")
    out = []
    for t in ticks:
        tick = engine.tick(t)
        s = tick.saccades
        out += [tick.yaw_deg.copy(), tick.pitch_deg.copy(), tick.lid.copy(), s.agent, s.onset_ns, s.kind,
                s.from_yaw_deg, s.to_pitch_deg, s.direction_deg, s.hold_s, tick.blinks.agent, tick.blinks.onset_ns]
    return out


def test_small_saccades_in_bounded_batches_give_the_same_trajectory(
    params: GazeParams, monkeypatch: pytest.MonkeyPatch
) -> None:
    # A second-long tick gives most of 12,000 agents a small saccade: several batches of 2,048.
    ticks = [S, 2 * S, 2 * S + FRAME, 2 * S + 2 * FRAME, 4 * S]
    monkeypatch.setattr(fixation, "_BATCH", 2048)
    batched = _trajectory(params, ticks)
    monkeypatch.setattr(fixation, "_BATCH", 1 << 40)
    whole = _trajectory(params, ticks)
    for a, b in zip(batched, whole, strict=True):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("instants", [1, 3, 1000])
def test_onsets_crowded_into_few_instants_sort_as_lexsort(instants: int) -> None:
    """Many onsets at a few instants share the sort's buckets: the order is still (onset, agent), ties
    in the order given."""
    rng = np.random.default_rng(instants)
    agent = rng.integers(0, 1_000_000, 60_000)
    onset = 5 * S + rng.integers(0, instants, agent.size) * 7919
    order, sorted_agent, sorted_onset = sort_onsets(agent, onset, 1_000_000)
    expected = np.lexsort((agent, onset))
    np.testing.assert_array_equal(order, expected)
    np.testing.assert_array_equal(sorted_agent, agent[expected])
    np.testing.assert_array_equal(sorted_onset, onset[expected])


def test_the_latest_eye_write_of_an_agent_wins() -> None:
    """A tick lands an agent's saccade and then one launched after it, in one write: the later stays."""
    eyes = np.zeros((5, 2))
    write_eyes(eyes, np.array([3, 1, 3, 3]), np.array([1.0, 2.0, 3.0, 4.0]), np.array([-1.0, -2.0, -3.0, -4.0]))
    np.testing.assert_array_equal(eyes, [[0, 0], [2, -2], [0, 0], [4, -4], [0, 0]])


@pytest.fixture(scope="module")
def params() -> GazeParams:
    return GazeParams.load()
