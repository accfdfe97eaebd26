"""From the bus to the agents' live scenes: what every process that draws the live face subscribes to,
and how each message becomes a scene call.

Each drawn agent has a `LiveScene` (agent/face/scene.py) fed its states (role, emotion, head, eyes),
events (saccades, speech lifecycle) and streams (eye state, clock anchors, mouth keys). The handlers
are registered on the owning service, so a message is refused the way any service refuses one: the
handler raises `Rejected` before it changes anything, and the service's `dispatch` reports it.

Messages wait in the socket until a frame needs them: `drain`, once per frame, reads what has arrived
(never ZMQ_CONFLATE, which would mix topics) so the frame sees every message that came before it.

Agents come and go at run time (docs/protocol.md, "Conversations created at run time"): `add_agent` and
`remove_agent` add and drop a scene and subscribe or unsubscribe its topics on the live socket (its current
states then come from the broker's cache). With `follow`, the scenes follow the dialogue service's
`state.*.agents` themselves (each created agent added, each removed one dropped); either way `live` holds the
latest list and `on_agents`, when set, is called with each new one.
"""

from __future__ import annotations

from collections import OrderedDict, deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from eca.agent.face.composed import ComposedFace
from eca.agent.face.scene import LiveScene
from eca.protocol.messages import (
    ALL_AGENTS,
    AgentsState,
    AttentionState,
    ClockAnchor,
    EmotionState,
    Expression,
    EyesState,
    EyeStates,
    GazeTargetState,
    HeadGesture,
    HeadState,
    Message,
    MouthKeys,
    Nod,
    RoleState,
    Saccade,
    SpeechFailed,
    SpeechFinished,
    SpeechInterrupted,
    SpeechStarted,
)
from eca.services.processes.runtime import Rejected, Service, latest_per_state_topic

KEEP_EYE_SAMPLES = 4
MAX_READ_PER_FRAME = 5000  # a frame never reads an unbounded backlog: the rest waits for the next frame
GONE_KEPT = 1024  # lately removed agents whose last messages, still on their way, are dropped without a word
AGENTS_TOPIC = f"state.{ALL_AGENTS}.{AgentsState.TYPE}"
EYES_TOPIC = f"stream.{ALL_AGENTS}.{EyeStates.TYPE}"  # every agent's eyes, a message per gaze tick
_EYES_TOPIC_BYTES = EYES_TOPIC.encode()


@dataclass
class AgentView:
    """One drawn agent: its scene, and what the stage last composed of it."""

    agent: str
    scene: LiveScene
    trail: deque[tuple[float, float]] = field(default_factory=deque)  # recent (look_x, look_y)
    face: ComposedFace | None = None  # what the stage last composed


# What a live scene is fed: each message type with the BusScenes method that handles it.
HANDLERS: dict[type[Message], str] = {
    RoleState: "on_role",
    EmotionState: "on_emotion",
    HeadState: "on_head",
    EyesState: "on_eyes",
    GazeTargetState: "on_gaze_target",
    AttentionState: "on_attention",
    Nod: "on_nod",
    HeadGesture: "on_head_gesture",
    Expression: "on_expression",
    Saccade: "on_saccade",
    EyeStates: "on_eye_states",
    ClockAnchor: "on_anchor",
    MouthKeys: "on_mouth",
    SpeechStarted: "on_speech_started",
    SpeechFinished: "on_speech_ended",
    SpeechInterrupted: "on_speech_ended",
    SpeechFailed: "on_speech_failed",
    AgentsState: "on_agents_state",
}
# Its events, subscribed one by one (agent_topics), not event.<agent>.* whole: the acknowledgements above all, one per
# command, which under a flood of commands (bench/reliability.py: 20,000 a second) every drawer would read and drop.
SCENE_EVENTS = tuple(cls for cls in HANDLERS if cls.CATEGORY == "event")


class BusScenes:
    """The live scenes of `agents`, fed from `service`'s bus (its handlers are registered on it).

    The i-th agent added (those given first) has its idle noise seeded `seed + i`, so each agent moves on its own.
    `follow`: also add every agent created at run time and drop it when it is removed (state.*.agents)."""

    def __init__(self, service: Service, agents: Sequence[str], *, seed: int = 0, idle_noise: bool = True,
                 follow: bool = False) -> None:
        self.service = service
        self.seed = seed
        self.idle_noise = idle_noise
        self.follow = follow
        self.views: list[AgentView] = []  # changed in place: a holder of this list sees agents come and go
        self.by_agent: dict[str, AgentView] = {}
        self._added = 0  # agents added so far: the next one's seed
        self._gone: OrderedDict[str, None] = OrderedDict()
        self._followed: set[str] = set()  # agents `follow` added (it drops only those)
        self.live: tuple[str, ...] = ()  # the instance's live agents as the latest state.*.agents lists them
        self._on_agents: Callable[[AgentsState], None] | None = None
        self._listening = False  # subscribed to state.*.agents on the live socket
        for agent in agents:
            self.add_agent(agent)
        # a commanded state (role, emotion, head, eye mode) changed since the drawer last cleared this: one
        # that can draw between its frame slots shows it at once instead of at the next slot
        self.commanded = False
        for cls, handler in HANDLERS.items():
            service.handle(cls, getattr(self, handler))

    def subscriptions(self) -> list[str]:
        """The topics of every agent's scene; the list of live agents too when following it or told of it."""
        subs = [EYES_TOPIC, *(p for v in self.views for p in agent_topics(v.agent))]
        if self.follow or self._on_agents is not None:
            self._listening = True
            subs.append(AGENTS_TOPIC)
        return subs

    @property
    def on_agents(self) -> Callable[[AgentsState], None] | None:
        """Called with each new state.*.agents (after `follow` has added and dropped agents by it), on the
        service's thread: where a service that chooses its agents itself (the web service, for the agents its
        pages watch) calls add_agent and remove_agent. Set on a connected service, it subscribes at once (the
        current list then comes from the broker's cache)."""
        return self._on_agents

    @on_agents.setter
    def on_agents(self, hook: Callable[[AgentsState], None] | None) -> None:
        self._on_agents = hook
        sub = self.service.sub
        if hook is not None and sub is not None and not self._listening:
            self._listening = True
            sub.subscribe(AGENTS_TOPIC)

    # --- agents added and removed at run time ------------------------------------------------------

    def add_agent(self, agent: str) -> AgentView:
        """A scene for `agent` (the one it has if it has one), its topics subscribed on the live socket."""
        view = self.by_agent.get(agent)
        if view is not None:
            return view
        view = AgentView(agent, LiveScene(seed=self.seed + self._added, idle_noise=self.idle_noise))
        self._added += 1
        self.views.append(view)
        self.by_agent[agent] = view
        self._gone.pop(agent, None)
        sub = self.service.sub
        if sub is not None:  # before the service connects, `subscriptions` names it
            for prefix in agent_topics(agent):
                sub.subscribe(prefix)
        return view

    def remove_agent(self, agent: str) -> bool:
        """Drop `agent`'s scene and unsubscribe its topics; False if it had none. What is still on its way for it
        is dropped without a word."""
        view = self.by_agent.pop(agent, None)
        if view is None:
            return False
        self.views.remove(view)
        self._followed.discard(agent)
        self._gone[agent] = None
        while len(self._gone) > GONE_KEPT:
            self._gone.popitem(last=False)
        sub = self.service.sub
        if sub is not None:
            for prefix in agent_topics(agent):
                sub.unsubscribe(prefix)
        return True

    def on_agents_state(self, m: AgentsState) -> None:
        self.live = tuple(m.agents)
        if self.follow:
            live = set(m.agents)
            for agent in [a for a in self._followed if a not in live]:
                self._followed.discard(agent)
                self.remove_agent(agent)
            for agent in m.created:
                if agent not in self.by_agent:
                    self._followed.add(agent)
                    self.add_agent(agent)
        if self._on_agents is not None:
            self._on_agents(m)

    def drain(self) -> int:
        """Handle every message waiting on the service's socket; returns how many were read.

        Eye-state samples are only ever interpolated near the newest ones, so of the eye-state messages in
        one batch only the newest KEEP_EYE_SAMPLES are decoded, and of each state topic only the newest
        message: a flood costs a socket read each, not a decode. Everything else (events, mouth keys,
        clock anchors) is handled in order; a state the last-value cache re-sent unchanged (byte for
        byte) is ignored. At most MAX_READ_PER_FRAME messages are read per frame, so the frame rate
        holds whatever arrives (the rest waits for the next frame). What is skipped is counted in the
        service's `coalesced`.
        """
        service = self.service
        assert service.sub is not None
        raw = service.sub.read_frames(MAX_READ_PER_FRAME)
        read = len(raw)
        raw = latest_per_state_topic(raw)
        service.coalesced += read - len(raw)
        seen: dict[bytes, int] = {}
        keep = [True] * len(raw)
        for i in range(len(raw) - 1, -1, -1):
            topic = raw[i][0]
            if topic == _EYES_TOPIC_BYTES:
                seen[topic] = seen.get(topic, 0) + 1
                keep[i] = seen[topic] <= KEEP_EYE_SAMPLES
        for frames, wanted in zip(raw, keep, strict=True):
            if not wanted:
                service.coalesced += 1
                continue
            got = service.sub.accept(frames)
            if got is not None:
                service.dispatch(got)
        return read

    # --- one handler per message type ------------------------------------------------------------

    def _scene(self, msg: Message) -> LiveScene | None:
        """The agent's scene; None for one removed a moment ago (its last messages are no news)."""
        view = self.by_agent.get(msg.agent)
        if view is None:
            if msg.agent in self._gone:
                return None
            raise Rejected(f"this renderer does not draw agent '{msg.agent}'")
        return view.scene

    def _guard(self, msg: Message, call: Callable[[LiveScene], None]) -> bool:
        """Hand msg to its agent's scene (`call`); whether it reached one. A value the scene refuses is
        rejected through the service."""
        scene = self._scene(msg)
        if scene is None:
            return False
        try:
            call(scene)
        except ValueError as exc:
            raise Rejected(str(exc)) from None
        return True

    def on_role(self, m: RoleState) -> None:
        if self._guard(m, lambda s: s.set_role(m.role, m.t_ns, m.speaker)):
            self.commanded = True

    def on_emotion(self, m: EmotionState) -> None:
        if self._guard(m, lambda s: s.set_emotion(m.name, m.intensity, m.transition_s, m.t_ns)):
            self.commanded = True

    def on_head(self, m: HeadState) -> None:
        if self._guard(m, lambda s: s.move_head(m.turn, m.nod, m.tilt, m.duration_s, m.t_ns)):
            self.commanded = True

    def on_attention(self, m: AttentionState) -> None:
        self._guard(m, lambda s: s.attend(m.yaw_deg, m.pitch_deg, m.duration_s, m.t_ns))

    def on_nod(self, m: Nod) -> None:
        self._guard(m, lambda s: s.nod(m.onset_ns, m.amplitude_deg, m.duration_s))

    def on_head_gesture(self, m: HeadGesture) -> None:
        self._guard(m, lambda s: s.head_gesture(m.id, m.lexeme, m.onset_ns, m.amplitude_deg, m.duration_s,
                                                m.repetitions))

    def on_expression(self, m: Expression) -> None:
        self._guard(m, lambda s: s.expression(m.id, m.onset_ns, m.peak_ns, m.relax_ns, m.end_ns, m.flexors))

    def on_eyes(self, m: EyesState) -> None:
        if self._guard(m, lambda s: s.set_eye_mode(m.mode)):
            self.commanded = True

    def on_gaze_target(self, m: GazeTargetState) -> None:
        """Nothing to do: the eyes follow the gaze service's eye states, which it makes of the target."""

    def on_saccade(self, m: Saccade) -> None:
        self._guard(m, lambda s: s.add_saccade(m.onset_ns, (m.from_yaw_deg, m.from_pitch_deg),
                                               (m.to_yaw_deg, m.to_pitch_deg), m.duration_s))

    def on_eye_states(self, m: EyeStates) -> None:
        """Each followed agent's eyes to its scene; the other agents' are not this service's."""
        for agent, yaw, pitch, lid, mode in m.rows():
            view = self.by_agent.get(agent)
            if view is None:
                continue
            try:
                view.scene.add_eye_sample(m.t_ns, yaw, pitch, lid, mode)
            except ValueError as exc:
                raise Rejected(f"{agent}: {exc}") from None

    def on_anchor(self, m: ClockAnchor) -> None:
        self._guard(m, lambda s: s.add_clock_anchor(m.request_id, m.sample_index, m.sample_rate, m.dac_time_ns))

    def on_mouth(self, m: MouthKeys) -> None:
        self._guard(m, lambda s: s.add_mouth_keys(m.request_id, m.sample_rate, m.sample_index, m.weights, m.reset,
                                                  m.t_ns))

    def on_speech_started(self, m: SpeechStarted) -> None:
        self._guard(m, lambda s: s.speech_started(m.request_id, m.dac_time_ns))

    def on_speech_ended(self, m: SpeechFinished | SpeechInterrupted) -> None:
        self._guard(m, lambda s: s.speech_ended(m.request_id, m.played_s, m.t_ns))

    def on_speech_failed(self, m: SpeechFailed) -> None:
        self._guard(m, lambda s: s.speech_failed(m.request_id, m.t_ns))


def agent_topics(agent: str) -> list[str]:
    """What the live scene of one agent is fed from."""
    return [f"state.{agent}.", *(f"event.{agent}.{cls.TYPE}" for cls in SCENE_EVENTS),
            f"stream.{agent}.clock_anchor", f"stream.{agent}.mouth"]
