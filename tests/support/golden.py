"""Golden images: a picture compared with the one committed under tests/golden/ within a tolerance (RMS, and the
share of pixels changed by more than CHANGED_LEVEL in any channel); ECA_REGEN_GOLDEN=1 writes them afresh, and a
picture out of tolerance is written beside its golden as NAME.actual.png (gitignored) to look at."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

GOLDEN_DIR = Path(__file__).resolve().parent.parent / "golden"
REGENERATE = os.environ.get("ECA_REGEN_GOLDEN", "") not in ("", "0")
CHANGED_LEVEL = 48  # of 255: a pixel counts as changed past this in any channel


def compare(actual: np.ndarray, expected: np.ndarray) -> tuple[float, float]:
    """(RMS of the difference, share of the pixels changed by more than CHANGED_LEVEL)."""
    diff = actual.astype(np.float64) - expected.astype(np.float64)
    rms = float(np.sqrt(np.mean(diff**2)))
    changed = float((np.abs(diff).max(-1) > CHANGED_LEVEL).mean())
    return rms, changed


def check_golden(actual: np.ndarray, name: str, max_rms: float, max_changed: float) -> None:
    """Assert `actual` matches tests/golden/NAME.png within the tolerance (or write it, with ECA_REGEN_GOLDEN=1)."""
    path = GOLDEN_DIR / f"{name}.png"
    if REGENERATE:
        GOLDEN_DIR.mkdir(exist_ok=True)
        Image.fromarray(actual).save(path)
        pytest.skip(f"regenerated {path.name}")
    assert path.exists(), f"{path} is missing; create it with ECA_REGEN_GOLDEN=1"
    expected = np.asarray(Image.open(path).convert("RGB"))
    assert expected.shape == actual.shape
    rms, changed = compare(actual, expected)
    if rms > max_rms or changed > max_changed:
        Image.fromarray(actual).save(path.with_suffix(".actual.png"))
    assert rms <= max_rms, f"{name}: RMS {rms:.2f} > {max_rms} (wrote {path.stem}.actual.png)"
    assert changed <= max_changed, f"{name}: {changed:.1%} of pixels changed (wrote {path.stem}.actual.png)"
