"""Situated gaze among several agents and the user: who looks at whom, measured on the gaze engine against
Vertegaal et al. 2001's proportions and Kendon 1967's turn pattern (configs/conversation.toml)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from eca.agent.gaze.engine import KIND, MUTUAL, TARGET_PITCH, TARGET_YAW, GazeEngine
from eca.agent.gaze.situated import USER, Conversation, GazeShift, HeadTurn, LookAt, SituatedParams, apply

S = 1_000_000_000
AGENTS = ("ada", "bob", "cy")


@pytest.fixture(scope="module")
def params() -> SituatedParams:
    return SituatedParams.load()


def test_shipped_proportions_are_vertegaals(params: SituatedParams) -> None:
    assert (params.listener_at_speaker, params.speaker_at_addressee) == (0.88, 0.77)  # Vertegaal et al. 2001
    assert params.user_direction_deg == (0.0, 0.0)  # the user at the camera


def test_seats_face_the_user_and_look_toward_each_others_faces(params: SituatedParams) -> None:
    talk = Conversation(AGENTS, seed=0, params=params)
    assert talk.direction("ada", USER) == (0.0, 0.0)
    # ada is drawn leftmost: bob and cy are to the viewer's right, so to ada's left (negative yaw).
    assert talk.direction("ada", "bob") == (-params.neighbour_yaw_deg, 0.0)
    assert talk.direction("ada", "cy") == (-min(2 * params.neighbour_yaw_deg, params.max_neighbour_yaw_deg), 0.0)
    assert talk.direction("cy", "bob") == (params.neighbour_yaw_deg, 0.0)


def test_alone_with_the_user_nothing_changes(params: SituatedParams) -> None:
    talk = Conversation(("ada",), seed=0, params=params)
    actions = talk.start_turn(0, USER, duration_s=3.0) + talk.start_turn(3 * S, None)
    assert actions == []  # no targets to choose among, no head to turn


def test_weights_follow_who_speaks_to_whom(params: SituatedParams) -> None:
    talk = Conversation(AGENTS, seed=0, params=params)
    looks = {a.agent: a for a in talk.start_turn(0, "bob", ("ada",), duration_s=1.0) if isinstance(a, LookAt)}
    ada = dict(zip(looks["ada"].names, looks["ada"].weights, strict=True))
    assert ada["bob"] == pytest.approx(0.88) and ada["cy"] == ada[USER] == pytest.approx(0.06)
    bob = dict(zip(looks["bob"].names, looks["bob"].weights, strict=True))
    assert bob["ada"] == pytest.approx(0.77) and bob["cy"] == bob[USER] == pytest.approx(0.115)
    looks = {a.agent: a for a in talk.start_turn(S, USER, duration_s=1.0) if isinstance(a, LookAt)}
    assert dict(zip(looks["cy"].names, looks["cy"].weights, strict=True))[USER] == pytest.approx(0.88)
    with pytest.raises(ValueError, match="unknown speaker"):
        talk.start_turn(2 * S, "dora")
    with pytest.raises(ValueError, match="addressees"):
        talk.start_turn(2 * S, "ada", ("ada",))


def test_the_head_turns_a_little_and_the_eyes_do_the_rest(params: SituatedParams) -> None:
    talk = Conversation(AGENTS, seed=0, params=params)
    actions = talk.start_turn(0, "cy", duration_s=1.0)
    heads = {a.agent: a for a in actions if isinstance(a, HeadTurn)}
    looks = {a.agent: a for a in actions if isinstance(a, LookAt)}
    toward = talk.direction("bob", "cy")[0]
    assert 0 < abs(heads["bob"].yaw_deg) < abs(toward)
    assert math.copysign(1, heads["bob"].yaw_deg) == math.copysign(1, toward)
    eyes = dict(zip(looks["bob"].names, looks["bob"].yaw_deg, strict=True))["cy"]
    assert heads["bob"].yaw_deg + eyes == pytest.approx(toward)  # head + eyes = the direction of the speaker
    assert abs(eyes) <= params.eye_comfort_deg + 1e-9


def _run_groups(params: SituatedParams, groups: int, turns: int, seed: int) -> dict[str, float]:
    """`groups` conversations of three agents on one engine, turn after turn (speakers and addressees drawn),
    sampled every frame: each listener's share of mutual-gaze time on the speaker, and each speaker's on its
    addressee."""
    engine = GazeEngine(3 * groups, seed=seed, mode="saccade+noise+blink")
    talks = [Conversation(AGENTS, seed=seed * 1000 + g, params=params) for g in range(groups)]
    index = [{a: 3 * g + k for k, a in enumerate(AGENTS)} for g in range(groups)]
    rng = np.random.default_rng(seed)
    t = 0
    listened = np.zeros(2)  # frames (on the speaker, in mutual gaze) of listeners
    spoken = np.zeros(2)  # frames (on the addressee, in mutual gaze) of speakers
    for _ in range(turns):
        length_s = float(rng.uniform(3.0, 8.0))
        turn = []
        for g, talk in enumerate(talks):
            people = (*AGENTS, USER)
            speaker = people[int(rng.integers(len(people)))]
            addressee = [p for p in people if p != speaker][int(rng.integers(3))]
            engine.set_role([index[g][a] for a in AGENTS if a != speaker], "listening", t)
            if speaker != USER:
                engine.set_role(index[g][speaker], "talking", t)
            apply(engine, talk.start_turn(t, speaker, (addressee,), duration_s=length_s), index[g])
            turn.append((speaker, addressee))
        end = t + round(length_s * S)
        for frame_t in range(t + S // 30, end, S // 30):
            for g, talk in enumerate(talks):
                apply(engine, talk.due(frame_t), index[g])
            engine.tick(frame_t)
            rows = engine._rows.view(np.float64)
            kinds = engine._rows[:, KIND]
            for g, talk in enumerate(talks):
                speaker, addressee = turn[g]
                for agent in AGENTS:
                    i = index[g][agent]
                    if kinds[i] != MUTUAL:
                        continue
                    at = (rows[i, TARGET_YAW], rows[i, TARGET_PITCH])
                    person = next(p for p in talk.people if p != agent and _aimed(talk, agent, p, at))
                    if agent == speaker:
                        spoken += (person == addressee, 1)
                    else:
                        listened += (person == speaker, 1)
        t = end
    return {"listener": listened[0] / listened[1], "speaker": spoken[0] / spoken[1]}


def _aimed(talk: Conversation, agent: str, person: str, at: tuple[float, float]) -> bool:
    head = talk.head[agent]
    yaw, pitch = talk.direction(agent, person)
    target = (max(-30.0, min(30.0, yaw - head[0])), max(-30.0, min(30.0, pitch - head[1])))
    return abs(target[0] - at[0]) < 1e-9 and abs(target[1] - at[1]) < 1e-9


def test_listeners_look_at_the_speaker_and_speakers_at_their_addressee(params: SituatedParams) -> None:
    shares = _run_groups(params, groups=60, turns=14, seed=5)
    assert shares["listener"] == pytest.approx(params.listener_at_speaker, abs=0.03)
    assert shares["speaker"] == pytest.approx(params.speaker_at_addressee, abs=0.04)


def test_a_long_turn_starts_looking_away_and_ends_looking_back(params: SituatedParams) -> None:
    starts = backs = 0
    n = 2_000
    for k in range(n):
        talk = Conversation(AGENTS, seed=k, params=params)
        actions = talk.start_turn(0, "ada", duration_s=5.0)
        starts += any(isinstance(a, GazeShift) and a.toward == "away" for a in actions)
        later = talk.due(10 * S)
        backs += any(isinstance(a, GazeShift) and a.toward == "mutual"
                     and a.t_ns == round((5.0 - params.look_back_lead_s) * S) for a in later)
    for count, p in ((starts, params.look_away_at_start), (backs, params.look_back_at_end)):
        assert abs(count / n - p) < 4 * math.sqrt(p * (1 - p) / n)
    short = Conversation(AGENTS, seed=1, params=params)
    assert not any(isinstance(a, GazeShift) for a in short.start_turn(0, "ada", duration_s=1.0) + short.due(S))
    interrupted = Conversation(AGENTS, seed=3, params=params)
    interrupted.start_turn(0, "ada", duration_s=5.0)
    interrupted.start_turn(S, "bob", duration_s=1.0)  # a new turn cancels ada's look back
    assert not [a for a in interrupted.due(10 * S) if a.agent == "ada"]


def test_a_live_turn_of_unknown_length_looks_back_when_it_ends(params: SituatedParams) -> None:
    backs, n = 0, 2_000
    for k in range(n):
        talk = Conversation(AGENTS, seed=k, params=params)
        talk.start_turn(0, "ada")  # live: its length is not known
        assert talk.due(60 * S) == []  # nothing is scheduled ahead
        ended = talk.end_turn(7 * S)
        assert talk.end_turn(8 * S) == []  # once
        backs += any(isinstance(a, GazeShift) and a.toward == "mutual" and a.t_ns == 7 * S and a.agent == "ada"
                     for a in ended)
    p = params.look_back_at_end
    assert abs(backs / n - p) < 4 * math.sqrt(p * (1 - p) / n)
    talk = Conversation(AGENTS, seed=0, params=params)
    for k in range(50):  # a new turn drops what the last one would have done at its end
        talk = Conversation(AGENTS, seed=k, params=params)
        talk.start_turn(0, "ada")
        talk.start_turn(S, "bob", duration_s=1.0)
        assert not [a for a in talk.end_turn(2 * S) if a.agent == "ada"]


def test_the_floor_follows_the_roles_as_the_dialogue_states_say_them() -> None:
    from eca.agent.gaze.situated import Floor

    floor = Floor(AGENTS)
    first = floor.update("ada", "listening", "user", ())
    assert first.turn == ("user", ()) and first.talking is None
    assert floor.update("bob", "listening", "user", ()).turn is None  # the same floor: no new turn
    talk = floor.update("ada", "talking", "ada", ("bob", "zed", "ada"))
    assert talk.talking is True and talk.turn == ("ada", ("bob",)) and talk.previous_speaker == "user"
    over = floor.update("bob", "talking", "bob", ())  # bob talks over her: the latest to start holds it
    assert over.turn == ("bob", ()) and over.previous_speaker == "ada"
    assert floor.update("ada", "listening", "bob", ()).talking is False  # ada stops: still bob's floor
    done = floor.update("bob", "silence", "", ())
    assert done.talking is False and done.turn is None and floor.turn == ("bob", ())  # ada, listening, names bob
    assert floor.update("ada", "listening", "zed", ()).turn == ("user", ())  # off screen: with the user
    assert floor.update("ada", "silence", "", ()).turn == (None, ())  # nobody named: a silence


def test_a_live_change_of_floor_ends_the_last_speaker_s_turn_first(params: SituatedParams) -> None:
    from eca.agent.gaze.situated import Floor, take_floor

    backs = 0
    for k in range(200):
        talk, floor = Conversation(AGENTS, seed=k, params=params), Floor(AGENTS)
        take_floor(talk, 0, floor.update("ada", "talking", "ada", ()))
        ended = take_floor(talk, 5 * S, floor.update("ada", "listening", "user", ()))
        backs += any(isinstance(a, GazeShift) and a.agent == "ada" and a.toward == "mutual" and a.t_ns == 5 * S
                     for a in ended)
        assert take_floor(talk, 6 * S, floor.update("ada", "listening", "user", ())) == []
    assert 0.55 < backs / 200 < 0.85  # look_back_at_end 0.7
