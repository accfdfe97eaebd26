"""The gaze service: the Attention Monitor and saccade engine for this instance's agents, live.

It follows each agent's state (role, emotion, head, eye mode, gaze target) from the dialogue
service, ticks the engine at a fixed rate (default 60 Hz) and publishes the eye state of every agent
each tick plus a saccade event at every onset, so a renderer can draw the exact trajectory at its
own frame times. A message that can start a saccade at once (role, head, gaze target, eye mode) makes
the service tick right after the batch it came in, so the saccade event and that agent's eye state go
out then rather than at the next scheduled tick: a renderer learns of it within one bus hop. The other
agents' eye states keep the scheduled rate.

It also hosts the conversation around the agents. From the agents' roles (who talks, to whom; who
listens to whom) it follows whose turn it is, and a `Conversation` (agent/gaze/situated.py) turns the
listeners' eyes to the speaker and the speaker's to its addressees, with a head turn toward the person
attended published as `state.<agent>.attention`; a speaker looks away as its turn starts and back as it
ends (Kendon). A `Backchannel` (agent/gaze/backchannel.py) answers the pauses of whoever speaks (an
agent's speech, the user's voice activity re-published by the dialogue service) with listeners' blinks
and nods (`event.<agent>.nod`).

Agents created at run time (`state.*.agents`, docs/protocol.md "Conversations created at run time") each have a
conversation of their own, alone with their user: they join the engine (a slot of its arrays; a removed agent's
slot, its eyes stopped, waits in a pool for the next one, so the arrays never grow past the most agents alive at
once) and their topics are subscribed on the live socket; a removed one is unsubscribed and forgotten.
"""

from __future__ import annotations

import argparse
from collections import OrderedDict
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np

from eca.agent.face.settings import load_flexor_units
from eca.agent.gaze.backchannel import Backchannel, ListenerBlink
from eca.agent.gaze.backchannel import Nod as NodAction
from eca.agent.gaze.engine import GazeEngine
from eca.agent.gaze.params import DEFAULT_ROLE, KINDS
from eca.agent.gaze.situated import USER, Action, Conversation, Floor, HeadTurn, apply, take_floor
from eca.agent.vocabulary import BACKCHANNEL_MODES
from eca.protocol.endpoints import BusConfig
from eca.protocol.messages import (
    ALL_AGENTS,
    MAX_LIVE_AGENTS,
    AgentsState,
    AttentionState,
    EmotionState,
    EyesState,
    EyeStates,
    GazeTargetState,
    HeadState,
    Nod,
    RoleState,
    Saccade,
    UserSpeech,
)
from eca.services.processes.runtime import Rejected, Service, parse_service_args

GONE_KEPT = 1024  # lately removed agents whose last messages, still on their way, are dropped without a word
FREE_MODE = "static"  # the eyes of a free slot: no saccades, no blinks, nothing for the engine to do


@dataclass
class Circle:
    """The people who see each other: the configured agents and the user, or one created agent and its user.
    Who looks at whom, the floor and the backchannels are the circle's own."""

    agents: tuple[str, ...]
    conversation: Conversation
    backchannel: Backchannel
    floor: Floor


class GazeService(Service):
    name = "gaze"

    def __init__(self, config: BusConfig, seed: int | None = None, **kwargs: Any) -> None:
        super().__init__(config, **kwargs)
        table = config.raw.get("gaze", {})
        self.tick_hz = float(table.get("rate_hz", 60.0))
        self.configured: tuple[str, ...] = tuple(config.agents)
        self.index: dict[str, int] = {a: i for i, a in enumerate(self.configured)}  # live agent -> engine slot
        units = load_flexor_units()
        self.head_deg = (units.turn_deg, units.nod_deg)
        self.seed = seed = int(table.get("seed", 0) if seed is None else seed)
        self.engine = GazeEngine(len(self.configured), seed, start_ns=self.clock.now_ns())
        self.conversation = Conversation(self.configured, seed)
        self.backchannel = Backchannel(self.configured, seed)
        self.floor = Floor(self.configured)
        configured = Circle(self.configured, self.conversation, self.backchannel, self.floor)
        self.circles: list[Circle] = [configured]
        self.circle_of: dict[str, Circle] = {a: configured for a in self.configured}
        self.slots: list[str | None] = list(self.configured)  # engine slot -> its agent (None: free)
        self.free: list[int] = []  # slots of removed agents, for the next created one
        self.created: list[str] = []  # live agents created at run time, in order
        self._joined = 0  # agents created so far
        self._gone: OrderedDict[str, None] = OrderedDict()
        self.modes = [self.engine.mode_of(i) for i in range(len(self.configured))]
        # Agents whose message in this batch may have started a saccade: the service ticks right after the
        # batch and sends their eye states then; the others' keep the rate_hz schedule.
        self.touched: set[int] = set()
        handlers: tuple[tuple[type[Any], Callable[[Any], None]], ...] = (
            (RoleState, self.on_role), (EmotionState, self.on_emotion), (HeadState, self.on_head),
            (EyesState, self.on_eyes), (GazeTargetState, self.on_target), (UserSpeech, self.on_user_speech),
            (AgentsState, self.on_agents))
        for cls, handler in handlers:
            self.handle(cls, handler)

    @property
    def agent_ids(self) -> list[str]:
        """The live agents: the configured ones, then those created at run time."""
        return [*self.configured, *self.created]

    @classmethod
    def from_args(cls, config: BusConfig, argv: list[str], **kwargs: Any) -> GazeService:
        parser = argparse.ArgumentParser(prog="python -m eca.services.processes.run gaze", add_help=False,
                                         exit_on_error=False)
        parser.add_argument("--seed", type=int, default=None, help="seed of the eyes and blinks")
        args = parse_service_args("gaze", argv, parser)
        return cls(config, seed=args.seed, **kwargs)

    def subscriptions(self) -> list[str]:
        return [p for a in self.configured for p in _topics(a)] + [f"state.{ALL_AGENTS}.{AgentsState.TYPE}"]

    def _i(self, agent: str) -> int | None:
        """The agent's engine slot; None for one removed a moment ago (its last messages are no news)."""
        i = self.index.get(agent)
        if i is None and agent not in self._gone:
            raise Rejected(f"unknown agent '{agent}'")
        return i

    def _now(self) -> int:
        return max(self.clock.now_ns(), self.engine.now_ns)

    # --- agents created and removed at run time ---------------------------------------------------

    def on_agents(self, msg: AgentsState) -> None:
        live = set(msg.agents)
        for agent in [a for a in self.created if a not in live]:
            self.remove_agent(agent)
        for agent in msg.created:
            if agent not in self.index:
                self.add_agent(agent)

    def add_agent(self, agent: str) -> int:
        """A created agent joins: a slot of the engine (a free one when there is one, its eyes restarted as a new
        agent's), a conversation of its own, and its topics."""
        now = self._now()
        if self.free:
            i = self.free.pop()
            self.engine.set_emotion(i, "natural", 1.0, now)
            self.engine.set_head(i, 0.0, 0.0, now)
            self.engine.set_target(i, 0.0, 0.0, now)
            self.engine.set_role(i, DEFAULT_ROLE, now)
            self.engine.set_mode(i, self.engine.params.default_mode, now)
            self.slots[i] = agent
        else:
            i = int(self.engine.add_agents(1, now)[0])
            self.slots.append(agent)
            self.modes.append(self.engine.mode_of(i))
        self.modes[i] = self.engine.mode_of(i)
        # its own seed, so no two created agents draw alike (not even two in the same slot)
        self._joined += 1
        seed = self.seed + len(self.configured) + self._joined
        circle = Circle((agent,), Conversation([agent], seed, self.conversation.params),
                        Backchannel([agent], seed, self.backchannel.params), Floor([agent]))
        self.circles.append(circle)
        self.circle_of[agent] = circle
        self.index[agent] = i
        self.created.append(agent)
        self._gone.pop(agent, None)
        if self.sub is not None:
            for prefix in _topics(agent):  # its current states come from the broker's cache at once
                self.sub.subscribe(prefix)
        self.touched.add(i)
        return i

    def remove_agent(self, agent: str) -> None:
        """A created agent leaves: its slot's eyes stop and the slot waits for the next agent."""
        i = self.index.pop(agent)
        self.engine.set_mode(i, FREE_MODE, self._now())
        self.modes[i] = FREE_MODE
        self.slots[i] = None
        self.free.append(i)
        self.touched.discard(i)
        self.circles.remove(self.circle_of.pop(agent))
        self.created.remove(agent)
        self._gone[agent] = None
        while len(self._gone) > GONE_KEPT:
            self._gone.popitem(last=False)
        if self.sub is not None:
            for prefix in _topics(agent):
                self.sub.unsubscribe(prefix)

    # --- the agents' states ------------------------------------------------------------------------

    def on_role(self, msg: RoleState) -> None:
        i = self._i(msg.agent)
        if i is None:
            return
        now = self._now()
        self.engine.set_role(i, msg.role, now)
        self.touched.add(i)
        circle = self.circle_of[msg.agent]
        change = circle.floor.update(msg.agent, msg.role, msg.speaker, msg.addressees)
        if change.talking is not None:
            circle.backchannel.speaking(now, msg.agent, change.talking)
        actions = take_floor(circle.conversation, now, change)
        self._act(actions)
        self.touched.update(self.index[a.agent] for a in actions)

    def on_user_speech(self, msg: UserSpeech) -> None:
        if self._i(msg.agent) is not None:
            # the user of this agent's conversation: everyone's, for the configured agents
            self.circle_of[msg.agent].backchannel.speaking(self._now(), USER, msg.speaking)

    def _act(self, actions: list[Action]) -> None:
        for turn in apply(self.engine, actions, self.index):
            self._publish_attention(turn)

    def _publish_attention(self, turn: HeadTurn) -> None:
        self.publish(AttentionState(agent=turn.agent, t_ns=max(turn.t_ns, 1),
                                    person=self.circle_of[turn.agent].conversation.attending[turn.agent],
                                    yaw_deg=turn.yaw_deg, pitch_deg=turn.pitch_deg, duration_s=turn.duration_s))

    def on_emotion(self, msg: EmotionState) -> None:
        i = self._i(msg.agent)
        if i is None:
            return
        try:
            self.engine.set_emotion(i, msg.name, msg.intensity, self._now())
        except ValueError as exc:
            raise Rejected(str(exc)) from None

    def on_head(self, msg: HeadState) -> None:
        # The eyes lead the head: the engine hears the new head direction when the move begins.
        i = self._i(msg.agent)
        if i is None:
            return
        self.engine.set_head(i, msg.turn * self.head_deg[0], msg.nod * self.head_deg[1], self._now())
        self.touched.add(i)

    def on_eyes(self, msg: EyesState) -> None:
        i = self._i(msg.agent)
        if i is None:
            return
        self.engine.set_mode(i, msg.mode, self._now())
        self.modes[i] = msg.mode
        self.touched.add(i)

    def on_target(self, msg: GazeTargetState) -> None:
        i = self._i(msg.agent)
        if i is None:
            return
        self.engine.set_target(i, msg.yaw_deg, msg.pitch_deg, self._now())
        self.touched.add(i)

    def after_batch(self) -> None:
        if self.touched:
            touched = sorted(self.touched)
            self.touched.clear()
            self._tick(self._now(), touched)

    def on_tick(self, now_ns: int) -> None:
        self._tick(now_ns, self.index.values())

    def _tick(self, now_ns: int, eye_states_for: Iterable[int]) -> None:
        """Advance every agent and publish every saccade begun since the last tick, and the eye states of
        `eye_states_for`."""
        now_ns = max(now_ns, self.engine.now_ns)
        for circle in self.circles:
            self._act(circle.conversation.due(now_ns))
            for action in circle.backchannel.due(now_ns):
                i = self.index[action.agent]
                if self.engine.mode_of(i) not in BACKCHANNEL_MODES:
                    continue  # the paper's conditions stay as they were
                if isinstance(action, ListenerBlink):
                    self.engine.blink_at(i, max(action.t_ns, self.engine.now_ns))
                elif isinstance(action, NodAction):
                    self.publish(Nod(agent=action.agent, onset_ns=action.t_ns, amplitude_deg=action.amplitude_deg,
                                     duration_s=action.duration_s))
        tick = self.engine.tick(now_ns)
        s = tick.saccades
        for k in range(len(s)):
            agent = self.slots[int(s.agent[k])]
            if agent is None:
                continue  # a free slot's last flight
            self.publish(Saccade(
                agent=agent, onset_ns=int(s.onset_ns[k]),
                from_yaw_deg=float(s.from_yaw_deg[k]), from_pitch_deg=float(s.from_pitch_deg[k]),
                to_yaw_deg=float(s.to_yaw_deg[k]), to_pitch_deg=float(s.to_pitch_deg[k]),
                amplitude_deg=float(s.amplitude_deg[k]), direction_deg=float(s.direction_deg[k]) % 360.0,
                duration_s=float(s.duration_s[k]), kind=KINDS[int(s.kind[k])],  # type: ignore[arg-type]
                hold_s=float(min(s.hold_s[k], 600.0))))
        seated = [i for i in eye_states_for if self.slots[i] is not None]
        for start in range(0, len(seated), MAX_LIVE_AGENTS):  # one message a tick (the protocol's list bound)
            at = seated[start:start + MAX_LIVE_AGENTS]
            self.publish(EyeStates(
                agent=ALL_AGENTS, t_ns=tick.t_ns, agents=[self.slots[i] for i in at],  # type: ignore[misc]
                yaw_deg=np.clip(tick.yaw_deg[at], -90.0, 90.0).tolist(),
                pitch_deg=np.clip(tick.pitch_deg[at], -90.0, 90.0).tolist(),
                lid=np.clip(tick.lid[at], 0.0, 1.0).tolist(), mode=[self.modes[i] for i in at]))  # type: ignore[misc]


def _topics(agent: str) -> list[str]:
    """What the service follows of one agent: its states and its user's voice activity."""
    return [f"state.{agent}.", f"event.{agent}.user_speech"]
