"""The onsets a GazeEngine tick reports: collected batch by batch as events run, sorted once per tick.

Saccades (Eyes Alive launches and the small saccades of fixation.py) and blinks are appended as batches,
each in the order its events ran; a tick takes them all, ordered by one sort of a packed key
(rows.sort_onsets) and gathered once.
"""

from __future__ import annotations

import numpy as np

from eca.agent.gaze.events import BlinkOnsets, SaccadeOnsets
from eca.agent.gaze.rows import sort_onsets

# A batch of saccades: agents, onsets, kinds, and a (9, k) float matrix in events.ONSET_FLOAT_FIELDS order.
SaccadeBatch = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]


class OnsetLog:
    """The saccade and blink onsets since the last tick."""

    def __init__(self) -> None:
        self._saccades: list[SaccadeBatch] = []
        self._blinks: list[tuple[np.ndarray, np.ndarray]] = []

    def add_saccades(self, agents: np.ndarray, onsets: np.ndarray, kinds: np.ndarray, floats: np.ndarray) -> None:
        self._saccades.append((agents, onsets, kinds, floats))

    def add_blinks(self, agents: np.ndarray, onsets: np.ndarray) -> None:
        self._blinks.append((agents, onsets))

    def take_saccades(self, more: list[SaccadeBatch], n_agents: int) -> SaccadeOnsets:
        """Every saccade since the last call, and the batches `more` after them, sorted by (onset, agent)."""
        batches = self._saccades
        batches.extend(more)
        if not batches:
            return SaccadeOnsets.empty()
        if len(batches) == 1:
            agent, onset, kind, floats = batches[0]
        else:
            agent = np.concatenate([batch[0] for batch in batches])
            onset = np.concatenate([batch[1] for batch in batches])
            kind = np.concatenate([batch[2] for batch in batches])
            floats = np.concatenate([batch[3] for batch in batches], axis=1)
        batches.clear()
        order, agent, onset = sort_onsets(agent, onset, n_agents)
        return SaccadeOnsets.from_columns(
            agent, onset, kind.take(order), floats.take(order, axis=1)
        )  # take: several times faster than fancy indexing, most of all on the 2-D floats

    def take_blinks(self, n_agents: int) -> BlinkOnsets:
        """Every blink since the last call, sorted by (onset, agent)."""
        batches = self._blinks
        if not batches:
            return BlinkOnsets.empty()
        if len(batches) == 1:
            agent, onset = batches[0]
        else:
            agent = np.concatenate([batch[0] for batch in batches])
            onset = np.concatenate([batch[1] for batch in batches])
        batches.clear()
        _, agent, onset = sort_onsets(agent, onset, n_agents)
        return BlinkOnsets(agent, onset)
