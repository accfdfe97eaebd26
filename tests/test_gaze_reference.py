"""The gaze engine against its reference model: any event sequence gives both the same trajectories.

GazeEngine runs the model for N agents in arrays; ReferenceAgent (agent/gaze/reference.py) is the same model
for one agent written step by step. Both are driven through random sequences of events (roles, emotions, head
turns, gaze targets one or several, forced gaze shifts, blinks on demand, eye modes, agents added on the way,
events stamped before the last tick) at irregular ticks, several events often at one instant, and must agree
at every tick on each agent's saccades (onset, kind, from, to, magnitude, amplitude, direction, duration,
hold: exactly), its blink onsets (exactly), its eye angles (exactly) and its lid. The lid alone is compared
to 1e-12: the reference reads the lid curve by np.interp in seconds, the engine evaluates each straight
piece of it as slope * t + offset in nanoseconds (inflight.LiveBlinks), which rounds differently (by about
1e-16 on a closure of at most 1).

Time runs forward as a live service delivers it: each event is stamped at or after the previous one, or
before the last tick (then it applies at the last tick's time).
"""

from __future__ import annotations

import numpy as np
from hypothesis import example, given, settings
from hypothesis import strategies as st

from eca.agent.gaze.engine import GazeEngine, SaccadeOnsets
from eca.agent.gaze.params import KINDS, MODES, ROLES, GazeParams
from eca.agent.gaze.reference import Onset, ReferenceAgent

PARAMS = GazeParams.load()
EMOTIONS = sorted(PARAMS.emotions)
MS = 1_000_000
MAX_AGENTS = 6
LID_TOLERANCE = 1e-12
ACTIONS = ("tick", "tick", "tick", "role", "emotion", "head", "target", "targets", "shift", "blink", "mode", "add")

events = st.lists(
    st.tuples(
        # Time since the previous event: often none (several events at one instant), often under a frame,
        # sometimes seconds (timers expire between ticks, several in one tick).
        st.one_of(
            st.sampled_from([0, 0, 1, 5 * MS, 16_666_667, 100 * MS, 400 * MS, 1500 * MS]),
            st.integers(0, 60 * MS),
            st.integers(0, 3000 * MS),
        ),
        st.sampled_from(ACTIONS),
        st.integers(1, 2**MAX_AGENTS - 1),  # which agents (a bit mask; those that exist)
        st.floats(-45.0, 45.0),
        st.floats(-45.0, 45.0),
        st.integers(0, 11),
        st.booleans(),  # stamped before the last tick, when nothing has happened since it
    ),
    min_size=20,
    max_size=80,
)


def _onsets_of(saccades: SaccadeOnsets, agent: int) -> list[Onset]:
    """One agent's rows of a tick's onsets, as the reference reports them."""
    return [
        Onset(int(saccades.onset_ns[k]), KINDS[saccades.kind[k]],
              *(float(getattr(saccades, name)[k]) for name in Onset._fields[2:]))
        for k in np.flatnonzero(saccades.agent == agent)
    ]


def _compare(engine: GazeEngine, agents: list[ReferenceAgent], t: int) -> None:
    tick = engine.tick(t)
    assert tick.yaw_deg.size == len(agents)
    for i, agent in enumerate(agents):
        ref = agent.tick(t)
        where = f"agent {i} at {t} ns ({MODES[agent.mode]})"
        assert _onsets_of(tick.saccades, i) == ref.saccades, where
        assert tick.blinks.onset_ns[tick.blinks.agent == i].tolist() == ref.blinks, where
        assert (float(tick.yaw_deg[i]), float(tick.pitch_deg[i])) == (ref.yaw_deg, ref.pitch_deg), where
        assert abs(float(tick.lid[i]) - ref.lid) <= LID_TOLERANCE, where


def _drive(n: int, seed: int, role: str, mode: str | None, script: list[tuple[int, str, int, float, float, int, bool]]
           ) -> None:
    engine = GazeEngine(n, seed=seed, params=PARAMS, role=role, mode=mode)
    agents = [ReferenceAgent(i, seed, PARAMS, 0, role, mode) for i in range(n)]
    t = last_tick = 0
    for step_ns, action, mask, a, b, choice, late in script:
        t += step_ns
        stamp = t - (choice + 1) * MS if late and t == last_tick else t
        chosen = [i for i in range(len(agents)) if mask >> i & 1] or [len(agents) - 1]
        targets = [agents[i] for i in chosen]
        if action == "tick":
            _compare(engine, agents, t)
            last_tick = t
        elif action == "role":
            engine.set_role(chosen, ROLES[choice % len(ROLES)], stamp)
            for agent in targets:
                agent.set_role(ROLES[choice % len(ROLES)], stamp)
        elif action == "emotion":
            name, intensity = EMOTIONS[choice % len(EMOTIONS)], (a + 45.0) / 90.0
            engine.set_emotion(chosen, name, intensity, stamp)
            for agent in targets:
                agent.set_emotion(name, intensity, stamp)
        elif action == "head":
            engine.set_head(chosen, a, b, stamp)
            for agent in targets:
                agent.set_head(a, b, stamp)
        elif action == "target":
            engine.set_target(chosen, a, b, stamp)
            for agent in targets:
                agent.set_target(a, b, stamp)
        elif action == "targets":  # one agent: several points to choose among
            count = 1 + choice % 3
            yaws, pitches, weights = [a, b, 0.0][:count], [b / 2, a, -5.0][:count], [1.0, 0.5, 0.25][:count]
            engine.set_targets(chosen[0], yaws, pitches, weights, stamp)
            targets[0].set_targets(yaws, pitches, weights, stamp)
        elif action == "shift":
            toward = ("mutual", "away")[choice % 2]
            engine.shift_gaze(chosen, toward, stamp)
            for agent in targets:
                agent.shift_gaze(toward, stamp)
        elif action == "blink":
            blinked = engine.blink_at(chosen, stamp).tolist()
            assert blinked == [i for i, agent in zip(chosen, targets, strict=True) if agent.blink_at(stamp)]
        elif action == "mode":
            engine.set_mode(chosen, MODES[choice % len(MODES)], stamp)
            for agent in targets:
                agent.set_mode(MODES[choice % len(MODES)], stamp)
        elif len(agents) < MAX_AGENTS:  # add an agent, in its own role and mode
            new_role, new_mode = ROLES[choice % len(ROLES)], MODES[mask % len(MODES)]
            (index,) = engine.add_agents(1, stamp, new_role, new_mode).tolist()
            agents.append(ReferenceAgent(index, seed, PARAMS, max(stamp, last_tick), new_role, new_mode))
    _compare(engine, agents, t + 5000 * MS)  # what was pending runs out


@settings(max_examples=80, deadline=None)
# Found by this test: small saccades run between two ticks (by an event for their agent) were hidden by the
# landing of a saccade launched before them; the eye state showed the landing point, not the scan's target.
@example(1, 0, "talking", None, [(0, "tick", 1, 0.0, 0.0, 0, False), (0, "role", 1, 0.0, 0.0, 2, False),
                                 (400 * MS, "role", 1, 0.0, 0.0, 8, False), (0, "tick", 1, 0.0, 0.0, 0, False)])
# And: small saccades run just before a switch out of mode saccade+noise+blink went unreported.
@example(1, 1, "listening", None, [(10 * MS, "tick", 1, 0.0, 0.0, 0, False), (1000 * MS, "mode", 1, 0.0, 0.0, 0, False),
                                   (1 * MS, "tick", 1, 0.0, 0.0, 0, False)])
@given(
    st.integers(1, 5),
    st.integers(0, 2**64 - 1),
    st.sampled_from(ROLES),
    st.sampled_from((None, *MODES)),
    events,
)
def test_engine_and_reference_give_the_same_trajectories(
    n: int, seed: int, role: str, mode: str | None, script: list[tuple[int, str, int, float, float, int, bool]]
) -> None:
    _drive(n, seed, role, mode, script)
