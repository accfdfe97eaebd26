"""Situated gaze in a multi-party conversation: who looks at whom, turn by turn.

The agents of one instance sit side by side facing the user, as their faces are drawn, and the user sits
in front of them at the camera (configs/conversation.toml [seats]). At every turn — someone
starts speaking to someone, or a silence begins — a `Conversation` decides for each agent which people
its gaze goes to and with what weights (Vertegaal et al. 2001: listeners look at the speaker, speakers at
their addressees), turns its head a little toward the person it attends, and, for the speaker of a long
turn, looks away as the turn starts and back at the listener near its end (Kendon 1967). It says so in
actions for the gaze engine (`GazeEngine.set_targets`, `shift_gaze`) and the face (a head turn), each at
its time; `apply` hands them to an engine. The Eyes Alive decisions themselves (when to look away, how
far, how long) stay the engine's: a person chosen here is where each mutual decision aims.

Angles are in an agent's frame: yaw + toward its right, pitch + up, 0 straight ahead of its body (toward
the user). The head turn is relative to the body; eye targets are relative to the head. Looking at the
user looks into the camera; a look at another agent turns toward its face on the screen. With one agent
alone every angle is 0, and nothing changes from a dyad.

Pure Python and deterministic: the random draws come from the counter-based stream of the seed.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from eca.agent.config import ConfigError, load_toml, require
from eca.agent.counter_rng import uniform01
from eca.agent.face.settings import load_flexor_units

USER = "user"
_NS = 1_000_000_000


@dataclass(frozen=True)
class SituatedParams:
    """The constants of configs/conversation.toml (their sources are named there)."""

    neighbour_yaw_deg: float
    max_neighbour_yaw_deg: float
    user_direction_deg: tuple[float, float]  # yaw, pitch of the user from every agent
    listener_at_speaker: float
    speaker_at_addressee: float
    long_turn_s: float
    look_away_at_start: float
    look_back_at_end: float
    look_back_lead_s: float
    head_share: float
    eye_comfort_deg: float
    head_turn_s: float
    head_limits_deg: tuple[float, float]  # turn, nod (configs/flexor_units.toml [head])

    def direction(self, agents: Sequence[str], agent: str, person: str) -> tuple[float, float]:
        """Where `person` (USER, or one of `agents`, the instance's in seat order) is seen from `agent`, relative
        to its body (which faces the user): the user where [seats] puts it, another agent toward its face on the
        screen (a face further right on the screen is to the agent's left: negative yaw)."""
        if person == USER:
            return self.user_direction_deg
        apart = agents.index(person) - agents.index(agent)
        yaw = min(abs(apart) * self.neighbour_yaw_deg, self.max_neighbour_yaw_deg)
        return (-math.copysign(yaw, apart), 0.0)

    @classmethod
    def load(cls, name: str = "conversation", units: str = "flexor_units") -> SituatedParams:
        doc, where = load_toml(name), f"configs/{name}.toml" if not name.endswith(".toml") else name
        head_units = load_flexor_units(units)
        sections = {key: require(doc, key, dict, where) for key in ("seats", "gaze", "turns", "head")}
        seats, gaze, turns, head = (sections[k] for k in ("seats", "gaze", "turns", "head"))
        ws = f"{where} [seats]"
        return cls(
            neighbour_yaw_deg=_number(seats, "neighbour_yaw_deg", ws, positive=True),
            max_neighbour_yaw_deg=_number(seats, "max_neighbour_yaw_deg", ws, positive=True),
            user_direction_deg=(_number(seats, "user_yaw_deg", ws), _number(seats, "user_pitch_deg", ws)),
            listener_at_speaker=_share(gaze, "listener_at_speaker", f"{where} [gaze]"),
            speaker_at_addressee=_share(gaze, "speaker_at_addressee", f"{where} [gaze]"),
            long_turn_s=_number(turns, "long_turn_s", f"{where} [turns]", positive=True),
            look_away_at_start=_share(turns, "look_away_at_start", f"{where} [turns]"),
            look_back_at_end=_share(turns, "look_back_at_end", f"{where} [turns]"),
            look_back_lead_s=_number(turns, "look_back_lead_s", f"{where} [turns]", positive=True),
            head_share=_share(head, "share", f"{where} [head]"),
            eye_comfort_deg=_number(head, "eye_comfort_deg", f"{where} [head]", positive=True),
            head_turn_s=_number(head, "turn_s", f"{where} [head]", positive=True),
            head_limits_deg=(head_units.turn_deg, head_units.nod_deg),
        )


def _number(table: dict[str, Any], key: str, where: str, positive: bool = False) -> float:
    value = require(table, key, float, where)
    if not math.isfinite(value) or (positive and value <= 0):
        raise ConfigError(f"{where}: '{key}' must be a finite number{' > 0' if positive else ''}, got {value!r}")
    return float(value)


def _share(table: dict[str, Any], key: str, where: str) -> float:
    value = _number(table, key, where)
    if not 0.0 <= value <= 1.0:
        raise ConfigError(f"{where}: '{key}' must be in [0, 1], got {value!r}")
    return value


@dataclass(frozen=True)
class LookAt:
    """The people an agent's mutual gaze chooses among from `t_ns` on (engine.set_targets): their names, eye
    targets in the agent's head frame (degrees) and weights."""

    t_ns: int
    agent: str
    names: tuple[str, ...]
    yaw_deg: tuple[float, ...]
    pitch_deg: tuple[float, ...]
    weights: tuple[float, ...]


@dataclass(frozen=True)
class GazeShift:
    """The agent's next gaze decision now, toward "mutual" or "away" (engine.shift_gaze)."""

    t_ns: int
    agent: str
    toward: str


@dataclass(frozen=True)
class HeadTurn:
    """The agent's head turns to (yaw, pitch), relative to its body, over `duration_s` from `t_ns`."""

    t_ns: int
    agent: str
    yaw_deg: float
    pitch_deg: float
    duration_s: float


Action = LookAt | GazeShift | HeadTurn


class Conversation:
    """Who looks at whom among `agents` and the user, turn by turn."""

    def __init__(self, agents: Sequence[str], seed: int, params: SituatedParams | None = None) -> None:
        if len(set(agents)) != len(agents) or USER in agents or not agents:
            raise ValueError(f"a conversation needs distinct agents other than '{USER}', got {list(agents)!r}")
        self.params = params if params is not None else SituatedParams.load()
        self.agents = tuple(agents)
        self.people = (*self.agents, USER)
        self.seed = int(seed)
        self._draws = [0] * len(self.agents)
        self._pending: list[Action] = []  # actions later than the turn's start (the look back)
        self._at_end: list[GazeShift] = []  # the look back of a turn of unknown length: when it ends
        self.speaker: str | None = None
        self.head: dict[str, tuple[float, float]] = {a: (0.0, 0.0) for a in self.agents}
        self.attending: dict[str, str] = {a: USER for a in self.agents}

    def direction(self, agent: str, person: str) -> tuple[float, float]:
        """Where `person` is seen from `agent` (SituatedParams.direction)."""
        return self.params.direction(self.agents, agent, person)

    def start_turn(self, t_ns: int, speaker: str | None, addressees: Sequence[str] = (),
                   duration_s: float | None = None) -> list[Action]:
        """`speaker` (an agent or the user) starts speaking to `addressees` (default: everyone else) at
        `t_ns`, for `duration_s` if known; None: a silence begins. Returns the actions due now; later ones
        (a speaker looking back near the end) come from `due`. A turn cancels the last one's pending
        actions."""
        if speaker is not None and speaker not in self.people:
            raise ValueError(f"unknown speaker {speaker!r}; the conversation has {', '.join(self.people)}")
        unknown = [a for a in addressees if a not in self.people or a == speaker]
        if unknown:
            raise ValueError(f"addressees must be other participants, got {', '.join(map(repr, unknown))}")
        self._pending.clear()
        self._at_end.clear()
        self.speaker = speaker
        actions: list[Action] = []
        if speaker is None:  # a silence: everyone keeps looking where the last turn left them
            return actions
        spoken_to = tuple(addressees) or tuple(p for p in self.people if p != speaker)
        for agent in self.agents if len(self.agents) > 1 else ():  # alone with the user: nothing to choose
            if agent == speaker:
                weights = self._shares(agent, spoken_to, self.params.speaker_at_addressee)
                attend = spoken_to[0] if len(spoken_to) == 1 else None
            else:
                weights = self._shares(agent, (speaker,), self.params.listener_at_speaker)
                attend = speaker
            actions += self._face(t_ns, agent, attend, weights)
        if speaker in self.agents and (duration_s is None or duration_s >= self.params.long_turn_s):
            k = self.agents.index(speaker)
            if self._draw(k) < self.params.look_away_at_start:
                actions.append(GazeShift(t_ns, speaker, "away"))
            look_back = self._draw(k) < self.params.look_back_at_end
            if look_back and duration_s is not None:
                back_ns = t_ns + round(max(duration_s - self.params.look_back_lead_s, 0.0) * _NS)
                self._pending.append(GazeShift(back_ns, speaker, "mutual"))
            elif look_back:  # live speech: its length is known only when it ends
                self._at_end.append(GazeShift(t_ns, speaker, "mutual"))
        return actions

    def end_turn(self, t_ns: int) -> list[Action]:
        """The speaker of a turn whose length was not known stops at `t_ns`: its look back at the listener
        (drawn when the turn began) happens now, as the speech ends."""
        actions: list[Action] = [GazeShift(t_ns, a.agent, a.toward) for a in self._at_end]
        self._at_end.clear()
        return actions

    def due(self, until_ns: int) -> list[Action]:
        """Pending actions at or before `until_ns`, in time order (taken)."""
        ready = sorted((a for a in self._pending if a.t_ns <= until_ns), key=lambda a: a.t_ns)
        self._pending = [a for a in self._pending if a.t_ns > until_ns]
        return ready

    def _shares(self, agent: str, favoured: Sequence[str], share: float) -> dict[str, float]:
        """Weights over everyone but `agent`: `share` split among `favoured`, the rest among the others (all
        to the favoured when there are no others)."""
        others = [p for p in self.people if p != agent and p not in favoured]
        favoured = [p for p in favoured if p != agent]
        if not others:
            return {p: 1.0 / len(favoured) for p in favoured}
        if not favoured:
            return {p: 1.0 / len(others) for p in others}
        return {**{p: share / len(favoured) for p in favoured}, **{p: (1.0 - share) / len(others) for p in others}}

    def _face(self, t_ns: int, agent: str, attend: str | None, weights: dict[str, float]) -> list[Action]:
        """Turn the head toward `attend` (or the weighted middle of the favoured) and aim the eyes."""
        if attend is not None:
            self.attending[agent] = attend
            yaw, pitch = self.direction(agent, attend)
        else:  # several addressees: toward the middle of those it speaks to
            top = max(weights.values())
            picks = [self.direction(agent, p) for p, w in weights.items() if w == top]
            yaw, pitch = sum(d[0] for d in picks) / len(picks), sum(d[1] for d in picks) / len(picks)
        head = (self._head_part(yaw, self.params.head_limits_deg[0]),
                self._head_part(pitch, self.params.head_limits_deg[1]))
        actions: list[Action] = []
        if head != self.head[agent]:
            self.head[agent] = head
            actions.append(HeadTurn(t_ns, agent, head[0], head[1], self.params.head_turn_s))
        names = tuple(weights)
        targets = [self.direction(agent, p) for p in names]
        actions.append(LookAt(t_ns, agent, names, tuple(d[0] - head[0] for d in targets),
                              tuple(d[1] - head[1] for d in targets), tuple(weights[p] for p in names)))
        return actions

    def _head_part(self, angle: float, limit: float) -> float:
        """The head's part of a gaze shift of `angle`: its share, and whatever would leave the eyes beyond
        their comfortable range; within the head's range."""
        head = angle * self.params.head_share
        excess = abs(angle - head) - self.params.eye_comfort_deg
        if excess > 0:
            head += math.copysign(excess, angle)
        return max(-limit, min(limit, head))

    def _draw(self, k: int) -> float:
        u = float(uniform01(self.seed, k, self._draws[k]))
        self._draws[k] += 1
        return u


@dataclass(frozen=True)
class FloorChange:
    """What one agent's new role changed: whether it started (True) or stopped (False) talking, None if
    neither; and the new turn, (speaker, addressees), when the floor changed hands (else None)."""

    talking: bool | None
    turn: tuple[str | None, tuple[str, ...]] | None
    previous_speaker: str | None


class Floor:
    """Who holds the floor live, from each agent's role as the dialogue states say it: the agent that began
    talking last (to the addressees its role names); else the person the listeners name as speaker (the
    user, or an agent a dialogue manager named; anyone else sits with the user, in front); else nobody."""

    def __init__(self, agents: Sequence[str]) -> None:
        self.known = (*agents, USER)
        self.roles: dict[str, tuple[str, str, tuple[str, ...]]] = {}  # agent -> role, speaker, addressees
        self.talking: list[str] = []  # agents talking now, the latest to start last
        self.turn: tuple[str | None, tuple[str, ...]] | None = None

    def update(self, agent: str, role: str, speaker: str, addressees: Sequence[str]) -> FloorChange:
        self.roles[agent] = (role, speaker, tuple(addressees))
        talking: bool | None = None
        if role == "talking" and agent not in self.talking:
            self.talking.append(agent)
            talking = True
        elif role != "talking" and agent in self.talking:
            self.talking.remove(agent)
            talking = False
        previous = self.turn[0] if self.turn is not None else None
        turn = self._turn()
        if turn == self.turn:
            return FloorChange(talking, None, previous)
        self.turn = turn
        return FloorChange(talking, turn, previous)

    def _turn(self) -> tuple[str | None, tuple[str, ...]]:
        if self.talking:
            speaker = self.talking[-1]
            return speaker, tuple(p for p in self.roles[speaker][2] if p in self.known and p != speaker)
        named = [who for role, who, _ in self.roles.values() if role == "listening" and who]
        if not named:
            return None, ()
        return (named[-1] if named[-1] in self.known else USER), ()


def take_floor(conversation: Conversation, t_ns: int, change: FloorChange) -> list[Action]:
    """The actions of a live change of floor: the last speaker's look back as its speech ends (its length
    was not known), then the new turn's."""
    if change.turn is None:
        return []
    actions = conversation.end_turn(t_ns) if change.previous_speaker in conversation.agents else []
    return actions + conversation.start_turn(t_ns, *change.turn)


def apply(engine: Any, actions: Sequence[Action], index: Mapping[str, int]) -> list[HeadTurn]:
    """Hand gaze actions to a GazeEngine (agent names to indices by `index`); the head turns, which are the
    face's, are returned."""
    heads: list[HeadTurn] = []
    for action in actions:
        i = index[action.agent]
        if isinstance(action, LookAt):
            engine.set_targets(i, action.yaw_deg, action.pitch_deg, action.weights, action.t_ns)
        elif isinstance(action, GazeShift):
            engine.shift_gaze(i, action.toward, action.t_ns)
        else:
            heads.append(action)
    return heads
