"""The eye modes besides the saccades' own motion: static eyes, Perlin noise, and Perlin's blinks.

Mode static holds the gaze target; mode noise moves the eyes around it by Perlin noise (the paper's
conditions a and b); modes noise and saccade blink by Perlin's formula (noise.perlin_blink), the others by
the statistical blink model (blink_timers.py) or not at all. A tick rewrites these modes' agents entirely
(their eyes move every tick), found through the state's per-mode member lists; the saccade modes' eyes
are written where they change (engine.py). `shown_position` gives where any agent's eye is at an instant,
whatever its mode, for a switch of mode.
"""

from __future__ import annotations

import numpy as np

from eca.agent.gaze.fixation import Fixations
from eca.agent.gaze.launch import Launcher
from eca.agent.gaze.params import FIXATIONAL, NOISE, SACCADE, STATIC, GazeParams
from eca.agent.gaze.rows import END, TARGET_PITCH, TARGET_YAW
from eca.agent.gaze.state import GazeState
from eca.agent.noise import perlin1d, perlin_blink


class EyeModes:
    """The eyes and lids of the agents in modes static, noise and saccade, and any eye's shown position."""

    def __init__(
        self,
        params: GazeParams,
        state: GazeState,
        launcher: Launcher,
        fixations: Fixations,
        noise_seed: int,
        perlin_blink_seed: int,
    ) -> None:
        self._params = params
        self._state = state
        self._launcher = launcher
        self._fixations = fixations
        self._noise_seed = noise_seed
        self._perlin_blink_seed = perlin_blink_seed

    def write(self, t: int, yaw: np.ndarray, pitch: np.ndarray, lid: np.ndarray) -> None:
        """Write the eyes of the agents in modes static and noise at `t`, and the Perlin blinks' lids."""
        state = self._state
        static = state.members(STATIC)
        if static.size:
            floats = state.rows.view(np.float64)
            yaw[static], pitch[static] = floats[static, TARGET_YAW], floats[static, TARGET_PITCH]
        noisy = state.members(NOISE)
        if noisy.size:
            yaw[noisy], pitch[noisy] = self._noise_position(noisy, t)
        for mode in (NOISE, SACCADE):
            members = state.members(mode)
            if members.size:
                lid[members] = perlin_blink(t * 1e-9, self._perlin_blink_seed, members.astype(np.uint64))

    def shown_position(self, idx: np.ndarray, t: int) -> tuple[np.ndarray, np.ndarray]:
        """Where each eye is at `t` in its current mode."""
        state = self._state
        rows = state.rows[idx]
        stale = state.flight_stale  # only looking: nothing is relaunched here
        position = np.empty((2, idx.size))
        self._launcher.position(rows, np.full(idx.size, t, dtype=np.int64), position)
        state.flight_stale = stale
        yaw, pitch = position
        mode = state.mode[idx]
        static = mode == STATIC
        floats = rows.view(np.float64)
        yaw[static], pitch[static] = floats[static, TARGET_YAW], floats[static, TARGET_PITCH]
        noisy = mode == NOISE
        if noisy.any():
            yaw[noisy], pitch[noisy] = self._noise_position(idx[noisy], t)
        held = np.flatnonzero((mode == FIXATIONAL) & (rows[:, END] <= t))
        if held.size:
            off_yaw, off_pitch = self._fixations.offsets(idx[held])
            yaw[held] = self._clip(yaw[held] + off_yaw, self._params.eye_yaw_limit_deg)
            pitch[held] = self._clip(pitch[held] + off_pitch, self._params.eye_pitch_limit_deg)
        return yaw, pitch

    def _noise_position(self, idx: np.ndarray, t: int) -> tuple[np.ndarray, np.ndarray]:
        p = self._params
        floats = self._state.rows.view(np.float64)
        x = t * 1e-9 * p.noise_frequency_hz
        stream = idx.astype(np.uint64) * np.uint64(2)
        yaw = floats[idx, TARGET_YAW] + p.noise_yaw_amplitude_deg * perlin1d(x, self._noise_seed, stream)
        pitch = floats[idx, TARGET_PITCH] + p.noise_pitch_amplitude_deg * perlin1d(
            x, self._noise_seed, stream + np.uint64(1)
        )
        return self._clip(yaw, p.eye_yaw_limit_deg), self._clip(pitch, p.eye_pitch_limit_deg)

    @staticmethod
    def _clip(values: np.ndarray, limit: float) -> np.ndarray:
        return np.clip(np.asarray(values, dtype=np.float64), -limit, limit)
