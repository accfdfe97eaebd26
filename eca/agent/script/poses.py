"""The flexor pose of an emotion at an intensity, so an emotion element carries a value per flexor."""

from __future__ import annotations

from functools import lru_cache

from eca.agent.face.emotions import EmotionTable, load_emotion_table


@lru_cache(maxsize=1)
def emotion_table() -> EmotionTable:
    return load_emotion_table()


@lru_cache(maxsize=64)
def emotion_pose(name: str, intensity: float) -> tuple[float, ...]:
    """One value per flexor (FLEXOR_NAMES order), NaN where the emotion does not care."""
    return tuple(float(v) for v in emotion_table().pose(name, intensity))
