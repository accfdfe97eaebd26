"""The Eyes Alive gaze model: Parameter Generator, Saccade Synthesizer, Attention Monitor, blinks.

`GazeEngine` drives any number of agents on explicit times; `eye_position_at` gives the eye's exact
position along one saccade, for renderers that interpolate from saccade events.
"""

from eca.agent.gaze.engine import GazeEngine
from eca.agent.gaze.events import BlinkOnsets, GazeTick, SaccadeOnsets
from eca.agent.gaze.params import KINDS, MODES, ROLES, GazeParams
from eca.agent.gaze.synth import eye_position_at, saccade_progress, saccade_velocity

__all__ = [
    "GazeEngine", "GazeTick", "SaccadeOnsets", "BlinkOnsets", "GazeParams", "KINDS", "MODES", "ROLES",
    "eye_position_at", "saccade_progress", "saccade_velocity",
]  # fmt: skip
