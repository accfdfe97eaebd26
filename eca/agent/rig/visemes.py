"""Visemes and VRM vowels from the five mouth weights (say_ah, say_oo, say_ee, say_mm, say_ff).

eca's mouth is five flexors, set by the lip-sync from the audio (agent/lipsync/, docs/lipsync.md) or by an
emotion's pose. Rigs that lip-sync by visemes want the 15 Oculus visemes instead, and VRM rigs the five vowels.

Visemes: each of the 14 non-silent visemes has a prototype, the mouth weights its mouth shape has (a small table
in configs/rig.toml [visemes], read off the OVRLipSync / OpenXR XrFaceTrackingVisemeMETA reference images and
Preston Blair's mouth chart). The weights follow the mouth's *shape* and its *activity* separately:

- shape: the cosine similarity of the mouth vector to each prototype, turned into shares by a softmax of
  `sharpness` * similarity (a soft nearest prototype: between two shapes the weights cross-fade, never switch);
- activity: the largest mouth weight over `rest_span`, clipped to 0..1; `sil` takes the rest (1 - activity), so
  a mouth at rest is pure `sil` and the 15 weights always sum to 1, as OVRLipSync's viseme frames do.

Five mouth weights cannot tell the tongue visemes (DD, kk, nn, TH) apart as well as audio can: their prototypes
differ only in how open and spread the lips are, as their reference images do.

VRM vowels (aa, ih, ou, ee, oh): VRM has only vowel mouths, so their shares are the same softmax over the
prototypes of the visemes aa, ih, ou, E, oh alone, and their sum is the mouth's opening: the largest of say_ah,
say_oo, say_ee, times one minus the largest of the closing shapes say_mm, say_ff (a closed or fricative mouth is
shown nearly closed, as on a VRM face without consonant shapes).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from eca.agent.rig.names import N_VISEMES, VISEME_NAMES, VRM_VOWELS

MOUTH_SHAPES: tuple[str, ...] = ("say_ah", "say_oo", "say_ee", "say_mm", "say_ff")  # agent/face/model.py's order
# Similarities lie in 0..1 (mouth weights are never negative), so exp(sharpness * similarity) stays finite for
# any sharpness up to this and the softmax needs no shift.
MAX_SHARPNESS = 300.0
_OPENING = slice(0, 3)  # say_ah, say_oo, say_ee open the mouth
_CLOSING = slice(3, 5)  # say_mm, say_ff close it


@dataclass(frozen=True, eq=False)
class VisemeTable:
    """Viseme prototypes and the two constants of the mapping (configs/rig.toml [visemes])."""

    prototypes: np.ndarray  # (14, 5): VISEME_NAMES[1:] x MOUTH_SHAPES, each row with some weight > 0
    sharpness: float  # softmax gain on the cosine similarity (0 < sharpness <= MAX_SHARPNESS)
    rest_span: float  # mouth weight at which the mouth counts as fully active (> 0)
    vowel_visemes: tuple[str, ...]  # the viseme of each VRM vowel, in VRM_VOWELS order
    _unit_t: np.ndarray = field(init=False, repr=False)
    _vowel_columns: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        prototypes = np.array(self.prototypes, dtype=np.float64)
        if prototypes.shape != (N_VISEMES - 1, len(MOUTH_SHAPES)):
            raise ValueError(f"viseme prototypes need shape ({N_VISEMES - 1}, 5), got {prototypes.shape}")
        if not 0.0 < self.sharpness <= MAX_SHARPNESS:
            raise ValueError(f"sharpness must lie in (0, {MAX_SHARPNESS:g}], got {self.sharpness!r}")
        if len(self.vowel_visemes) != len(VRM_VOWELS):
            raise ValueError(f"need one viseme for each VRM vowel ({', '.join(VRM_VOWELS)})")
        prototypes.flags.writeable = False
        object.__setattr__(self, "prototypes", prototypes)
        # Unit prototypes as columns: a mouth vector times this is its projection on each prototype.
        unit = prototypes / np.linalg.norm(prototypes, axis=1, keepdims=True)
        object.__setattr__(self, "_unit_t", np.ascontiguousarray(unit.T))
        columns = np.array([VISEME_NAMES.index(v) - 1 for v in self.vowel_visemes], dtype=np.intp)
        object.__setattr__(self, "_vowel_columns", columns)

    def weights(self, mouth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(visemes (N, 15) in VISEME_NAMES order, VRM vowels (N, 5) in VRM_VOWELS order) from (N, 5) mouth
        weights in MOUTH_SHAPES order (clipped to 0..1: no mouth shape has a negative weight)."""
        return self.weights_unclipped(np.clip(mouth, 0.0, 1.0))

    def weights_unclipped(self, m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """`weights` of mouth weights already within 0..1 (the retargeter's, once per frame)."""
        norm = np.sqrt(np.einsum("ij,ij->i", m, m))
        # A mouth at rest has no shape; any finite similarity does, since its activity is 0 there.
        gain = self.sharpness / np.maximum(norm, 1e-12)
        e = np.exp((m @ self._unit_t) * gain[:, None])  # softmax numerators; see MAX_SHARPNESS
        activity = np.minimum(m.max(axis=1) * (1.0 / self.rest_span), 1.0)
        visemes = np.empty((m.shape[0], N_VISEMES))
        visemes[:, 0] = 1.0 - activity
        np.multiply(e, (activity / e.sum(axis=1))[:, None], out=visemes[:, 1:])

        opening = m[:, _OPENING].max(axis=1) * (1.0 - m[:, _CLOSING].max(axis=1))
        vowel_e = e[:, self._vowel_columns]
        vowels = vowel_e * (opening / vowel_e.sum(axis=1))[:, None]
        return visemes, vowels
