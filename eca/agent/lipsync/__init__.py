"""Lip-sync from the audio itself: causal per-block estimator, offline tracks, mouth flexor weights."""

from eca.agent.lipsync.config import MOUTH_FLEXORS, VISEMES, LipSyncConfig
from eca.agent.lipsync.estimator import REST_WEIGHTS, LipSyncEstimator, MouthKey, MouthTrack, mouth_track

__all__ = [
    "MOUTH_FLEXORS",
    "REST_WEIGHTS",
    "VISEMES",
    "LipSyncConfig",
    "LipSyncEstimator",
    "MouthKey",
    "MouthTrack",
    "mouth_track",
]
