"""DAC-time mapping, sample-rate conversion, and the sinks that need no sound card."""

from __future__ import annotations

import logging
import threading

import numpy as np
import pytest

from eca.agent.clock import VirtualClock
from eca.services.processes.audio import FakeSink, NullSink, Player, PlayerAnchor, PlayerFinished, PlayerStarted, output
from eca.services.processes.audio.clockmap import CallbackStamp, ClockMap
from eca.services.processes.audio.resample import Resampler, resample

SR = 48_000
OFFSET_NS = 5_000_000_000_123  # monotonic - stream clock, unknown to the map


def stamps(n: int, jitter_ns: list[int] | None = None, latency_s: float = 0.02) -> list[CallbackStamp]:
    out = []
    for k in range(n):
        stream_now = 100.0 + k * 0.01
        late = jitter_ns[k] if jitter_ns else 0
        out.append(CallbackStamp(stream_now + latency_s, stream_now,
                                 round(stream_now * 1e9) + OFFSET_NS + late, 480))
    return out


def test_dac_time_maps_to_monotonic_with_the_smallest_recent_offset() -> None:
    rng = np.random.default_rng(0)
    jitter = [0] + [int(v) for v in rng.integers(0, 3_000_000, 299)]  # callbacks run up to 3 ms late
    cmap = ClockMap(SR, 0.02)
    mapped = [cmap.to_monotonic_ns(s) for s in stamps(300, jitter)]
    truth = [round((100.0 + k * 0.01 + 0.02) * 1e9) + OFFSET_NS for k in range(300)]
    # Up to 3 ms of callback jitter shrinks to well under 0.1 ms (the least-delayed callback wins).
    errors = [m - t for m, t in zip(mapped, truth, strict=True)]
    assert min(errors) >= 0 and max(errors) <= 100_000
    assert cmap.fallbacks == 0


@pytest.mark.parametrize("bad", ["zero", "behind", "far", "nan", "backwards"])
def test_implausible_dac_times_fall_back_to_now_plus_latency(bad: str) -> None:
    cmap = ClockMap(SR, 0.02, max_ahead_s=1.0)
    good = stamps(11)
    for s in good[:10]:
        cmap.to_monotonic_ns(s)
    s = good[10]
    dac = {"zero": 0.0, "behind": s.current_time_s - 0.5, "far": s.current_time_s + 5.0,
           "nan": float("nan"), "backwards": good[5].dac_time_s}[bad]
    mapped = cmap.to_monotonic_ns(CallbackStamp(dac, s.current_time_s, s.monotonic_ns, 480))
    expected_fallback = s.monotonic_ns + 20_000_000
    previous_end = round(good[9].dac_time_s * 1e9) + OFFSET_NS + 10_000_000
    assert mapped == max(expected_fallback, previous_end) if bad == "backwards" else expected_fallback
    assert cmap.fallbacks == 1


def test_resampler_is_accurate_and_chunking_does_not_matter() -> None:
    for a, b in ((22_050, 48_000), (48_000, 16_000), (44_100, 48_000)):
        x = np.sin(2 * np.pi * 1000 * np.arange(a) / a)
        y = resample(x, a, b)
        assert abs(len(y) - b) <= 3
        ref = np.sin(2 * np.pi * 1000 * np.arange(len(y)) / b)
        assert np.abs(y[100:-100] - ref[100:-100]).max() < 1e-3
        r = Resampler(a, b)
        rng = np.random.default_rng(1)
        cuts = np.sort(rng.integers(0, len(x), 40))
        parts = [r.process(p) for p in np.split(x, cuts)] + [r.flush()]
        assert np.array_equal(np.concatenate(parts), y)
    same = np.arange(10, dtype=np.float32)
    assert np.array_equal(resample(same, SR, SR), same)


def test_null_sink_plays_in_real_time_and_reports_from_one_thread() -> None:
    done = threading.Event()
    events: list[object] = []
    threads: set[str] = set()

    def on_event(e: object) -> None:
        threads.add(threading.current_thread().name)
        events.append(e)
        if isinstance(e, PlayerFinished):
            done.set()

    with Player(NullSink(SR, 480), on_event) as player:
        player.say_pcm("u", np.full(round(0.2 * SR), 0.1, np.float32), SR)
        assert done.wait(5.0)
    start = next(e for e in events if isinstance(e, PlayerStarted))
    finish = next(e for e in events if isinstance(e, PlayerFinished))
    assert finish.dac_time_ns - start.dac_time_ns == pytest.approx(0.2e9, abs=1e5)
    anchors = [e for e in events if isinstance(e, PlayerAnchor)]
    assert len(anchors) >= 5
    assert len(threads) == 1


def test_no_device_falls_back_to_a_null_sink_with_one_warning(monkeypatch, caplog) -> None:
    import eca.services.processes.audio.sounddevice_sink as sds

    monkeypatch.setattr(sds, "no_output_reason", lambda device=None: "PortAudio lists no output device")
    monkeypatch.setattr(output, "_warned_no_device", False)
    with caplog.at_level(logging.WARNING, logger="eca.services.processes.audio.output"):
        first = output.open_sink(SR, 480)
        second = output.open_sink(SR, 480)
    assert isinstance(first, NullSink) and isinstance(second, NullSink)
    warnings = [r for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 1
    assert "no audio output" in warnings[0].getMessage()
    assert "no output device" in warnings[0].getMessage()


def test_fake_sink_needs_start_and_keeps_time() -> None:
    clock = VirtualClock(7)
    sink = FakeSink(clock, SR, 480)
    with pytest.raises(RuntimeError):
        sink.advance(1)
    sink.start(lambda out, stamp: out.fill(0.25))
    played = sink.advance(3)
    assert played.shape == (1440,) and np.all(played == 0.25)
    assert clock.now_ns() == 7 + 30_000_000


def test_audio_config_loads_and_rejects_bad_values() -> None:
    from eca.agent.config import ConfigError, load_toml
    from eca.services.processes.audio.config import AudioConfig

    cfg = AudioConfig.load()
    assert cfg.sample_rate == 48_000 and cfg.block_frames == 960 and cfg.device is None
    assert cfg.anchor_hz >= 60
    data = load_toml("audio")
    data["player"]["anchor_hz"] = 30.0
    with pytest.raises(ConfigError, match="anchor_hz"):
        AudioConfig.from_dict(data)
    data = load_toml("audio")
    data["device"]["latency"] = "medium"
    with pytest.raises(ConfigError, match="latency"):
        AudioConfig.from_dict(data)
