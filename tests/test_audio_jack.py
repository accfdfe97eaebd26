"""Integration: the player on a real-time-paced PortAudio device (a JACK dummy server): clock anchors, and
the voice blocks copied in the real callback.

PortAudio must initialise after the JACK server is up, so the player runs in a fresh interpreter.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import threading
import time
import uuid
from collections.abc import Iterator

import numpy as np
import pytest
from scipy import stats

PLAY_S = 1.5

CHILD = r"""
import json, sys, threading, time
import numpy as np
from eca.services.processes.audio import PlayerAnchor, Player, PlayerFinished, open_sink

sink = open_sink(48_000, 480)
done = threading.Event()
anchors, lifecycle = [], []

def on_event(e):
    if isinstance(e, PlayerAnchor):
        anchors.append((e.sample_index, e.dac_time_ns, time.monotonic_ns()))
    else:
        lifecycle.append(type(e).__name__)
    if isinstance(e, PlayerFinished):
        done.set()

player = Player(sink, on_event).start()
seconds = float(sys.argv[1])
t = np.arange(round(seconds * 48_000)) / 48_000
player.say_pcm("u", (0.2 * np.sin(2 * np.pi * 220 * t)).astype(np.float32), 48_000)
finished = done.wait(seconds + 5.0)
stream = sink._stream
diag = {"active": bool(stream.active) if stream is not None else None, "status": sink.status_count,
        "queued": len(player._tracks), "records": len(player._records)}
player.close()
print(json.dumps({"sink": type(sink).__name__, "finished": finished, "lifecycle": lifecycle,
                  "anchors": anchors, "fallbacks": getattr(sink, "clock_fallbacks", None), "diag": diag}))
"""


VOICE_CHILD = r"""
import json, sys, threading
import numpy as np
from eca.services.processes.audio import Player, PlayerFinished, PlayerVoiceBlock, open_sink
from eca.services.processes.audio.player import pcm16_bytes

sink = open_sink(48_000, 480)
done = threading.Event()  # the utterance has played (its last block is reported with it)
voice = []

def on_event(e):
    if isinstance(e, PlayerVoiceBlock):
        voice.append(e)
    elif isinstance(e, PlayerFinished) and e.request_id == "u":
        done.set()

player = Player(sink, on_event, publish_voice=True).start()
seconds = float(sys.argv[1])
t = np.arange(round(seconds * 48_000)) / 48_000
x = (0.2 * np.sin(2 * np.pi * 220 * t)).astype(np.float32)
player.say_pcm("u", x, 48_000)
finished = done.wait(seconds + 5.0)
player.close()
ids = [v.request_id for v in voice]
start = ids.index("u") if "u" in ids else len(voice)
track = b"".join(v.pcm for v in voice[start:])
print(json.dumps({"sink": type(sink).__name__, "finished": finished, "said": track[: 2 * len(x)] == pcm16_bytes(x),
                  "silence_after": not any(track[2 * len(x):]), "first_samples": [v.first_sample for v in voice],
                  "dac_ns": [v.dac_time_ns for v in voice]}))
"""


def run_child(code: str, jack_server: str) -> tuple[dict, str]:
    """Run `code` against the JACK server in a fresh interpreter: its JSON result and its stderr."""
    env = {**os.environ, "JACK_DEFAULT_SERVER": jack_server, "JACK_NO_START_SERVER": "1"}
    run = subprocess.run([sys.executable, "-c", code, str(PLAY_S)], capture_output=True, text=True,
                         timeout=60, env=env, cwd=os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    assert run.returncode == 0, run.stderr[-2000:]
    return json.loads(run.stdout.strip().splitlines()[-1]), run.stderr


@pytest.fixture
def jack_server() -> Iterator[str]:
    if shutil.which("jackd") is None or shutil.which("jack_lsp") is None:
        pytest.skip("jackd / jack_lsp not installed (Debian package jackd2)")
    name = f"eca-test-{os.getpid()}-{uuid.uuid4().hex[:8]}"
    env = {**os.environ, "JACK_NO_AUDIO_RESERVATION": "1"}
    # -t: a generous client timeout, so a loaded test machine does not get the client zombified.
    proc = subprocess.Popen(["jackd", "-n", name, "-t", "5000", "-d", "dummy", "-r", "48000", "-p", "480"],
                            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 15.0
        poll = threading.Event()
        while True:  # readiness: jack_lsp succeeds once the server accepts clients
            if proc.poll() is not None:
                pytest.skip(f"jackd exited at start: {proc.stderr.read().decode(errors='replace')[-300:]}")
            ready = subprocess.run(["jack_lsp", "-s", name], capture_output=True, timeout=10, env=env)
            if ready.returncode == 0 and b"playback" in ready.stdout:
                break
            if time.monotonic() > deadline:
                pytest.fail("jackd did not become ready within 15 s")
            poll.wait(0.05)  # polling interval, bounded by the deadline above
        yield name
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=5)


def test_clock_anchors_advance_at_the_wall_clock_rate(jack_server: str) -> None:
    result, stderr = run_child(CHILD, jack_server)
    assert result["sink"] == "SoundDeviceSink", result
    assert result["finished"], (result["lifecycle"], result["diag"], stderr[-1000:])
    # mouth keys go out in pieces as the preparer computes them, the first before any sound
    assert result["lifecycle"][0] == "PlayerMouthKeys"
    assert [k for k in result["lifecycle"] if k != "PlayerMouthKeys"] == ["PlayerStarted", "PlayerFinished"]
    a = np.array(result["anchors"], dtype=np.float64)
    sample, dac_ns, wall_ns = a[:, 0], a[:, 1], a[:, 2]
    span_s = (wall_ns[-1] - wall_ns[0]) / 1e9
    assert span_s > 0.8 * PLAY_S
    assert len(a) / span_s >= 60.0
    # Audio seconds per wall-clock second, from when the anchors arrived: 1 within 1%. Theil-Sen slopes (the
    # median of the pairwise slopes): on a loaded machine a few anchors come late or carry a DAC time the
    # server's clock estimate has not settled yet, and a least-squares line let them tilt it past 1%.
    rate_wall = stats.theilslopes(sample / 48_000, wall_ns / 1e9)[0]
    assert rate_wall == pytest.approx(1.0, rel=0.01)
    # The anchors themselves: DAC time per sample on the monotonic clock, also within 1%.
    rate_dac = stats.theilslopes(sample / 48_000, dac_ns / 1e9)[0]
    assert rate_dac == pytest.approx(1.0, rel=0.01)
    # Each anchor names a DAC time a little ahead of when it was published, never far off.
    lead_ms = (dac_ns - wall_ns) / 1e6
    assert -20.0 < np.median(lead_ms) < 200.0


def test_the_voice_blocks_are_what_the_device_played(jack_server: str) -> None:
    """The copy the real callback keeps of PortAudio's buffer: every sample that sounds once, in order; DAC times
    from the stream's clock, one block apart up to the mapping's corrections (sub-millisecond)."""
    result, _ = run_child(VOICE_CHILD, jack_server)
    assert result["sink"] == "SoundDeviceSink", result
    assert result["finished"] and result["said"] and result["silence_after"]
    # only blocks that sound are reported, the utterance's: one after the other (the silence before it is not)
    first = result["first_samples"]
    assert first and first == [first[0] + 480 * k for k in range(len(first))]
    steps_ms = np.diff(result["dac_ns"]) / 1e6
    assert np.median(steps_ms) == pytest.approx(10.0, abs=0.01)
    # the DAC times come from the device clock's mapping, which a loaded machine nudges now and then;
    # nearly every block still follows the last by its length
    assert np.mean(np.abs(steps_ms - 10.0) < 2.0) >= 0.95, steps_ms
