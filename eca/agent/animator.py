"""One agent's face and gaze driven by a script timeline on virtual time (the offline pipeline's models).

The cues are applied at their exact times and the models are sampled at any frame time, so the same
seed and timeline give the same frames at any frame rate. The seed drives only the eyes and the
blinks; the face's idle noise has its own fixed seed, so another seed changes nothing else. Each frame
also says what the models are in at that time (the agent's role and emotion), read back from them
rather than from the script.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from eca.agent.clock import nanoseconds
from eca.agent.face.composed import ComposedFace
from eca.agent.face.model import FaceModel
from eca.agent.face.settings import load_flexor_units
from eca.agent.gaze.backchannel import USER, Backchannel, BackchannelParams, ListenerBlink
from eca.agent.gaze.engine import GazeEngine
from eca.agent.lipsync.estimator import MouthTrack
from eca.agent.script import EmotionCue, GazeCue, HeadCue, RoleCue, Timeline
from eca.agent.vocabulary import BACKCHANNEL_MODES

FACE_IDLE_SEED = 7  # fixed: the render seed changes eyes and blinks only


@dataclass
class Utterance:
    """A line of speech placed on the timeline: its samples, and its mouth track if the agent says it."""

    start_s: float
    samples: np.ndarray
    track: MouthTrack | None


AgentCue = RoleCue | EmotionCue | HeadCue | GazeCue


def head_degrees() -> tuple[float, float]:
    """Degrees of head turn and nod per flexor unit (configs/flexor_units.toml [head])."""
    units = load_flexor_units()
    return units.turn_deg, units.nod_deg


class CueFollower:
    """One agent's face and its row `index` of a gaze engine, moved by that agent's own cues (role, emotion,
    head, gaze). `eyes` fixes the eye mode; None lets the eye-mode cues decide."""

    def __init__(self, face: FaceModel, gaze: GazeEngine, index: int, eyes: str | None,
                 head_deg: tuple[float, float]) -> None:
        self.face, self.gaze, self.index, self.eyes, self.head_deg = face, gaze, index, eyes, head_deg
        self.head = (0.0, 0.0, 0.0)
        self.target = (0.0, 0.0)

    def apply(self, cue: AgentCue, t_ns: int) -> None:
        i = self.index
        if isinstance(cue, RoleCue):
            self.gaze.set_role(i, cue.role, t_ns)
        elif isinstance(cue, EmotionCue):
            self.face.set_emotion(cue.name, cue.intensity, cue.transition_s, t_ns)
            self.gaze.set_emotion(i, cue.name, cue.intensity, t_ns)
        elif isinstance(cue, HeadCue):
            self.head = cue.targets(self.head)
            self.face.move_head(*self.head, cue.duration_s, t_ns)
            self.gaze.set_head(i, self.head[0] * self.head_deg[0], self.head[1] * self.head_deg[1], t_ns)
        elif isinstance(cue, GazeCue):
            if cue.mode is not None and self.eyes is None:
                self.gaze.set_mode(i, cue.mode, t_ns)
            target = cue.target(self.target)
            if target is not None:
                self.target = target
                self.gaze.set_target(i, *target, t_ns)


SpeechEvent = tuple[float, str, bool]  # (t_s, who, started): a speaker's voice starts or stops


class ListenerResponses:
    """The listeners' backchannels (agent/gaze/backchannel.py) at the pauses of a script's speech: fed when
    each speaker's voice starts and stops (found in the audio), it nods the faces and blinks the gaze rows of
    `agents` (rows 0, 1, ... of `gaze`), in the eye modes that have backchannels. A speaker who is not one of
    the agents is the user (a single agent's dialogue partner)."""

    def __init__(self, agents: Sequence[str], faces: Sequence[FaceModel], gaze: GazeEngine, seed: int,
                 speech: Sequence[SpeechEvent], params: BackchannelParams | None = None) -> None:
        self.agents, self.faces, self.gaze = tuple(agents), list(faces), gaze
        self.index = {a: k for k, a in enumerate(self.agents)}
        self.model = Backchannel(self.agents, seed, params)
        self.speech = sorted(speech, key=lambda e: (e[0], e[2]))  # a stop before a start at one instant
        self.next = 0

    def advance(self, t_ns: int) -> None:
        """Feed the speech up to `t_ns` and show the responses due by then."""
        while self.next < len(self.speech) and nanoseconds(self.speech[self.next][0]) <= t_ns:
            at, who, started = self.speech[self.next]
            self.model.speaking(nanoseconds(at), who if who in self.index else USER, started)
            self.next += 1
        for action in self.model.due(t_ns):
            k = self.index[action.agent]
            if self.gaze.mode_of(k) not in BACKCHANNEL_MODES:
                continue  # the paper's conditions stay as they were
            if isinstance(action, ListenerBlink):
                self.gaze.blink_at(k, max(action.t_ns, self.gaze.now_ns))
            else:
                self.faces[k].nod(action.amplitude_deg, action.duration_s, action.t_ns)


def mouth_at(utterances: list[Utterance], sample_rate: int, t_s: float) -> dict[str, float] | None:
    """The mouth shapes of the utterance (with a mouth track) playing at `t_s`, or None."""
    for u in utterances:
        index = (t_s - u.start_s) * sample_rate
        if 0 <= index < u.samples.size:
            assert u.track is not None
            return u.track.weights_at(index)
    return None


class TimelineAnimator:
    def __init__(self, timeline: Timeline, agent: str, *, seed: int, eyes: str | None,
                 utterances: list[Utterance], sample_rate: int, speech: Sequence[SpeechEvent] = (),
                 backchannel: BackchannelParams | None = None) -> None:
        """`eyes` fixes the eye mode; None lets the timeline's own eye-mode cues decide. `speech`: when each
        speaker's voice starts and stops, for the agent's backchannels (configs/backchannel.toml)."""
        self.eyes = eyes
        self.sample_rate = sample_rate
        self.cues = [c for c in timeline.cues if isinstance(c, AgentCue) and c.agent == agent]
        self.next_cue = 0
        self.utterances = [u for u in utterances if u.track is not None]
        self.face = FaceModel(seed=FACE_IDLE_SEED, idle_noise=True)
        self.gaze = GazeEngine(1, seed, start_ns=0)
        if eyes is not None:
            self.gaze.set_mode(0, eyes, 0)
        self.follower = CueFollower(self.face, self.gaze, 0, eyes, head_degrees())
        self.responses = ListenerResponses((agent,), (self.face,), self.gaze, seed, speech, backchannel)

    def frame_at(self, t_s: float) -> ComposedFace:
        """The face at `t_s`, every cue up to it applied; times must not go back."""
        t_ns = nanoseconds(t_s)
        while self.next_cue < len(self.cues) and nanoseconds(self.cues[self.next_cue].t_s) <= t_ns:
            cue = self.cues[self.next_cue]
            self.follower.apply(cue, max(nanoseconds(cue.t_s), self.gaze.now_ns))
            self.next_cue += 1
        self.responses.advance(t_ns)
        tick = self.gaze.tick(t_ns)
        self.face.set_eyes(float(tick.yaw_deg[0]), float(tick.pitch_deg[0]), float(tick.lid[0]))
        self.face.set_mouth(mouth_at(self.utterances, self.sample_rate, t_s))
        return self.face.compose(t_ns, role=self.gaze.role_of(0))
