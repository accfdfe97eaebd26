"""Where a voice speaks and where it pauses: the stretches of speech of one utterance's samples.

A 10 ms block is silent when its RMS level is more than `silence_below_db` under the utterance's loud
level (its 90th percentile block level), or under an absolute floor; a silence of at least `min_pause_s`
between speech is a pause (Goldman-Eisler 1968's 250 ms by default, configs/backchannel.toml). Shorter
silences, such as the closures of stop consonants, stay inside the speech. Listeners' backchannels
(agent/gaze/backchannel.py) come at these pauses.
"""

from __future__ import annotations

import numpy as np

BLOCK_S = 0.010
SILENCE_BELOW_DB = 25.0  # under the utterance's loud level: speech levels span ~20-30 dB (vowels vs. fricatives)
FLOOR_DB = -55.0  # re full scale: quieter is silence whatever the utterance


def speech_segments(samples: np.ndarray, sample_rate: int, min_pause_s: float,
                    silence_below_db: float = SILENCE_BELOW_DB) -> list[tuple[float, float]]:
    """(start_s, end_s) of each stretch of speech in `samples` (mono, float in [-1, 1] or int16), in order;
    stretches are separated by silences of at least `min_pause_s`."""
    if sample_rate <= 0:
        raise ValueError(f"sample rate must be > 0, got {sample_rate}")
    x = np.asarray(samples)
    x = x.astype(np.float64) / 32768.0 if x.dtype == np.int16 else x.astype(np.float64)
    block = max(1, round(BLOCK_S * sample_rate))
    n = len(x) // block
    if n == 0:
        return []
    power = np.mean(x[: n * block].reshape(n, block) ** 2, axis=1)
    level = 10.0 * np.log10(power + 1e-12)
    loud = float(np.percentile(level, 90))
    voiced = level > max(loud - silence_below_db, FLOOR_DB)
    edges = np.flatnonzero(np.diff(np.concatenate(([0], voiced.astype(np.int8), [0]))))
    runs = [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True)]
    gap = round(min_pause_s / BLOCK_S)
    merged: list[list[int]] = []
    for a, b in runs:
        if merged and a - merged[-1][1] < gap:
            merged[-1][1] = b
        else:
            merged.append([a, b])
    step = block / sample_rate
    return [(a * step, b * step) for a, b in merged]
