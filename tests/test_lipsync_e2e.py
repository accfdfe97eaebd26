"""Audio to mouth end to end on the bus: the drawn mouth opens within two video frames of the sound.

The same measurement as `bench/lipsync.py` (which reports the figures): broker, dialogue, audio
service (null sink, paced by the monotonic clock) and a headless renderer at 60 fps in threads; say
requests of a vowel after silence; the clock anchors give the DAC time of the first loud sample and
the renderer's published face frames the time the drawn jaw crosses half its opening. The bound is
generous (the target is 10 ms) so that a loaded machine does not fail it while a regression of a
frame or more, e.g. mouth keys placed on the wrong sample or a lost clock anchor, does.
"""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.gl  # draws: the renderer's compiled code is loaded first (conftest.py)

try:
    from eca.services.processes.renderer import create_headless_context

    create_headless_context().release()
except Exception as exc:  # pragma: no cover - depends on the machine
    pytest.skip(f"no headless OpenGL here: {exc}", allow_module_level=True)

FRAME_S = 1.0 / 60.0
BENCH = Path(__file__).resolve().parent.parent / "bench" / "lipsync.py"


def load_bench() -> object:
    spec = importlib.util.spec_from_file_location("bench_lipsync", BENCH)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses and typing look modules up by name
    spec.loader.exec_module(module)
    return module


def test_mouth_opens_within_two_frames_of_the_audio_onset_at_the_dac() -> None:
    bench = load_bench()
    result = bench.bus_offsets_ms(4, timeout_s=10.0)  # type: ignore[attr-defined]
    offsets = result["offsets_ms"]
    assert len(offsets) == 4
    assert not any(math.isnan(o) for o in offsets), offsets  # every onset was seen in the face frames
    assert max(abs(o) for o in offsets) <= 2 * FRAME_S * 1e3, offsets
    # speech-started and the clock anchors describe the same DAC timeline
    assert max(abs(v) for v in result["started_vs_anchor_us"]) <= 1000.0, result


def test_onset_helpers_on_known_data() -> None:
    bench = load_bench()
    anchors = [(4800, 1_100_000_000), (0, 1_000_000_000)]
    assert bench.dac_time_ns(anchors, 48_000, 2400) == pytest.approx(1_050_000_000)  # type: ignore[attr-defined]
    assert bench.dac_time_ns(anchors, 48_000, 9600) == pytest.approx(1_200_000_000)  # type: ignore[attr-defined]
    # frames every 10 ms; the jaw goes 0 -> 0.8 between 1.000 and 1.010 s and stays: half of 0.8 at 1.005 s
    frames = [(round(1e9 + k * 1e7), 0.0 if k <= 0 else 0.8) for k in range(-10, 30)]
    onset = bench.mouth_onset_ns(frames, 1.0e9)  # type: ignore[attr-defined]
    assert onset == pytest.approx(1.005e9)
