"""Listener backchannels (agent/gaze/backchannel.py) and the pauses they answer (agent/lipsync/pauses.py)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from eca.agent.config import ConfigError
from eca.agent.gaze.backchannel import USER, Backchannel, BackchannelParams, ListenerBlink, Nod
from eca.agent.lipsync.pauses import speech_segments

NS = 1_000_000_000
PARAMS = BackchannelParams.load()


def _user_talks(model: Backchannel, pauses: int, speech_s: float = 2.0, pause_s: float = 1.5) -> list:
    """The user speaks `pauses` stretches of `speech_s`, each followed by a pause; returns every action."""
    actions, t = [], 0
    for _ in range(pauses):
        model.speaking(t, USER, True)
        t += round(speech_s * NS)
        model.speaking(t, USER, False)
        t += round(pause_s * NS)
        actions += model.due(t)
    return actions


def _rates(params: BackchannelParams, pauses: int = 3000) -> tuple[float, float, list, list]:
    model = Backchannel(["ada", "bob"], seed=11, params=params)
    actions = _user_talks(model, pauses)
    nods = [a for a in actions if isinstance(a, Nod) and a.agent == "ada"]
    blinks = [a for a in actions if isinstance(a, ListenerBlink) and a.agent == "ada"]
    return len(nods) / pauses, len(blinks) / pauses, nods, blinks


def _tolerance(p: float, n: int) -> float:
    return 4.0 * (p * (1 - p) / n) ** 0.5


def test_each_listener_nods_and_blinks_at_the_configured_share_of_pauses() -> None:
    nod_rate, blink_rate, _, _ = _rates(PARAMS)
    assert abs(nod_rate - PARAMS.nod_probability) < _tolerance(PARAMS.nod_probability, 3000)
    assert abs(blink_rate - PARAMS.blink_probability) < _tolerance(PARAMS.blink_probability, 3000)


def test_a_wrong_probability_in_the_config_is_seen_in_the_rates() -> None:
    wrong = dataclasses.replace(PARAMS, nod_probability=PARAMS.nod_probability + 0.1)
    nod_rate, _, _, _ = _rates(wrong)
    assert abs(nod_rate - PARAMS.nod_probability) > _tolerance(PARAMS.nod_probability, 3000)


def test_delays_amplitudes_and_durations_cover_their_configured_ranges() -> None:
    _, _, nods, blinks = _rates(PARAMS, pauses=2000)
    cycle = round(3.5 * NS)  # speech 2 s + pause 1.5 s
    nod_delay = np.array([(n.t_ns - 2 * NS) % cycle for n in nods]) / NS
    blink_delay = np.array([(b.t_ns - 2 * NS) % cycle for b in blinks]) / NS
    for values, (lo, hi) in ((nod_delay, PARAMS.nod_delay_s), (blink_delay, PARAMS.blink_delay_s),
                             (np.array([n.amplitude_deg for n in nods]), PARAMS.nod_amplitude_deg),
                             (np.array([n.duration_s for n in nods]), PARAMS.nod_duration_s)):
        assert values.min() >= lo - 1e-9 and values.max() <= hi + 1e-9
        # uniform over the range: the median sits in its middle, both ends are reached
        assert abs(np.median(values) - (lo + hi) / 2) < 0.06 * (hi - lo) + 1e-9
        assert values.min() < lo + 0.05 * (hi - lo) + 1e-9 and values.max() > hi - 0.05 * (hi - lo) - 1e-9


def test_short_speech_and_quick_successive_pauses_are_not_answered() -> None:
    model = Backchannel(["ada"], seed=3, params=dataclasses.replace(PARAMS, nod_probability=1.0,
                                                                     blink_probability=1.0))
    model.speaking(0, USER, True)
    model.speaking(round((PARAMS.min_speech_s - 0.05) * NS), USER, False)  # too little speech
    assert model.due(10 * NS) == [] and model.opportunities == 0
    t = 10 * NS
    model.speaking(t, USER, True)
    model.speaking(t + 2 * NS, USER, False)  # answered
    first = model.due(t + 5 * NS)
    assert {type(a) for a in first} == {Nod, ListenerBlink}
    # another speaker's pause within the refractory time of that response is not answered by ada ...
    model2 = Backchannel(["ada", "bob"], seed=3, params=model.params)
    model2.speaking(0, USER, True)
    model2.speaking(NS, "bob", True)  # bob talks over the end of the user's stretch
    model2.speaking(2 * NS, USER, False)  # ada (not bob, who speaks) responds
    model2.speaking(2 * NS + round((PARAMS.refractory_s - 0.05) * NS), "bob", False)
    assert model2.opportunities == 2
    assert {a.agent for a in model2.due(5 * NS)} == {"ada"} and len(model2.due(99 * NS)) == 0
    # ... and one after it is
    model2.speaking(6 * NS, "bob", True)
    model2.speaking(8 * NS, "bob", False)
    assert {a.agent for a in model2.due(10 * NS)} == {"ada"}


def test_an_agent_never_backchannels_while_it_speaks() -> None:
    always = dataclasses.replace(PARAMS, nod_probability=1.0, blink_probability=1.0)
    model = Backchannel(["ada", "bob"], seed=5, params=always)
    model.speaking(0, "bob", True)
    model.speaking(0, USER, True)
    model.speaking(2 * NS, USER, False)  # bob is speaking: only ada responds
    model.speaking(2 * NS, "ada", False)  # (ada was not speaking: nothing)
    due = model.due(4 * NS)
    assert due and {a.agent for a in due} == {"ada"}
    model.speaking(5 * NS, USER, True)
    model.speaking(7 * NS, USER, False)  # ada's responses are pending ...
    model.speaking(7 * NS + 1, "ada", True)  # ... and ada takes the turn before they are due
    assert [a for a in model.due(9 * NS) if a.agent == "ada"] == []
    # the speaker's own pauses never make it respond to itself
    model.speaking(10 * NS, "ada", False)
    assert all(a.agent == "bob" or a.agent != "ada" for a in model.due(12 * NS))


def test_the_same_seed_gives_the_same_backchannels() -> None:
    runs = [_user_talks(Backchannel(["ada", "bob", "cy"], seed=9), 50) for _ in range(2)]
    assert runs[0] == runs[1] and runs[0]
    assert _user_talks(Backchannel(["ada", "bob", "cy"], seed=10), 50) != runs[0]


def test_bad_speakers_and_configs_are_named() -> None:
    with pytest.raises(ValueError, match="unknown speaker 'zed'"):
        Backchannel(["ada"], seed=0).speaking(0, "zed", True)
    with pytest.raises(ValueError, match="distinct agents"):
        Backchannel(["ada", "ada"], seed=0)


def test_a_bad_config_is_named(tmp_path) -> None:
    bad = tmp_path / "bc.toml"
    bad.write_text((__import__("eca.agent.config", fromlist=["config_path"]).config_path("backchannel"))
                   .read_text().replace("probability = 0.35", "probability = 1.5"))
    with pytest.raises(ConfigError, match=r"\[nod\]: 'probability' must be in \[0, 1\]"):
        BackchannelParams.load(str(bad))
    bad.write_text(bad.read_text().replace("probability = 1.5", "probability = 0.3")
                   .replace("delay_s = [0.2, 0.6]", "delay_s = [0.6, 0.2]"))
    with pytest.raises(ConfigError, match="'delay_s' must be \\[low, high\\]"):
        BackchannelParams.load(str(bad))


def _voice(rate: int, plan: list[tuple[str, float]], seed: int = 1) -> tuple[np.ndarray, list[tuple[float, float]]]:
    """Speech-like bursts (noise in a syllable envelope) and silences; returns the samples and the speech
    stretches by construction."""
    rng = np.random.default_rng(seed)
    parts, spans, t = [], [], 0.0
    for kind, seconds in plan:
        n = round(seconds * rate)
        if kind == "speech":
            envelope = 0.55 + 0.45 * np.sin(2 * np.pi * 4.0 * np.arange(n) / rate) ** 2  # ~8 syllables/s
            parts.append(0.3 * envelope * rng.standard_normal(n))
            spans.append((t, t + seconds))
        else:
            parts.append(1e-4 * rng.standard_normal(n))
        t += seconds
    return np.concatenate(parts), spans


def test_pauses_split_speech_and_short_closures_do_not() -> None:
    rate = 16_000
    samples, spans = _voice(rate, [("speech", 1.2), ("silence", 0.08), ("speech", 0.6), ("silence", 0.5),
                                   ("speech", 0.9), ("silence", 0.3)])
    got = speech_segments(samples, rate, min_pause_s=0.25)
    assert len(got) == 2  # the 80 ms closure stays inside the first stretch
    (a0, b0), (a1, b1) = got
    assert abs(a0 - spans[0][0]) < 0.02 and abs(b0 - spans[1][1]) < 0.02
    assert abs(a1 - spans[2][0]) < 0.02 and abs(b1 - spans[2][1]) < 0.02
    # a longer minimum pause merges them; int16 input gives the same answer
    assert len(speech_segments(samples, rate, min_pause_s=0.6)) == 1
    as_int16 = np.round(samples * 32767).astype(np.int16)
    again = speech_segments(as_int16, rate, min_pause_s=0.25)
    assert np.allclose(np.array(again), np.array(got), atol=0.011)
    assert speech_segments(np.zeros(5), rate, 0.25) == []
