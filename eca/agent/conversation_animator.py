"""The agents of one dialogue on virtual time: their faces, one gaze engine, and who looks at whom.

The offline pipeline's models for a dialogue of several agents (docs/scripts.md). Each agent follows its own
cues as the single-agent animator's agent does (agent/animator.py: role, emotion, head, gaze), all share one
GazeEngine (a row each, in seat order), and a situated Conversation (agent/gaze/situated.py) turns each
TurnCue of the timeline into the people each agent's gaze chooses among, forced gaze shifts, and a head turn
toward the person attended. Its later actions (a speaker looking back near the end of a long turn) are
applied at their own times, before any cue or frame after them.

The people sit where they sit, whatever the head does. The engine aims the eyes in the frame of the head
the situated model turns toward the person attended (agent/gaze/situated.py), but the head the face shows
differs from it: on its way there (a turn takes a fraction of a second), and by what the other head layers
add (an emotion's posture, a scripted move, a nod, idle noise). The eyes are shown counter-rotated by that
difference, within their range, so the gaze (eyes plus head) points where the gaze model aims: it lands on
a person at once and stays there while the head follows or moves, as the vestibulo-ocular reflex holds it
(eye-head gaze shifts: the eyes lead, the head follows; Freedman & Sparks 1997). The frames report the eyes
as shown.

Listeners answer pauses in whoever speaks (`speech`: when each speaker's voice starts and stops, from the
audio) with nods and blinks (agent/gaze/backchannel.py), in the eye modes that have them.

The same seed and timeline give the same frames at any frame rate. The seed drives the eyes, the blinks and
the choices of who is looked at; each face's idle noise has a fixed seed of its own (the first agent's is
the single-agent animator's).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from eca.agent.animator import (
    FACE_IDLE_SEED,
    AgentCue,
    CueFollower,
    ListenerResponses,
    SpeechEvent,
    Utterance,
    head_degrees,
    mouth_at,
)
from eca.agent.clock import nanoseconds
from eca.agent.face.composed import ComposedFace
from eca.agent.face.model import FaceModel
from eca.agent.gaze.backchannel import BackchannelParams
from eca.agent.gaze.engine import GazeEngine
from eca.agent.gaze.events import GazeTick
from eca.agent.gaze.situated import USER, Action, Conversation, SituatedParams, apply
from eca.agent.script import Timeline, TurnCue


@dataclass(frozen=True)
class ConversationFrame:
    """Every agent's face at one time (seat order), and whose turn it is: `speaker` (an agent or the user)
    speaking to `addressees`, or None between turns and in silences."""

    faces: tuple[ComposedFace, ...]
    speaker: str | None
    addressees: tuple[str, ...]


class ConversationAnimator:
    def __init__(self, timeline: Timeline, agents: Sequence[str], *, seed: int, eyes: str | None,
                 utterances: Mapping[str, list[Utterance]], sample_rate: int,
                 situated: SituatedParams | None = None, speech: Sequence[SpeechEvent] = (),
                 backchannel: BackchannelParams | None = None) -> None:
        """`agents` in seat order, left to right; `eyes` fixes every agent's eye mode (None: the timeline's
        eye-mode cues decide); `utterances` are each agent's own lines (with mouth tracks); `situated` the
        constants of configs/conversation.toml; `speech` when each speaker's voice starts and stops (agents
        and the user); `backchannel` the constants of configs/backchannel.toml."""
        self.agents = tuple(agents)
        if not self.agents or len(set(self.agents)) != len(self.agents) or USER in self.agents:
            raise ValueError(f"a conversation needs distinct agents other than {USER!r}, got {list(agents)!r}")
        self.index = {agent: k for k, agent in enumerate(self.agents)}
        self.sample_rate = sample_rate
        self.cues = [c for c in timeline.cues
                     if isinstance(c, TurnCue) or (isinstance(c, AgentCue) and c.agent in self.index)]
        self.next_cue = 0
        self.utterances = [[u for u in utterances.get(agent, []) if u.track is not None] for agent in self.agents]
        self.gaze = GazeEngine(len(self.agents), seed, start_ns=0)
        if eyes is not None:
            self.gaze.set_mode(np.arange(len(self.agents)), eyes, 0)
        self.faces = [FaceModel(seed=FACE_IDLE_SEED + k, idle_noise=True) for k in range(len(self.agents))]
        head_deg = head_degrees()
        self.followers = [CueFollower(face, self.gaze, k, eyes, head_deg) for k, face in enumerate(self.faces)]
        self.conversation = Conversation(self.agents, seed, situated)
        self.turn: TurnCue | None = None
        self.responses = ListenerResponses(self.agents, self.faces, self.gaze, seed, speech, backchannel)

    def frame_at(self, t_s: float) -> ConversationFrame:
        """Every agent's face at `t_s`, every cue and situated action up to it applied; times must not go
        back."""
        t_ns = nanoseconds(t_s)
        while self.next_cue < len(self.cues) and nanoseconds(self.cues[self.next_cue].t_s) <= t_ns:
            cue = self.cues[self.next_cue]
            at = max(nanoseconds(cue.t_s), self.gaze.now_ns)
            self._act(self.conversation.due(at))
            if isinstance(cue, TurnCue):
                self.turn = cue
                self._act(self.conversation.start_turn(at, cue.speaker, cue.addressees, cue.duration_s))
            else:
                self.followers[self.index[cue.agent]].apply(cue, at)
            self.next_cue += 1
        self._act(self.conversation.due(t_ns))
        self.responses.advance(t_ns)
        tick = self.gaze.tick(t_ns)
        faces = tuple(self._face(k, tick, t_s) for k in range(len(self.agents)))
        turn = self.turn
        if turn is None or turn.speaker is None or t_ns >= nanoseconds(turn.t_s + turn.duration_s):
            return ConversationFrame(faces, None, ())
        return ConversationFrame(faces, turn.speaker, turn.addressees)

    def _act(self, actions: list[Action]) -> None:
        for head in apply(self.gaze, actions, self.index):
            self.faces[self.index[head.agent]].attend(head.yaw_deg, head.pitch_deg, head.duration_s, head.t_ns)

    def _face(self, k: int, tick: GazeTick, t_s: float) -> ComposedFace:
        face = self.faces[k]
        face.set_eyes(float(tick.yaw_deg[k]), float(tick.pitch_deg[k]), float(tick.lid[k]))
        face.set_mouth(mouth_at(self.utterances[k], self.sample_rate, t_s))
        # The eyes were aimed from the head turned toward the person attended: shown counter-rotated for the
        # head shown (FaceModel.compose).
        return face.compose(tick.t_ns, role=self.gaze.role_of(k), eyes_hold_attention=True)
