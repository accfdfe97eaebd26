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
"""

from __future__ import annotations

import argparse
from collections.abc import Iterable
from typing import Any

import numpy as np

from eca.agent.face.settings import load_flexor_units
from eca.agent.gaze.backchannel import Backchannel, ListenerBlink
from eca.agent.gaze.backchannel import Nod as NodAction
from eca.agent.gaze.engine import GazeEngine
from eca.agent.gaze.params import KINDS
from eca.agent.gaze.situated import USER, Action, Conversation, Floor, HeadTurn, apply, take_floor
from eca.agent.vocabulary import BACKCHANNEL_MODES
from eca.protocol.endpoints import BusConfig
from eca.protocol.messages import (
    AttentionState,
    EmotionState,
    EyesState,
    EyeState,
    GazeTargetState,
    HeadState,
    Nod,
    RoleState,
    Saccade,
    UserSpeech,
)
from eca.services.processes.runtime import Rejected, Service, parse_service_args


class GazeService(Service):
    name = "gaze"

    def __init__(self, config: BusConfig, seed: int | None = None, **kwargs: Any) -> None:
        super().__init__(config, **kwargs)
        table = config.raw.get("gaze", {})
        self.tick_hz = float(table.get("rate_hz", 60.0))
        self.agent_ids: list[str] = list(config.agents)
        self.index = {a: i for i, a in enumerate(self.agent_ids)}
        units = load_flexor_units()
        self.head_deg = (units.turn_deg, units.nod_deg)
        seed = int(table.get("seed", 0) if seed is None else seed)
        self.engine = GazeEngine(len(self.agent_ids), seed, start_ns=self.clock.now_ns())
        self.conversation = Conversation(self.agent_ids, seed)
        self.backchannel = Backchannel(self.agent_ids, seed)
        self.floor = Floor(self.agent_ids)
        self.modes = [self.engine.mode_of(i) for i in range(len(self.agent_ids))]
        # Agents whose message in this batch may have started a saccade: the service ticks right after the
        # batch and sends their eye states then; the others' keep the rate_hz schedule.
        self.touched: set[int] = set()
        for cls, handler in ((RoleState, self.on_role), (EmotionState, self.on_emotion), (HeadState, self.on_head),
                             (EyesState, self.on_eyes), (GazeTargetState, self.on_target),
                             (UserSpeech, self.on_user_speech)):
            self.handle(cls, handler)

    @classmethod
    def from_args(cls, config: BusConfig, argv: list[str], **kwargs: Any) -> GazeService:
        parser = argparse.ArgumentParser(prog="python -m eca.services.processes.run gaze", add_help=False,
                                         exit_on_error=False)
        parser.add_argument("--seed", type=int, default=None, help="seed of the eyes and blinks")
        args = parse_service_args("gaze", argv, parser)
        return cls(config, seed=args.seed, **kwargs)

    def subscriptions(self) -> list[str]:
        return [f"state.{a}." for a in self.agent_ids] + [f"event.{a}.user_speech" for a in self.agent_ids]

    def _i(self, agent: str) -> int:
        try:
            return self.index[agent]
        except KeyError:
            raise Rejected(f"unknown agent '{agent}'") from None

    def _now(self) -> int:
        return max(self.clock.now_ns(), self.engine.now_ns)

    def on_role(self, msg: RoleState) -> None:
        i = self._i(msg.agent)
        now = self._now()
        self.engine.set_role(i, msg.role, now)
        self.touched.add(i)
        change = self.floor.update(msg.agent, msg.role, msg.speaker, msg.addressees)
        if change.talking is not None:
            self.backchannel.speaking(now, msg.agent, change.talking)
        actions = take_floor(self.conversation, now, change)
        self._act(actions)
        self.touched.update(self.index[a.agent] for a in actions)

    def on_user_speech(self, msg: UserSpeech) -> None:
        self._i(msg.agent)
        self.backchannel.speaking(self._now(), USER, msg.speaking)

    def _act(self, actions: list[Action]) -> None:
        for turn in apply(self.engine, actions, self.index):
            self._publish_attention(turn)

    def _publish_attention(self, turn: HeadTurn) -> None:
        self.publish(AttentionState(agent=turn.agent, t_ns=max(turn.t_ns, 1),
                                    person=self.conversation.attending[turn.agent],
                                    yaw_deg=turn.yaw_deg, pitch_deg=turn.pitch_deg, duration_s=turn.duration_s))

    def on_emotion(self, msg: EmotionState) -> None:
        try:
            self.engine.set_emotion(self._i(msg.agent), msg.name, msg.intensity, self._now())
        except ValueError as exc:
            raise Rejected(str(exc)) from None

    def on_head(self, msg: HeadState) -> None:
        # The eyes lead the head: the engine hears the new head direction when the move begins.
        i = self._i(msg.agent)
        self.engine.set_head(i, msg.turn * self.head_deg[0], msg.nod * self.head_deg[1], self._now())
        self.touched.add(i)

    def on_eyes(self, msg: EyesState) -> None:
        i = self._i(msg.agent)
        self.engine.set_mode(i, msg.mode, self._now())
        self.modes[i] = msg.mode
        self.touched.add(i)

    def on_target(self, msg: GazeTargetState) -> None:
        i = self._i(msg.agent)
        self.engine.set_target(i, msg.yaw_deg, msg.pitch_deg, self._now())
        self.touched.add(i)

    def after_batch(self) -> None:
        if self.touched:
            touched = sorted(self.touched)
            self.touched.clear()
            self._tick(self._now(), touched)

    def on_tick(self, now_ns: int) -> None:
        self._tick(now_ns, range(len(self.agent_ids)))

    def _tick(self, now_ns: int, eye_states_for: Iterable[int]) -> None:
        """Advance every agent and publish every saccade begun since the last tick, and the eye states of
        `eye_states_for`."""
        now_ns = max(now_ns, self.engine.now_ns)
        self._act(self.conversation.due(now_ns))
        for action in self.backchannel.due(now_ns):
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
            agent = self.agent_ids[int(s.agent[k])]
            self.publish(Saccade(
                agent=agent, onset_ns=int(s.onset_ns[k]),
                from_yaw_deg=float(s.from_yaw_deg[k]), from_pitch_deg=float(s.from_pitch_deg[k]),
                to_yaw_deg=float(s.to_yaw_deg[k]), to_pitch_deg=float(s.to_pitch_deg[k]),
                amplitude_deg=float(s.amplitude_deg[k]), direction_deg=float(s.direction_deg[k]) % 360.0,
                duration_s=float(s.duration_s[k]), kind=KINDS[int(s.kind[k])],  # type: ignore[arg-type]
                hold_s=float(min(s.hold_s[k], 600.0))))
        yaw = np.clip(tick.yaw_deg, -90.0, 90.0)
        pitch = np.clip(tick.pitch_deg, -90.0, 90.0)
        lid = np.clip(tick.lid, 0.0, 1.0)
        for i in eye_states_for:
            agent = self.agent_ids[i]
            self.publish(EyeState(agent=agent, t_ns=tick.t_ns, yaw_deg=float(yaw[i]), pitch_deg=float(pitch[i]),
                                  lid=float(lid[i]), mode=self.modes[i]))  # type: ignore[arg-type]

