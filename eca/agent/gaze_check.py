"""Who looks at whom in a rendered conversation, measured from where the eyes and head point.

For each frame and agent the gaze direction is the eyes' direction in the head plus the head's (yaw and
pitch in degrees, in the agent's body frame, which faces the user). The person looked at is the one whose
seat lies nearest that direction (configs/conversation.toml [seats], as agent/gaze/situated.py places
them), if within `tolerance_deg`; otherwise the agent looks at nobody (away, or between people).

This is measured on what is drawn, not read from the gaze model's state, so it checks the whole pipeline
(seats, head turns, eye angles, their signs) and counts what a viewer sees: an away glance that stays near
the speaker counts as looking at the speaker, and a person beyond the eyes' reach from where the head points
is not reached. Vertegaal et al. (2001) report who is looked at while people look at someone; the share of
those frames (`of_looks`) is that figure's counterpart, the share of all frames (`share`) is lower by the
time spent looking at nobody.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from eca.agent.gaze.situated import USER, Conversation, SituatedParams

NOBODY = -1
# Default tolerance: wider than the scans over a partner's face (eyes +-1.8 deg, mouth 4 deg below:
# configs/gaze.toml) plus the head's idle noise (about 1 deg), narrower than half the 23 deg between the
# nearest two seats seen from an end seat (32 and 55 deg): each direction is near at most one person. eca's.
DEFAULT_TOLERANCE_DEG = 8.0


@dataclass(frozen=True)
class LookCounts:
    """Frames of one agent in one role: at the person it should look at (the speaker, or an addressee), at
    another person, at nobody."""

    frames: int
    at_target: int
    at_other: int

    @property
    def elsewhere(self) -> int:
        return self.frames - self.at_target - self.at_other

    @property
    def share(self) -> float:
        """Of all its frames in that role, the share at the target (NaN without frames)."""
        return self.at_target / self.frames if self.frames else float("nan")

    @property
    def of_looks(self) -> float:
        """Of its frames looking at some person, the share at the target (NaN without any)."""
        looks = self.at_target + self.at_other
        return self.at_target / looks if looks else float("nan")

    def __add__(self, other: LookCounts) -> LookCounts:
        return LookCounts(self.frames + other.frames, self.at_target + other.at_target, self.at_other + other.at_other)


@dataclass(frozen=True)
class GazeCheck:
    """Per agent (seat order): as a listener, frames at the current speaker; as a speaker, frames at one of
    its addressees. Frames between turns and in silences count in neither."""

    agents: tuple[str, ...]
    listening: tuple[LookCounts, ...]
    speaking: tuple[LookCounts, ...]

    @property
    def all_listening(self) -> LookCounts:
        return sum(self.listening, LookCounts(0, 0, 0))

    @property
    def all_speaking(self) -> LookCounts:
        return sum(self.speaking, LookCounts(0, 0, 0))


def looked_at(agents: Sequence[str], agent: str, yaw_deg: np.ndarray, pitch_deg: np.ndarray,
              tolerance_deg: float = DEFAULT_TOLERANCE_DEG, params: SituatedParams | None = None) -> np.ndarray:
    """Per frame, the index in (*agents, USER) of the person `agent` looks at (gaze directions in its body
    frame, degrees), or NOBODY."""
    seats = Conversation(agents, seed=0, params=params)
    people = seats.people
    directions = np.array([seats.direction(agent, p) if p != agent else (np.inf, np.inf) for p in people])
    distance = np.hypot(np.asarray(yaw_deg)[:, None] - directions[:, 0],
                        np.asarray(pitch_deg)[:, None] - directions[:, 1])
    nearest = np.argmin(distance, axis=1)
    return np.where(distance[np.arange(nearest.size), nearest] <= tolerance_deg, nearest, NOBODY)


def check_gaze(agents: Sequence[str], speaker: Sequence[str | None], addressees: Sequence[Sequence[str]],
               gaze_yaw_deg: np.ndarray, gaze_pitch_deg: np.ndarray, tolerance_deg: float = DEFAULT_TOLERANCE_DEG,
               params: SituatedParams | None = None) -> GazeCheck:
    """Count who looks at whom. `speaker[k]` holds the turn at frame k (an agent, the user, or None),
    speaking to `addressees[k]`; `gaze_*_deg[a, k]` is agent a's gaze (eyes plus head) at frame k."""
    agents = tuple(agents)
    people = (*agents, USER)
    if not tolerance_deg > 0:
        raise ValueError(f"the tolerance must be an angle > 0 degrees, got {tolerance_deg!r}")
    n_frames = len(speaker)
    if gaze_yaw_deg.shape != (len(agents), n_frames) or gaze_pitch_deg.shape != gaze_yaw_deg.shape:
        raise ValueError(f"gaze arrays must be (agents, frames) = ({len(agents)}, {n_frames})")
    speaker_index = np.array([people.index(s) if s is not None else NOBODY for s in speaker])
    listening, speaking = [], []
    for a, agent in enumerate(agents):
        person = looked_at(agents, agent, gaze_yaw_deg[a], gaze_pitch_deg[a], tolerance_deg, params)
        listens = (speaker_index != NOBODY) & (speaker_index != a)
        at_speaker = listens & (person == speaker_index)
        at_someone = listens & (person != NOBODY)
        listening.append(LookCounts(int(listens.sum()), int(at_speaker.sum()), int((at_someone & ~at_speaker).sum())))
        speaks = np.flatnonzero(speaker_index == a)
        at_addressee = sum(person[k] != NOBODY and people[person[k]] in addressees[k] for k in speaks.tolist())
        at_anyone = int(np.count_nonzero(person[speaks] != NOBODY))
        speaking.append(LookCounts(int(speaks.size), int(at_addressee), at_anyone - int(at_addressee)))
    return GazeCheck(agents, tuple(listening), tuple(speaking))
