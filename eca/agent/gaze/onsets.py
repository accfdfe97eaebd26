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
# From this many saccades a tick (a million agents report some fifty thousand) the floats are sorted field
# by field: see _sorted_floats.
FIELD_BY_FIELD = 16384


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
            agent, onset, kind, _ = batches[0]
        else:
            agent = np.concatenate([batch[0] for batch in batches])
            onset = np.concatenate([batch[1] for batch in batches])
            kind = np.concatenate([batch[2] for batch in batches])
        order, agent, onset = sort_onsets(agent, onset, n_agents)
        floats = _sorted_floats(batches, order)
        batches.clear()
        return SaccadeOnsets.from_columns(agent, onset, kind.take(order), floats)

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


def _sorted_floats(batches: list[SaccadeBatch], order: np.ndarray) -> np.ndarray:
    """The batches' float matrices side by side, columns in `order`.

    The gather reads its source in random order: from one matrix of all the fields (megabytes with many
    saccades) nearly every read misses the core's cache. Field by field, each is first copied into one
    scratch row, which the gather then reads from cache. Below FIELD_BY_FIELD saccades the whole matrix
    stays in cache and one gather of it costs fewer numpy calls."""
    if order.size < FIELD_BY_FIELD:
        floats = batches[0][3] if len(batches) == 1 else np.concatenate([batch[3] for batch in batches], axis=1)
        return floats.take(order, axis=1)  # take: several times faster than fancy indexing of 2-D arrays
    out = np.empty((batches[0][3].shape[0], order.size))
    field = np.empty(order.size)
    for j, row in enumerate(out):
        np.concatenate([batch[3][j] for batch in batches], out=field)
        # Any mode but "raise" takes straight into `row` (that one takes into a copy first); `order` holds
        # valid indices, so all modes give the same.
        np.take(field, order, out=row, mode="wrap")
    return out
