"""Scoring lip-sync against phoneme-labelled speech (espeak-ng mnemonics, as `espeak-ng -x` prints them).

Each 10 ms key is labelled with the phoneme sounding at the middle of its block and scored against
the mouth-shape class that phoneme calls for. Phonemes without a clear single shape (schwa, r, l, t,
d, k, g, n, h, mid vowels) are left out. A stop (p, b) is scored over the first half of its segment
only: that is the closure, with the lips pressed; the second half is the release burst.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass

from eca.agent.lipsync.estimator import MouthKey

CLASSES: tuple[str, ...] = ("open", "rounded", "spread", "closed", "fricative")

PHONEME_CLASS: dict[str, str] = {
    **dict.fromkeys(("a", "a#", "A:", "A@", "aI", "aU", "V", "0", "a:"), "open"),
    **dict.fromkeys(("u:", "U", "O:", "O", "o", "oU", "O@", "U@", "w"), "rounded"),
    **dict.fromkeys(("i:", "i", "I", "I2", "i@", "j"), "spread"),
    **dict.fromkeys(("m", "b", "p"), "closed"),
    **dict.fromkeys(("s", "z", "f", "v", "S", "Z", "T"), "fricative"),
}
_STOPS = ("p", "b")


@dataclass(frozen=True)
class Agreement:
    counts: dict[str, Counter[str]]  # true class -> predicted viseme counts

    def share(self, cls: str) -> float:
        total = sum(self.counts.get(cls, Counter()).values())
        return self.counts[cls][cls] / total if total else float("nan")

    def n(self, cls: str) -> int:
        return sum(self.counts.get(cls, Counter()).values())

    def merged(self, other: Agreement) -> Agreement:
        counts = {c: Counter(self.counts.get(c, Counter())) + other.counts.get(c, Counter()) for c in CLASSES}
        return Agreement(counts)


def score(keys: Iterable[MouthKey], phonemes: Sequence[tuple[str, int]], sample_rate: int) -> Agreement:
    """`phonemes`: (mnemonic, first sample) in time order, as espeak's phoneme events give them."""
    counts: dict[str, Counter[str]] = {c: Counter() for c in CLASSES}
    for key, cls in labelled(keys, phonemes, sample_rate):
        counts[cls][key.viseme] += 1
    return Agreement(counts)


# The Oculus visemes (agent/rig) that show each scored class. Five mouth weights tell the classes apart, not the
# consonants within one (eca/agent/rig/visemes.py): a fricative may show as FF, SS, TH or CH.
CLASS_VISEMES: dict[str, frozenset[str]] = {
    "open": frozenset({"aa"}),
    "rounded": frozenset({"ou", "oh"}),
    "spread": frozenset({"ih", "E"}),
    "closed": frozenset({"PP"}),
    "fricative": frozenset({"FF", "SS", "TH", "CH"}),
}


def score_visemes(keys: Iterable[MouthKey], phonemes: Sequence[tuple[str, int]], sample_rate: int,
                  viseme_of: Callable[[Sequence[MouthKey]], Sequence[str]]) -> Agreement:
    """As `score`, for the viseme a rig is sent: `viseme_of` gives each key's strongest viseme (from its mouth
    weights, through the retargeting); a key agrees when that viseme shows its phoneme's class."""
    pairs = list(labelled(keys, phonemes, sample_rate))
    shown = viseme_of([key for key, _ in pairs])
    counts: dict[str, Counter[str]] = {c: Counter() for c in CLASSES}
    for (_, cls), viseme in zip(pairs, shown, strict=True):
        counts[cls][cls if viseme in CLASS_VISEMES[cls] else viseme] += 1
    return Agreement(counts)


def labelled(keys: Iterable[MouthKey], phonemes: Sequence[tuple[str, int]],
             sample_rate: int) -> Iterator[tuple[MouthKey, str]]:
    """Each scored key with the class of the phoneme at the middle of its block (see the module docstring)."""
    starts = [p[1] for p in phonemes]
    half_block = sample_rate // 200
    j = -1
    for key in keys:
        mid = key.sample_index + half_block
        while j + 1 < len(starts) and starts[j + 1] <= mid:
            j += 1
        if j < 0:
            continue
        name = phonemes[j][0]
        cls = PHONEME_CLASS.get(name)
        if cls is None:
            continue
        if name in _STOPS and j + 1 < len(starts) and mid > (starts[j] + starts[j + 1]) / 2:
            continue
        yield key, cls
