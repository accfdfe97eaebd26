"""Listener backchannels: at a pause in a partner's speech, a listening agent sometimes nods and/or blinks.

Fed who speaks when (`speaking(t_ns, who, on)` — an agent of the instance or the user; from a voice
activity detector, an agent's speech events, or pauses found in a script's audio), a `Backchannel` treats
the end of every stretch of speech as a pause opportunity (configs/backchannel.toml [opportunity]): after
at least `min_speech_s` of speech, and not within `refractory_s` of the listener's last response (Ward &
Tsukahara 2000), each other agent that is not speaking draws a nod and a blink, each at its probability,
to come after the configured delay (a blink 0.25-0.5 s later: Nakano & Kitazawa 2010). An agent that
starts to speak drops what it had pending: it never backchannels while it speaks.

The actions come out of `due(until_ns)` at their times: a `Nod` for the face (FaceModel.nod), a
`ListenerBlink` for the gaze engine (GazeEngine.blink_at, which pulls a due blink forward, so the blink rate
stays the blink model's). Pure Python and deterministic: the draws come from the counter-based stream of
the seed, one stream per agent.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from eca.agent.config import ConfigError, load_toml, require
from eca.agent.counter_rng import uniform01

USER = "user"
_NS = 1_000_000_000
_STREAM_SALT = 0x0BAC_C4A1  # keeps these draws apart from the other models' streams of the same seed


@dataclass(frozen=True)
class BackchannelParams:
    """The constants of configs/backchannel.toml (their sources are named there)."""

    min_speech_s: float
    refractory_s: float
    min_pause_s: float
    nod_probability: float
    nod_delay_s: tuple[float, float]
    nod_amplitude_deg: tuple[float, float]
    nod_duration_s: tuple[float, float]
    blink_probability: float
    blink_delay_s: tuple[float, float]

    @classmethod
    def load(cls, name: str = "backchannel") -> BackchannelParams:
        doc = load_toml(name)
        where = name if name.endswith(".toml") else f"configs/{name}.toml"
        tables = {k: require(doc, k, dict, where) for k in ("opportunity", "nod", "blink")}
        opp, nod, blink = tables["opportunity"], tables["nod"], tables["blink"]
        return cls(
            min_speech_s=_seconds(opp, "min_speech_s", f"{where} [opportunity]"),
            refractory_s=_seconds(opp, "refractory_s", f"{where} [opportunity]"),
            min_pause_s=_seconds(opp, "min_pause_s", f"{where} [opportunity]"),
            nod_probability=_probability(nod, "probability", f"{where} [nod]"),
            nod_delay_s=_range(nod, "delay_s", f"{where} [nod]"),
            nod_amplitude_deg=_range(nod, "amplitude_deg", f"{where} [nod]", positive=True),
            nod_duration_s=_range(nod, "duration_s", f"{where} [nod]", positive=True),
            blink_probability=_probability(blink, "probability", f"{where} [blink]"),
            blink_delay_s=_range(blink, "delay_s", f"{where} [blink]"),
        )


def _seconds(table: dict[str, Any], key: str, where: str) -> float:
    value = require(table, key, float, where)
    if not math.isfinite(value) or value < 0:
        raise ConfigError(f"{where}: '{key}' must be a finite number >= 0, got {value!r}")
    return float(value)


def _probability(table: dict[str, Any], key: str, where: str) -> float:
    value = _seconds(table, key, where)
    if value > 1:
        raise ConfigError(f"{where}: '{key}' must be in [0, 1], got {value!r}")
    return value


def _range(table: dict[str, Any], key: str, where: str, positive: bool = False) -> tuple[float, float]:
    value = require(table, key, list, where)
    ok = len(value) == 2 and all(isinstance(v, int | float) and not isinstance(v, bool) for v in value)
    if ok:
        lo, hi = float(value[0]), float(value[1])
        ok = math.isfinite(lo) and math.isfinite(hi) and 0 <= lo <= hi and (lo > 0 or not positive)
    if not ok:
        raise ConfigError(f"{where}: '{key}' must be [low, high] with 0 {'<' if positive else '<='} low <= high, "
                          f"got {value!r}")
    return lo, hi


@dataclass(frozen=True)
class Nod:
    """The agent nods from `t_ns`: the chin dips `amplitude_deg` and comes back within `duration_s`."""

    t_ns: int
    agent: str
    amplitude_deg: float
    duration_s: float


@dataclass(frozen=True)
class ListenerBlink:
    """The agent blinks at `t_ns` if its blink model has one due soon (GazeEngine.blink_at)."""

    t_ns: int
    agent: str


BackchannelAction = Nod | ListenerBlink


class Backchannel:
    """The listeners' nods and blinks at the pauses of whoever speaks among `agents` and the user."""

    def __init__(self, agents: Sequence[str], seed: int, params: BackchannelParams | None = None) -> None:
        if len(set(agents)) != len(agents) or USER in agents or not agents:
            raise ValueError(f"backchannels need distinct agents other than '{USER}', got {list(agents)!r}")
        self.params = params if params is not None else BackchannelParams.load()
        self.agents = tuple(agents)
        self.seed = (int(seed) ^ _STREAM_SALT) & 0xFFFF_FFFF_FFFF_FFFF
        self._draws = [0] * len(self.agents)
        self._since: dict[str, int] = {}  # who is speaking -> since when
        self._last_response: dict[str, int] = {}  # agent -> time of its last nod or blink
        self._pending: list[BackchannelAction] = []
        self.opportunities = 0  # pauses that were a chance to respond, for statistics

    def is_speaking(self, who: str) -> bool:
        return who in self._since

    def speaking(self, t_ns: int, who: str, on: bool) -> None:
        """`who` starts (on) or stops speaking at `t_ns`. A stop after enough speech is a pause opportunity
        for every other agent that is silent; a start cancels what `who` itself had pending."""
        if who != USER and who not in self.agents:
            raise ValueError(f"unknown speaker {who!r}; the conversation has {', '.join((*self.agents, USER))}")
        if on:
            self._since.setdefault(who, t_ns)
            self._pending = [a for a in self._pending if a.agent != who]
            return
        began = self._since.pop(who, None)
        if began is None or t_ns - began < self.params.min_speech_s * _NS:
            return
        self.opportunities += 1
        for k, agent in enumerate(self.agents):
            if agent == who or agent in self._since:
                continue
            last = self._last_response.get(agent)
            if last is not None and t_ns - last < self.params.refractory_s * _NS:
                continue
            self._respond(t_ns, k, agent)

    def pause(self, t_ns: int, who: str, speech_s: float) -> None:
        """A pause found in `who`'s audio at `t_ns`, after `speech_s` of speech (a script's turn: the speech
        around it is known in advance)."""
        self.speaking(t_ns - round(speech_s * _NS), who, True)
        self.speaking(t_ns, who, False)

    def due(self, until_ns: int) -> list[BackchannelAction]:
        """The actions at or before `until_ns`, in time order (taken). An action of an agent that speaks at
        its time is dropped, whatever the order the caller learnt of things in."""
        ready = sorted((a for a in self._pending if a.t_ns <= until_ns), key=lambda a: (a.t_ns, a.agent))
        self._pending = [a for a in self._pending if a.t_ns > until_ns]
        return [a for a in ready if a.agent not in self._since]

    def _respond(self, t_ns: int, k: int, agent: str) -> None:
        p = self.params
        nod, blink = self._draw(k) < p.nod_probability, self._draw(k) < p.blink_probability
        if nod:
            at = t_ns + round(self._between(k, p.nod_delay_s) * _NS)
            self._pending.append(Nod(at, agent, self._between(k, p.nod_amplitude_deg),
                                     self._between(k, p.nod_duration_s)))
        if blink:
            self._pending.append(ListenerBlink(t_ns + round(self._between(k, p.blink_delay_s) * _NS), agent))
        if nod or blink:
            self._last_response[agent] = t_ns

    def _between(self, k: int, bounds: tuple[float, float]) -> float:
        return bounds[0] + (bounds[1] - bounds[0]) * self._draw(k)

    def _draw(self, k: int) -> float:
        u = float(uniform01(self.seed, k, self._draws[k]))
        self._draws[k] += 1
        return u
