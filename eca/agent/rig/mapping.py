"""Flexors onto named rig weights: each weight a clipped linear function of the flexors' two directions.

A flexor in [-1, 1] moves a face two ways (smile +: corners up, smile -: corners down), and a rig has a separate
shape for each (MouthSmile, MouthFrown). So the map reads each flexor as two parts, `name+` = max(f, 0) and
`name-` = max(-f, 0), and each output row weighs parts:

    weight = clip(bias + sum of gain * part, 0, 1)

(`bias` is 0 unless a row names it.) Negative gains let one action hold another back (a raised brow keeps the
knit from lowering the brow: worry, not anger). A row may instead be a list of such terms, all of which must
hold: its weight is the smallest of them (a relaxed face needs a smile *and* soft lids; the lips can close over
an open jaw only as far as it is open).

The eye angles enter the same way, in degrees: `eye_l_yaw+` is the left eye's look to the agent's right,
`eye_l_yaw-` to its left, `eye_l_pitch+`/`-` up/down, and likewise `eye_r_...`; the ARKit eyeLook rows are made
from configs/rig.toml [eye_look] this way (config.py).

All rows are one matrix product over the (N, 51) inputs of N faces (`rig_inputs`), then a clip and a few
minimums: cheap enough for every agent of a crowd at every frame.
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from eca.agent.config import ConfigError
from eca.agent.face.flexors import FLEXOR_INDEX, FLEXOR_NAMES, N_FLEXORS

EYE_ANGLES: tuple[str, ...] = ("eye_l_yaw", "eye_l_pitch", "eye_r_yaw", "eye_r_pitch")
PART_NAMES: tuple[str, ...] = tuple(f"{n}+" for n in FLEXOR_NAMES) + tuple(f"{n}-" for n in FLEXOR_NAMES)
INPUT_NAMES: tuple[str, ...] = PART_NAMES + tuple(f"{a}{s}" for a in EYE_ANGLES for s in "+-") + ("bias",)
N_INPUTS = len(INPUT_NAMES)
INPUT_INDEX: dict[str, int] = {name: i for i, name in enumerate(INPUT_NAMES)}


def _split_matrix() -> np.ndarray:
    """(26, 51): [flexors, eye angles, 1] times this, with negatives set to 0, are the inputs."""
    split = np.zeros((N_FLEXORS + len(EYE_ANGLES) + 1, N_INPUTS))
    for i, name in enumerate(FLEXOR_NAMES):
        split[i, INPUT_INDEX[f"{name}+"]] = 1.0
        split[i, INPUT_INDEX[f"{name}-"]] = -1.0
    for j, angle in enumerate(EYE_ANGLES):
        split[N_FLEXORS + j, INPUT_INDEX[f"{angle}+"]] = 1.0
        split[N_FLEXORS + j, INPUT_INDEX[f"{angle}-"]] = -1.0
    split[-1, INPUT_INDEX["bias"]] = 1.0
    return split


_SPLIT = _split_matrix()


def rig_inputs(values: np.ndarray, eyes_deg: np.ndarray) -> np.ndarray:
    """(N, 51) inputs (INPUT_NAMES) of (N, 21) flexor vectors and (N, 4) eye angles [left yaw, left pitch, right
    yaw, right pitch] in degrees: each one's positive and negative part, then a 1 for the bias."""
    n = values.shape[0]
    stacked = np.empty((n, N_FLEXORS + len(EYE_ANGLES) + 1))
    stacked[:, :N_FLEXORS] = values
    stacked[:, N_FLEXORS:-1] = eyes_deg
    stacked[:, -1] = 1.0
    inputs = stacked @ _SPLIT
    return np.maximum(inputs, 0.0, out=inputs)


@dataclass(frozen=True, eq=False)
class FlexorMap:
    """Output names and their terms: output k is the minimum over its terms of clip(inputs @ gains[:, term])."""

    names: tuple[str, ...]
    gains: np.ndarray  # (51, T): one column per term, rows in INPUT_NAMES order
    first: np.ndarray  # (n_outputs,): each output's first term
    more: tuple[tuple[np.ndarray, np.ndarray], ...] = ()  # per further rank: (outputs, their term of that rank)
    _index: dict[str, int] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self.gains.flags.writeable = False
        object.__setattr__(self, "_index", {n: i for i, n in enumerate(self.names)})

    def apply(self, inputs: np.ndarray) -> np.ndarray:
        """(N, n_outputs) weights in 0..1 of (N, 51) inputs (`rig_inputs`)."""
        terms = inputs @ self.gains
        np.maximum(terms, 0.0, out=terms)  # (two ufuncs: np.clip's wrapper costs more than the work here)
        np.minimum(terms, 1.0, out=terms)
        out = terms[:, self.first]
        for outputs, columns in self.more:
            out[:, outputs] = np.minimum(out[:, outputs], terms[:, columns])
        return out

    def row(self, name: str) -> list[dict[str, float]]:
        """The terms of one output as {part: gain} (for reading the map, e.g. in a test or a report)."""
        k = self._index[name]
        columns = [int(self.first[k])] + [int(c[list(o).index(k)]) for o, c in self.more if k in o]
        return [{INPUT_NAMES[p]: float(self.gains[p, c]) for p in np.flatnonzero(self.gains[:, c])} for c in columns]

    @classmethod
    def concat(cls, maps: Sequence[FlexorMap]) -> FlexorMap:
        """One map computing the outputs of several, in order (one matrix product instead of several)."""
        names: list[str] = []
        gains, firsts = [], []
        more: dict[int, tuple[list[np.ndarray], list[np.ndarray]]] = {}
        n_out = n_terms = 0
        for m in maps:
            names.extend(m.names)
            gains.append(m.gains)
            firsts.append(m.first + n_terms)
            for rank, (outputs, columns) in enumerate(m.more):
                slot = more.setdefault(rank, ([], []))
                slot[0].append(outputs + n_out)
                slot[1].append(columns + n_terms)
            n_out += len(m.names)
            n_terms += m.gains.shape[1]
        extra = tuple((np.concatenate(o), np.concatenate(c)) for _, (o, c) in sorted(more.items()))
        return cls(tuple(names), np.hstack(gains), np.concatenate(firsts), extra)


def parse_flexor_map(table: object, names: Sequence[str], where: str) -> FlexorMap:
    """A map from a TOML table with one row per name in `names` (all of them, no others); `where` names the
    file and table for errors. A row is {part = gain, ..., bias = b} (an empty {} is a weight that stays 0) or a
    non-empty list of such terms."""
    if not isinstance(table, Mapping):
        raise ConfigError(f"{where}: must be a table of rows, got {table!r}")
    unknown = [key for key in table if key not in names]
    if unknown:
        close = difflib.get_close_matches(unknown[0], list(names), n=3)
        hint = f"; did you mean {', '.join(close)}?" if close else f"; rows: {', '.join(names)}"
        raise ConfigError(f"{where}: unknown row '{unknown[0]}'{hint}")
    missing = [name for name in names if name not in table]
    if missing:
        raise ConfigError(f"{where}: missing row(s) {', '.join(missing)} (write {{}} for a weight that stays 0)")
    columns: list[np.ndarray] = []
    first: list[int] = []
    ranks: list[tuple[list[int], list[int]]] = []
    for k, name in enumerate(names):
        terms = _terms(table[name], f"{where} {name}")
        for rank, term in enumerate(terms):
            if rank == 0:
                first.append(len(columns))
            else:
                while len(ranks) < rank:
                    ranks.append(([], []))
                ranks[rank - 1][0].append(k)
                ranks[rank - 1][1].append(len(columns))
            columns.append(term)
    gains = np.stack(columns, axis=1) if columns else np.zeros((N_INPUTS, 0))
    more = tuple((np.array(o, dtype=np.intp), np.array(c, dtype=np.intp)) for o, c in ranks)
    return FlexorMap(tuple(names), gains, np.array(first, dtype=np.intp), more)


def _terms(row: object, where: str) -> list[np.ndarray]:
    if isinstance(row, Mapping):
        return [_term(row, where)]
    if isinstance(row, list) and row and all(isinstance(t, Mapping) for t in row):
        return [_term(t, f"{where}[{i}]") for i, t in enumerate(row)]
    raise ConfigError(f"{where}: must be {{part = gain, ...}} or a non-empty list of them, got {row!r}")


def _term(term: Mapping[str, Any], where: str) -> np.ndarray:
    column = np.zeros(N_INPUTS)
    for part, gain in term.items():
        if isinstance(gain, bool) or not isinstance(gain, int | float) or not math.isfinite(gain):
            raise ConfigError(f"{where}: '{part}' must be a finite number, got {gain!r}")
        if part not in INPUT_INDEX:
            name = part.rstrip("+-")
            if name in FLEXOR_INDEX or name in EYE_ANGLES:
                why = f"write '{name}+' or '{name}-' (its positive or negative direction)"
            else:
                why = f"unknown flexor '{name}'; flexors: {', '.join(FLEXOR_NAMES)} (or the eye angles, or bias)"
            raise ConfigError(f"{where}: '{part}': {why}")
        column[INPUT_INDEX[part]] = float(gain)
    return column
