"""GazeEngine: the Attention Monitor's behaviour, the statistics it produces, and its reproducibility."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from eca.agent.gaze.blink import lid_closure
from eca.agent.gaze.engine import GazeEngine, SaccadeOnsets
from eca.agent.gaze.inflight import LiveBlinks
from eca.agent.gaze.params import KINDS, GazeParams
from eca.agent.gaze.synth import eye_position_at
from eca.agent.noise import perlin_blink

S = 1_000_000_000
MUTUAL, AWAY, HEAD, SCAN, MICRO = (KINDS.index(k) for k in ("mutual", "away", "head", "scan", "micro"))
# The Eyes Alive statistics hold alike with the statistical blink model and with the fixational movements of
# the paper's recommendation riding on them.
EYES_ALIVE_MODES = ("saccade+blink", "saccade+noise+blink")


@pytest.fixture(scope="module")
def params() -> GazeParams:
    return GazeParams.load()


def _run(engine: GazeEngine, until_ns: int, step_ns: int, start_ns: int = 0) -> list[SaccadeOnsets]:
    ticks = [engine.tick(t) for t in range(start_ns + step_ns, until_ns + 1, step_ns)]
    return [t.saccades for t in ticks]


def _concat(onsets: list[SaccadeOnsets]) -> dict[str, np.ndarray]:
    fields = SaccadeOnsets.__dataclass_fields__
    return {name: np.concatenate([getattr(o, name) for o in onsets]) for name in fields}


def _eyes_alive(onsets: dict[str, np.ndarray], after_ns: int = -1) -> dict[str, np.ndarray]:
    """The Eyes Alive saccades (mutual, away, head) among the onsets, those after `after_ns`."""
    keep = (onsets["kind"] <= HEAD) & (onsets["onset_ns"] > after_ns)
    return {name: column[keep] for name, column in onsets.items()}


@pytest.fixture(scope="module", params=EYES_ALIVE_MODES)
def talking_crowd(params: GazeParams, request: pytest.FixtureRequest) -> dict[str, np.ndarray]:
    engine = GazeEngine(20_000, seed=11, params=params, mode=request.param)
    engine.set_role(np.arange(20_000), "talking", 0)
    # Drop the decision at 0, made once the role is in; the start-up one went with it (same instant).
    return _eyes_alive(_concat(_run(engine, 12 * S, S)), after_ns=0)


def test_mutual_fraction_and_holds_while_talking(params: GazeParams, talking_crowd: dict[str, np.ndarray]) -> None:
    kind = talking_crowd["kind"]
    assert kind.size >= 100_000
    assert abs(100.0 * np.mean(kind == MUTUAL) - 41.0) < 1.0
    talking = params.roles["talking"]
    for code, distribution in ((MUTUAL, talking.mutual_interval), (AWAY, talking.away_interval)):
        holds = talking_crowd["hold_s"][kind == code]
        assert stats.kstest(holds, distribution.cdf_s).pvalue > 0.01


def test_away_saccades_use_the_drawn_magnitude_and_direction(
    params: GazeParams, talking_crowd: dict[str, np.ndarray]
) -> None:
    away = talking_crowd["kind"] == AWAY
    magnitude = talking_crowd["magnitude_deg"][away]
    from eca.agent.gaze.generator import magnitude_cdf

    assert stats.kstest(magnitude, lambda a: magnitude_cdf(a, params, 27.5)).pvalue > 0.01
    offset = np.hypot(talking_crowd["to_yaw_deg"][away], talking_crowd["to_pitch_deg"][away])
    inside = (np.abs(talking_crowd["to_yaw_deg"][away]) < 30) & (np.abs(talking_crowd["to_pitch_deg"][away]) < 30)
    np.testing.assert_allclose(offset[inside], magnitude[inside], atol=1e-9)
    duration = talking_crowd["duration_s"]
    np.testing.assert_allclose(duration, 0.025 + 0.0024 * talking_crowd["amplitude_deg"], atol=1e-9)


@pytest.mark.parametrize("mode", EYES_ALIVE_MODES)
def test_listening_mutual_fraction(params: GazeParams, mode: str) -> None:
    engine = GazeEngine(25_000, seed=12, params=params, mode=mode)
    engine.set_role(np.arange(25_000), "listening", 0)
    onsets = _eyes_alive(_concat(_run(engine, 40 * S, 4 * S)), after_ns=0)
    assert onsets["kind"].size >= 100_000
    assert abs(100.0 * np.mean(onsets["kind"] == MUTUAL) - 75.0) < 1.0


@pytest.mark.parametrize("mode", EYES_ALIVE_MODES)
def test_role_switch_decides_at_once_in_the_new_regime(params: GazeParams, mode: str) -> None:
    n = 20_000
    engine = GazeEngine(n, seed=13, params=params, mode=mode)
    engine.set_role(np.arange(n), "listening", 0)
    engine.tick(5 * S)
    switch_ns = 5 * S + 123_457
    engine.set_role(np.arange(n), "talking", switch_ns)
    onsets = engine.tick(5 * S + S // 60).saccades
    at_switch = (onsets.onset_ns == switch_ns) & (onsets.kind <= HEAD)
    assert at_switch.sum() == n  # every agent, at the event's own time
    assert abs(100.0 * np.mean(onsets.kind[at_switch] == MUTUAL) - 41.0) < 1.5  # talking's, not 75%
    assert engine.role_of(0) == "talking"


def test_head_turn_above_threshold_leads_with_a_saccade(params: GazeParams) -> None:
    assert params.head_turn_threshold_deg == 10.0
    engine = GazeEngine(1, seed=14, params=params)
    engine.tick(S)
    engine.set_head(0, 6.0, 0.0, S + 1000)  # below the threshold: nothing
    assert not np.any(engine.tick(S + 2000).saccades.kind == HEAD)
    engine.set_head(0, 6.0 + 15.0, 0.0, 2 * S)  # 21 deg right from the reference (0, 0)
    onsets = engine.tick(2 * S + 1).saccades
    head = onsets.kind == HEAD
    assert head.sum() == 1 and onsets.onset_ns[head][0] == 2 * S
    assert onsets.to_yaw_deg[head][0] == pytest.approx(21.0) and onsets.to_pitch_deg[head][0] == 0.0
    engine.set_head(0, 21.0, -14.0, 3 * S)  # now a turn downward
    onsets = engine.tick(3 * S + 1).saccades
    assert onsets.to_pitch_deg[onsets.kind == HEAD][0] == pytest.approx(-14.0)


def test_same_seed_and_events_give_the_identical_trajectory(params: GazeParams) -> None:
    def trajectory(seed: int) -> np.ndarray:
        engine = GazeEngine(50, seed=seed, params=params)
        rows = []
        for frame in range(1, 600):
            t = frame * S // 60
            if frame == 100:
                engine.set_role(np.arange(0, 50, 2), "talking", t - 5)
            if frame == 250:
                engine.set_emotion(3, "disappointed", 0.8, t)
                engine.set_head(4, 30.0, 0.0, t)
            tick = engine.tick(t)
            rows.append(np.concatenate([tick.yaw_deg, tick.pitch_deg, tick.lid]))
        return np.array(rows)

    first = trajectory(21)
    np.testing.assert_array_equal(first, trajectory(21))
    assert not np.array_equal(first, trajectory(22))


def test_engine_saccades_land_exactly_on_target(params: GazeParams) -> None:
    engine = GazeEngine(200, seed=15, params=params)
    engine.set_role(np.arange(200), "talking", 0)
    onsets = engine.tick(S).saccades
    for k in range(0, len(onsets), 37):
        end_ns = int(onsets.onset_ns[k] + round(onsets.duration_s[k] * S))
        landed = eye_position_at(
            end_ns,
            onsets.onset_ns[k],
            (onsets.from_yaw_deg[k], onsets.from_pitch_deg[k]),
            (onsets.to_yaw_deg[k], onsets.to_pitch_deg[k]),
            onsets.duration_s[k],
        )
        assert tuple(landed) == (onsets.to_yaw_deg[k], onsets.to_pitch_deg[k])


@pytest.mark.parametrize("mode", EYES_ALIVE_MODES)
@pytest.mark.parametrize(("role", "rate"), [("talking", 26.0), ("listening", 26.0), ("silence", 17.0)])
def test_blink_rates_by_role(params: GazeParams, role: str, rate: float, mode: str) -> None:
    n, minutes = 4_000, 2.0
    engine = GazeEngine(n, seed=16, params=params, mode=mode)
    engine.set_role(np.arange(n), role, 0)
    blinks = sum(len(engine.tick(t).blinks) for t in range(S, int(minutes * 60) * S + 1, S))
    assert blinks / (n * minutes) == pytest.approx(rate, rel=0.02)


def test_large_saccades_carry_more_blinks(params: GazeParams) -> None:
    engine = GazeEngine(5_000, seed=17, params=params)
    engine.set_role(np.arange(5_000), "talking", 0)
    onset_pairs, blink_pairs = [], []
    for t in range(S, 30 * S + 1, S):
        tick = engine.tick(t)
        onset_pairs.append(np.stack([tick.saccades.agent, tick.saccades.onset_ns, tick.saccades.amplitude_deg]))
        blink_pairs.append(np.stack([tick.blinks.agent, tick.blinks.onset_ns]))
    saccades = np.concatenate(onset_pairs, axis=1)
    saccades = saccades[:, saccades[1] > 0]  # two decisions share t = 0 (start-up, then the role)
    blinks = {(int(a), int(t)) for a, t in np.concatenate(blink_pairs, axis=1).T}
    with_blink = np.array([(int(a), int(t)) in blinks for a, t, _ in saccades.T])
    large, small = saccades[2] > 20.0, saccades[2] < 5.0
    assert with_blink[large].mean() > 0.2 and with_blink[small].mean() == 0.0


def test_adding_an_agent_leaves_the_others_unchanged(params: GazeParams) -> None:
    def run(n: int, late_joiner: bool) -> np.ndarray:
        engine = GazeEngine(n, seed=18, params=params)
        engine.set_role(np.arange(3), "talking", 0)
        rows = []
        for frame in range(1, 400):
            if late_joiner and frame == 120:
                assert list(engine.add_agents(2, frame * S // 30)) == [n, n + 1]
            tick = engine.tick(frame * S // 30)
            rows.append(np.concatenate([tick.yaw_deg[:3], tick.pitch_deg[:3], tick.lid[:3]]))
        return np.array(rows)

    alone = run(3, False)
    np.testing.assert_array_equal(alone, run(4, False))
    np.testing.assert_array_equal(alone, run(3, True))


def test_tick_rate_does_not_change_the_trajectory(params: GazeParams) -> None:
    def run(tick_times: list[int]) -> tuple[dict[str, np.ndarray], dict[int, np.ndarray]]:
        engine = GazeEngine(30, seed=19, params=params)
        events = {2 * S + 777: ("talking",), 6 * S + 3: ("listening",)}
        onsets, states = [], {}
        for t in tick_times:
            for when in sorted(events):
                if engine.now_ns < when <= t:
                    engine.set_role(np.arange(30), events[when][0], when)
            tick = engine.tick(t)
            onsets.append(tick.saccades)
            states[t] = np.concatenate([tick.yaw_deg, tick.pitch_deg, tick.lid])
        return _concat(onsets), states

    common = list(range(S // 2, 10 * S + 1, S // 2))
    fine = sorted(set(range(S // 90, 10 * S + 1, S // 90)) | set(common))
    coarse_irregular = sorted(set(common) | {S // 7, 3 * S + 1, 7 * S + 999_999})
    onsets_fine, states_fine = run(fine)
    onsets_coarse, states_coarse = run(coarse_irregular)
    for name in onsets_fine:
        np.testing.assert_array_equal(onsets_fine[name], onsets_coarse[name], err_msg=name)
    for t in common:
        np.testing.assert_array_equal(states_fine[t], states_coarse[t])


def test_eye_modes(params: GazeParams) -> None:
    engine = GazeEngine(4, seed=20, params=params, mode="saccade+blink")
    assert engine.mode_of(0) == "saccade+blink"
    assert GazeEngine(1, seed=20, params=params).mode_of(0) == params.default_mode == "saccade+noise+blink"
    engine.set_mode(0, "static", 0)
    engine.set_mode(1, "noise", 0)
    engine.set_mode(2, "saccade", 0)
    engine.set_target(0, 5.0, -2.0, 0)
    ticks, yaw, lid = [], [], []
    for t in range(S // 30, 20 * S, S // 30):
        ticks.append(engine.tick(t))
        yaw.append(ticks[-1].yaw_deg.copy())  # a tick's arrays are views, valid until the next tick
        lid.append(ticks[-1].lid.copy())
    yaw, lid = np.array(yaw), np.array(lid)
    agents_with_onsets = set(np.concatenate([t.saccades.agent[t.saccades.onset_ns > 0] for t in ticks]).tolist())
    assert agents_with_onsets == {2, 3}
    assert np.all(yaw[:, 0] == 5.0) and np.all(lid[:, 0] == 0.0)
    assert np.ptp(yaw[:, 1]) > 2.0 and len(np.unique(np.round(yaw[:, 1], 6))) > 500
    times_s = np.arange(S // 30, 20 * S, S // 30) * 1e-9
    expected_lid = np.array([perlin_blink(t, engine._seed_perlin_blink, np.uint64([2]))[0] for t in times_s])
    np.testing.assert_array_equal(lid[:, 2], expected_lid)
    blink_agents = set(np.concatenate([t.blinks.agent for t in ticks]).tolist())
    assert blink_agents == {3} and lid[:, 3].max() > 0.9
    # Switching at run time: static -> saccade+blink decides a saccade at the switch time.
    engine.set_mode(0, "saccade+blink", 20 * S + 5)
    onsets = engine.tick(20 * S + 10).saccades
    assert 0 in onsets.agent[onsets.onset_ns == 20 * S + 5]


def test_target_defines_mutual_gaze(params: GazeParams) -> None:
    engine = GazeEngine(300, seed=21, params=params)
    engine.set_target(np.arange(300), 12.0, 4.0, 0)
    onsets = _concat(_run(engine, 20 * S, S))
    onsets = {name: column[onsets["onset_ns"] > 0] for name, column in onsets.items()}
    mutual = onsets["kind"] == MUTUAL
    assert np.all(onsets["to_yaw_deg"][mutual] == 12.0) and np.all(onsets["to_pitch_deg"][mutual] == 4.0)
    away = onsets["kind"] == AWAY
    offsets = np.hypot(onsets["to_yaw_deg"][away] - 12.0, onsets["to_pitch_deg"][away] - 4.0)
    assert np.median(np.abs(offsets - onsets["magnitude_deg"][away])) < 1e-9


@pytest.mark.parametrize("mode", EYES_ALIVE_MODES)
def test_emotion_shifts_mutual_gaze_with_intensity(params: GazeParams, mode: str) -> None:
    n = 20_000
    fractions = []
    for intensity in (0.0, 0.5, 1.0):
        engine = GazeEngine(n, seed=22, params=params, mode=mode)
        engine.set_emotion(np.arange(n), "angry", intensity, 0)
        engine.set_role(np.arange(n), "talking", 0)
        kinds = _eyes_alive(_concat(_run(engine, 6 * S, 3 * S)), after_ns=0)["kind"]
        fractions.append(100.0 * np.mean(kinds == MUTUAL))
    assert fractions == pytest.approx([41.0, 53.5, 66.0], abs=1.0)
    assert params.emotion("half-angry").mutual_shift == pytest.approx(0.5 * params.emotion("angry").mutual_shift)


def test_invalid_names_list_the_valid_ones(params: GazeParams) -> None:
    engine = GazeEngine(2, seed=0, params=params)
    with pytest.raises(ValueError, match="talking, listening, silence"):
        engine.set_role(0, "shouting", 0)
    with pytest.raises(ValueError, match="static, noise, saccade, saccade\\+blink"):
        engine.set_mode(0, "blinky", 0)
    with pytest.raises(ValueError, match="natural, happy"):
        engine.set_emotion(0, "bored", 1.0, 0)
    with pytest.raises(ValueError, match="intensity"):
        engine.set_emotion(0, "happy", 1.5, 0)
    with pytest.raises(ValueError, match="out of range"):
        engine.set_role(2, "talking", 0)
    with pytest.raises(ValueError, match="finite"):
        engine.set_target(0, float("nan"), 0.0, 0)
    engine.tick(S)
    with pytest.raises(ValueError, match="before the previous tick"):
        engine.tick(S - 1)


def test_disappointed_gaze_drops(params: GazeParams) -> None:
    def share_down(emotion: str) -> float:
        n = 10_000
        engine = GazeEngine(n, seed=23, params=params, role="talking")
        engine.set_emotion(np.arange(n), emotion, 1.0, 0)
        onsets = _concat(_run(engine, 20 * S, 5 * S))
        away = (onsets["kind"] == AWAY) & (onsets["onset_ns"] > 0)
        angle = np.mod(np.rad2deg(np.arctan2(onsets["to_pitch_deg"][away], onsets["to_yaw_deg"][away])), 360.0)
        return float(np.mean(np.abs(angle - 270.0) < 1e-6))

    natural, disappointed = share_down("natural"), share_down("disappointed")
    assert abs(natural - 0.2038) < 0.01  # the table's 20.38% downward
    assert disappointed > natural + 0.15


@pytest.mark.parametrize("mode", EYES_ALIVE_MODES)
def test_eye_state_follows_the_latest_onsets(params: GazeParams, mode: str) -> None:
    """The eye state a tick hands out (kept from tick to tick and rewritten only where it changes) is where
    each agent's latest reported saccade puts the eye, and the lid its latest blink; through role changes,
    head turns, long and short steps, and blinks cancelled by a mode switch. A small saccade (scan,
    microsaccade) moves the eye state to its landing at its onset; the others follow their trajectory."""
    n = 120
    engine = GazeEngine(n, seed=31, params=params, role="talking", mode=mode)
    rng = np.random.default_rng(5)
    small = np.zeros(n, dtype=bool)
    onset = np.zeros(n, dtype=np.int64)
    from_deg, to_deg, duration = np.zeros((n, 2)), np.zeros((n, 2)), np.ones(n)
    last_blink = np.full(n, -(10**18))
    static = np.arange(15)
    t, lids_seen, cancelled = 0, 0, 0
    for step in range(700):
        event_t = t + 1
        if step == 250:
            engine.set_mode(static, "static", event_t)
            last_blink[static] = -(10**18)  # blinks in progress are cancelled
        if step == 450:
            engine.set_mode(static, mode, event_t)
        if step % 40 == 20:
            engine.set_role(rng.choice(n, 30, replace=False), ["listening", "talking", "silence"][step % 3], event_t)
        if step % 60 == 30:
            engine.set_head(rng.choice(n, 30, replace=False), rng.uniform(-40, 40), rng.uniform(-20, 20), event_t)
        t += int(rng.choice([S // 240, S // 60, S // 60, S // 7, 3 * S // 2]))
        tick = engine.tick(t)
        s = tick.saccades
        for k in range(len(s)):  # sorted by onset: the last one of an agent is its latest
            a = s.agent[k]
            onset[a], duration[a], small[a] = s.onset_ns[k], s.duration_s[k], s.kind[k] >= SCAN
            from_deg[a] = s.from_yaw_deg[k], s.from_pitch_deg[k]
            to_deg[a] = s.to_yaw_deg[k], s.to_pitch_deg[k]
        for a, b in zip(tick.blinks.agent, tick.blinks.onset_ns, strict=True):
            last_blink[a] = b
        expected = eye_position_at(t, onset, from_deg, to_deg, duration)
        expected[small] = to_deg[small]
        saccading = np.ones(n, dtype=bool)
        if 250 <= step < 450:
            saccading[static] = False
            assert np.all(tick.yaw_deg[static] == 0.0) and np.all(tick.lid[static] == 0.0)
        np.testing.assert_allclose(tick.yaw_deg[saccading], expected[saccading, 0], rtol=0, atol=1e-9)
        np.testing.assert_allclose(tick.pitch_deg[saccading], expected[saccading, 1], rtol=0, atol=1e-9)
        lid = lid_closure((t - last_blink) * 1e-9, params.blink)
        np.testing.assert_allclose(tick.lid[saccading], lid[saccading], rtol=0, atol=1e-12)
        lids_seen += np.count_nonzero(lid)
        if step == 249:
            cancelled = np.count_nonzero(tick.lid[static])  # blinks in progress at the switch to static
    assert lids_seen > 1000 and cancelled > 0
    with pytest.raises(ValueError):
        tick.yaw_deg[0] = 1.0  # a tick hands out read-only views of the engine's eye state


@pytest.mark.parametrize(
    ("curve_s", "closure"),
    [([0.0, 0.05, 0.2, 0.25], [0.0, 1.0, 0.33, 0.0]), ([0.01, 0.03, 0.03, 0.1, 0.3], [0.2, 1.0, 0.9, 0.5, 0.1])],
)
def test_lids_of_blinks_in_progress_follow_the_curve_piece_by_piece(curve_s: list[float], closure: list[float]) -> None:
    """The lids of a whole window of blinks, computed a straight piece at a time, are the curve's values
    (np.interp, with 0 before it starts) at every elapsed time, knots and the curve's very end included."""
    n = 400
    blinks = LiveBlinks(np.array(curve_s), np.array(closure), n)
    t = 10 * S
    end_ns = round(curve_s[-1] * S)
    knots = [t - round(k * S) for k in curve_s]
    rng = np.random.default_rng(4)
    onsets = np.sort(np.concatenate([rng.integers(t - end_ns, t + 1, n - len(knots)), knots]))
    lid = np.full(n + 1, -1.0)
    blinks.update(t, lid, np.arange(n), onsets)
    curve_ns = np.array(curve_s) * 1e9  # in nanoseconds, so the curve's end is exactly representable
    expected = np.interp((t - onsets).astype(float), curve_ns, closure, left=0.0, right=0.0)
    np.testing.assert_allclose(lid[:n], expected, rtol=0, atol=1e-12)


def test_events_stamped_out_of_order_between_ticks_divide_by_no_zero(params: GazeParams) -> None:
    """A mode switch stamped ahead of the last tick leaves a zero-length fixation starting in the future; an
    event stamped before it asks where the eye is then. No division by zero, and the eye is where the static
    mode put it (the gaze target) when the return to saccades launches the next one."""
    engine = GazeEngine(2, seed=1, params=params, role="talking")
    engine.tick(1 * S)
    engine.set_mode([0], "static", 5 * S)
    with np.errstate(all="raise"):
        engine.set_mode([0], "saccade", 4 * S)
        onsets = engine.tick(4 * S).saccades
    launched = np.flatnonzero((onsets.agent == 0) & (onsets.onset_ns == 4 * S))
    assert launched.size == 1
    assert (onsets.from_yaw_deg[launched[0]], onsets.from_pitch_deg[launched[0]]) == (0.0, 0.0)
