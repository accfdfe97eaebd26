"""From the bus to the agents' live scenes: what every process that draws the live face subscribes to,
and how each message becomes a scene call.

Each drawn agent has a `LiveScene` (agent/face/scene.py) fed its states (role, emotion, head, eyes),
events (saccades, speech lifecycle) and streams (eye state, clock anchors, mouth keys). The handlers
are registered on the owning service, so a message is refused the way any service refuses one: the
handler raises `Rejected` before it changes anything, and the service's `dispatch` reports it.

Messages wait in the socket until a frame needs them: `drain`, once per frame, reads what has arrived
(never ZMQ_CONFLATE, which would mix topics) so the frame sees every message that came before it.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

from eca.agent.face.composed import ComposedFace
from eca.agent.face.scene import LiveScene
from eca.protocol.messages import (
    AttentionState,
    ClockAnchor,
    EmotionState,
    EyesState,
    EyeState,
    GazeTargetState,
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


@dataclass
class AgentView:
    """One drawn agent: its scene, and what the stage last composed of it."""

    agent: str
    scene: LiveScene
    trail: deque[tuple[float, float]] = field(default_factory=deque)  # recent (look_x, look_y)
    face: ComposedFace | None = None  # what the stage last composed


class BusScenes:
    """The live scenes of `agents`, fed from `service`'s bus (its handlers are registered on it).

    Agent i's idle noise is seeded `seed + i`, so each agent moves on its own."""

    def __init__(self, service: Service, agents: Sequence[str], *, seed: int = 0, idle_noise: bool = True) -> None:
        self.service = service
        self.views = [AgentView(a, LiveScene(seed=seed + i, idle_noise=idle_noise)) for i, a in enumerate(agents)]
        self.by_agent = {v.agent: v for v in self.views}
        # a commanded state (role, emotion, head, eye mode) changed since the drawer last cleared this: one
        # that can draw between its frame slots shows it at once instead of at the next slot
        self.commanded = False
        handlers: tuple[tuple[type[Any], Callable[[Any], None]], ...] = (
            (RoleState, self.on_role),
            (EmotionState, self.on_emotion),
            (HeadState, self.on_head),
            (EyesState, self.on_eyes),
            (GazeTargetState, lambda m: None),
            (AttentionState, self.on_attention),
            (Nod, self.on_nod),
            (Saccade, self.on_saccade),
            (EyeState, self.on_eye_state),
            (ClockAnchor, self.on_anchor),
            (MouthKeys, self.on_mouth),
            (SpeechStarted, self.on_speech_started),
            (SpeechFinished, self.on_speech_ended),
            (SpeechInterrupted, self.on_speech_ended),
            (SpeechFailed, self.on_speech_failed),
        )
        for cls, fn in handlers:
            service.handle(cls, fn)

    def subscriptions(self) -> list[str]:
        subs = []
        for v in self.views:
            a = v.agent
            subs += [
                f"state.{a}.",
                f"event.{a}.",
                f"stream.{a}.eye_state",
                f"stream.{a}.clock_anchor",
                f"stream.{a}.mouth",
            ]
        return subs

    def drain(self) -> int:
        """Handle every message waiting on the service's socket; returns how many were read.

        Eye-state samples are only ever interpolated near the newest ones, so of each agent's samples in
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
            if topic.endswith(b".eye_state"):
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

    def _scene(self, msg: Message) -> LiveScene:
        view = self.by_agent.get(msg.agent)
        if view is None:
            raise Rejected(f"this renderer does not draw agent '{msg.agent}'")
        return view.scene

    def _guard(self, fn: Callable[..., None], *args: Any) -> None:
        try:
            fn(*args)
        except ValueError as exc:
            raise Rejected(str(exc)) from None

    def on_role(self, m: RoleState) -> None:
        self._guard(self._scene(m).set_role, m.role, m.t_ns, m.speaker)
        self.commanded = True

    def on_emotion(self, m: EmotionState) -> None:
        self._guard(self._scene(m).set_emotion, m.name, m.intensity, m.transition_s, m.t_ns)
        self.commanded = True

    def on_head(self, m: HeadState) -> None:
        self._guard(self._scene(m).move_head, m.turn, m.nod, m.tilt, m.duration_s, m.t_ns)
        self.commanded = True

    def on_attention(self, m: AttentionState) -> None:
        self._guard(self._scene(m).attend, m.yaw_deg, m.pitch_deg, m.duration_s, m.t_ns)

    def on_nod(self, m: Nod) -> None:
        self._guard(self._scene(m).nod, m.onset_ns, m.amplitude_deg, m.duration_s)

    def on_eyes(self, m: EyesState) -> None:
        self._guard(self._scene(m).set_eye_mode, m.mode)
        self.commanded = True

    def on_saccade(self, m: Saccade) -> None:
        self._guard(
            self._scene(m).add_saccade,
            m.onset_ns,
            (m.from_yaw_deg, m.from_pitch_deg),
            (m.to_yaw_deg, m.to_pitch_deg),
            m.duration_s,
        )

    def on_eye_state(self, m: EyeState) -> None:
        self._guard(self._scene(m).add_eye_sample, m.t_ns, m.yaw_deg, m.pitch_deg, m.lid, m.mode)

    def on_anchor(self, m: ClockAnchor) -> None:
        self._guard(self._scene(m).add_clock_anchor, m.request_id, m.sample_index, m.sample_rate, m.dac_time_ns)

    def on_mouth(self, m: MouthKeys) -> None:
        self._guard(
            self._scene(m).add_mouth_keys, m.request_id, m.sample_rate, m.sample_index, m.weights, m.reset, m.t_ns
        )

    def on_speech_started(self, m: SpeechStarted) -> None:
        self._guard(self._scene(m).speech_started, m.request_id, m.dac_time_ns)

    def on_speech_ended(self, m: SpeechFinished | SpeechInterrupted) -> None:
        self._guard(self._scene(m).speech_ended, m.request_id, m.played_s, m.t_ns)

    def on_speech_failed(self, m: SpeechFailed) -> None:
        self._guard(self._scene(m).speech_failed, m.request_id, m.t_ns)
