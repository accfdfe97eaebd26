"""What a GazeEngine tick returns: the eye state of every agent and the onsets since the last tick."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from eca.agent.gaze.params import KINDS

ONSET_FLOAT_FIELDS = (
    "from_yaw_deg", "from_pitch_deg", "to_yaw_deg", "to_pitch_deg",
    "magnitude_deg", "amplitude_deg", "direction_deg", "duration_s", "hold_s",
)  # fmt: skip


@dataclass(frozen=True)
class SaccadeOnsets:
    """Saccades that started since the previous tick, sorted by (onset_ns, agent).

    `magnitude_deg` is the Eyes Alive magnitude drawn for an away saccade (measured from the gaze
    target); `amplitude_deg` and `direction_deg` (0 right, 90 up) describe the eye's actual movement
    from -> to, and the duration follows the amplitude (eq. 2). `kind` indexes KINDS (mutual, away,
    head); `hold_s` is how long the eye then holds the fixation after landing.
    """

    agent: np.ndarray
    onset_ns: np.ndarray
    from_yaw_deg: np.ndarray
    from_pitch_deg: np.ndarray
    to_yaw_deg: np.ndarray
    to_pitch_deg: np.ndarray
    magnitude_deg: np.ndarray
    amplitude_deg: np.ndarray
    direction_deg: np.ndarray
    duration_s: np.ndarray
    kind: np.ndarray
    hold_s: np.ndarray

    def __len__(self) -> int:
        return int(self.agent.size)

    def kind_names(self) -> list[str]:
        return [KINDS[k] for k in self.kind]

    @classmethod
    def from_columns(
        cls, agent: np.ndarray, onset_ns: np.ndarray, kind: np.ndarray, floats: np.ndarray
    ) -> SaccadeOnsets:
        """Build from the agent, onset and kind columns and a (9, len) matrix in ONSET_FLOAT_FIELDS order."""
        columns = dict(zip(ONSET_FLOAT_FIELDS, floats, strict=True))
        return cls(agent=agent, onset_ns=onset_ns, kind=kind, **columns)

    @classmethod
    def empty(cls) -> SaccadeOnsets:
        return cls.from_columns(
            np.empty(0, np.int64), np.empty(0, np.int64), np.empty(0, np.int8),
            np.empty((len(ONSET_FLOAT_FIELDS), 0)),
        )  # fmt: skip


@dataclass(frozen=True)
class BlinkOnsets:
    """Blinks of the statistical blink model that started since the previous tick, sorted by time."""

    agent: np.ndarray
    onset_ns: np.ndarray

    def __len__(self) -> int:
        return int(self.agent.size)

    @classmethod
    def empty(cls) -> BlinkOnsets:
        return cls(np.empty(0, np.int64), np.empty(0, np.int64))


@dataclass(frozen=True)
class GazeTick:
    """Eye state of every agent at `t_ns` (yaw/pitch in degrees, lid 0 open..1 closed) and new onsets.

    `yaw_deg`, `pitch_deg` and `lid` are read-only views of the engine's own eye state, which the engine
    updates in place where it changes: they are valid until the engine's next `tick` or `add_agents`.
    Copy them (`tick.yaw_deg.copy()`) to keep a tick's state past that. The onsets are the caller's own.
    """

    t_ns: int
    yaw_deg: np.ndarray
    pitch_deg: np.ndarray
    lid: np.ndarray
    saccades: SaccadeOnsets
    blinks: BlinkOnsets
