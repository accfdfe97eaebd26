"""The renderer service in-process (real broker and sockets, EGL headless): bus in, face frames out."""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import zmq

from eca.agent.face.scene import LiveScene
from eca.agent.face.settings import load_flexor_units
from eca.agent.gaze.synth import eye_position_at
from eca.protocol.bus import Publisher, Subscriber
from eca.protocol.endpoints import BusConfig
from eca.protocol.messages import (
    ALL_AGENTS,
    ClockAnchor,
    EmotionState,
    EyeStates,
    FaceFrame,
    HeadState,
    MouthKeys,
    Saccade,
)
from eca.services.processes.renderer.options import RendererOptions, options_from
from eca.services.processes.renderer.service import RendererService
from eca.services.processes.renderer.video import read_video_frames
from tests.support.bus import BrokerThread, ServiceThread, private_bus_config

pytestmark = pytest.mark.gl  # draws: the renderer's compiled code is loaded first (conftest.py)

UNITS = load_flexor_units()
SMALL = (96, 72)

try:
    from eca.services.processes.renderer import create_headless_context

    create_headless_context().release()
except Exception as exc:  # pragma: no cover - depends on the machine
    pytest.skip(f"no headless OpenGL here: {exc}", allow_module_level=True)


@pytest.fixture
def bus() -> Iterator[tuple[BusConfig, Publisher, Subscriber]]:
    with private_bus_config(agents=["ada", "bob"]) as config, BrokerThread(config):
        ctx = zmq.Context()
        pub = Publisher(ctx, config, "test")
        pub.wait_ready()
        sub = Subscriber(ctx, config, ["stream.ada.face_frame", "stream.bob.face_frame"])
        sub.wait_ready()
        try:
            yield config, pub, sub
        finally:
            pub.close()
            sub.close()
            ctx.term()


def frames_until(sub: Subscriber, predicate, timeout_s: float = 10.0) -> list[FaceFrame]:  # noqa: ANN001
    """Face frames received until one satisfies predicate (that one included)."""
    got: list[FaceFrame] = []
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        r = sub.recv(deadline - time.monotonic())
        if r is not None and isinstance(r.message, FaceFrame):
            got.append(r.message)
            if predicate(r.message):
                return got
    raise AssertionError(f"no matching face frame within {timeout_s} s ({len(got)} frames seen)")


def renderer(config: BusConfig, **changes: object) -> RendererService:
    opts = RendererOptions(mode="headless", fps=30.0, size=SMALL, idle_noise=False, progress=False,
                           agents=("ada",))
    for k, v in changes.items():
        setattr(opts, k, v)
    return RendererService(config, opts)


def test_options_come_from_the_config_table_then_the_command_line() -> None:
    extra = '[renderer]\nfps = 24.0\nwidth = 320\nheight = 240\nview = "upper"\n'
    with private_bus_config(extra=extra) as config:
        opts = options_from(config, [])
        assert (opts.fps, opts.size, opts.view, opts.mode) == (24.0, (320, 240), "upper", "auto")
        opts = options_from(config, ["--headless", "--size", "128x96", "--agent", "a", "--agent", "b",
                                     "--seconds", "2", "--fps", "10", "--no-idle"])
        assert (opts.mode, opts.size, opts.agents, opts.total_slots, opts.idle_noise) == (
            "headless", (128, 96), ("a", "b"), 20, False)
        with pytest.raises(ValueError, match="unknown renderer arguments"):
            options_from(config, ["--colour", "red"])
        with pytest.raises(ValueError, match="fps"):
            options_from(config, ["--fps", "0"])
        with pytest.raises(ValueError, match="headless"):
            options_from(config, ["--window", "--video", "x.mp4"])
    with private_bus_config(extra="[renderer]\nspeed = 3\n") as config, pytest.raises(ValueError, match="speed"):
        options_from(config, [])


def test_a_late_renderer_shows_the_current_state_in_its_first_frame(bus) -> None:  # noqa: ANN001
    config, pub, sub = bus
    # states published before the renderer exists: the broker's last-value cache keeps them
    emotion = pub.publish(EmotionState(agent="ada", name="angry", intensity=1.0, transition_s=0.2))
    head = pub.publish(HeadState(agent="ada", turn=0.4, nod=-0.2, tilt=0.0, duration_s=0.3))
    svc = renderer(config)
    with ServiceThread(svc):
        first = frames_until(sub, lambda f: True)[0]
    assert svc.mode == "headless"
    # the very first frame is the face those states give at its display time (transitions included)
    expected = LiveScene(idle_noise=False)
    expected.set_emotion("angry", 1.0, 0.2, emotion.t_ns)
    expected.move_head(0.4, -0.2, 0.0, 0.3, head.t_ns)
    assert first.flexors == pytest.approx(expected.frame_at(first.frame_ns).as_dict(), abs=1e-9)
    assert first.flexors["brows_knit"] != 0.0


def test_frames_show_each_state_and_the_saccade_trajectory(bus) -> None:  # noqa: ANN001
    config, pub, sub = bus
    svc = renderer(config, fps=60.0)
    with ServiceThread(svc):
        frames_until(sub, lambda f: True)
        pub.publish(EmotionState(agent="ada", name="happy", intensity=1.0, transition_s=0.0))
        frames_until(sub, lambda f: f.flexors["smile_l"] == pytest.approx(0.85))
        # a saccade 100 ms ahead, announced now: frames must follow its exact trajectory
        now = time.monotonic_ns()
        pub.publish(EyeStates(agent=ALL_AGENTS, agents=["ada"], yaw_deg=[0.0], pitch_deg=[0.0], lid=[0.0],
                              mode=["saccade"]))
        onset = now + 100_000_000
        sac = Saccade(agent="ada", onset_ns=onset, from_yaw_deg=0.0, from_pitch_deg=0.0, to_yaw_deg=20.0,
                      to_pitch_deg=-10.0, amplitude_deg=22.4, direction_deg=333.4, duration_s=0.2, kind="away")
        pub.publish(sac)
        frames = frames_until(sub, lambda f: f.frame_ns > onset + 300_000_000)
    checked = mid = 0
    for f in frames:
        if f.frame_ns < now + 20_000_000:
            continue  # the eye state may not have arrived yet
        want = eye_position_at(f.frame_ns, onset, (0.0, 0.0), (20.0, -10.0), 0.2)
        assert f.flexors["look_x"] * UNITS.look_x_deg == pytest.approx(want[0], abs=1e-6)
        assert f.flexors["look_y"] * UNITS.look_y_deg == pytest.approx(want[1], abs=1e-6)
        checked += 1
        mid += 1.0 < want[0] < 19.0
    assert checked >= 15 and mid >= 3  # at 60 fps a 200 ms saccade is seen mid-flight several times


def test_the_mouth_follows_the_dac_clock(bus) -> None:  # noqa: ANN001
    config, pub, sub = bus
    svc = renderer(config, fps=60.0)
    with ServiceThread(svc):
        frames_until(sub, lambda f: True)
        start = time.monotonic_ns() + 50_000_000
        rate = 16_000
        n = 100  # 1 s of keys, say_ah a triangle wave
        positions = [k * 160 for k in range(n)]
        ah = [1.0 - abs((k % 20) - 10) / 10 for k in range(n)]
        for k in range(0, n, 16):  # streamed in small messages, as the audio service does
            pub.publish(MouthKeys(agent="ada", request_id="r1", sample_rate=rate, sample_index=positions[k:k + 16],
                                  weights={"say_ah": ah[k:k + 16]}))
        pub.publish(ClockAnchor(agent="ada", request_id="r1", sample_index=0, sample_rate=rate, dac_time_ns=start))
        frames = frames_until(sub, lambda f: f.frame_ns > start + 1_200_000_000)
    spoken = [f for f in frames if start + 10_000_000 < f.frame_ns < start + 980_000_000]
    assert len(spoken) > 20
    for f in spoken:
        sample = (f.frame_ns - start) * rate / 1e9
        k = int(sample // 160)
        frac = sample / 160 - k
        want = ah[k] * (1 - frac) + ah[min(k + 1, n - 1)] * frac
        assert f.flexors["say_ah"] == pytest.approx(want, abs=1e-6)
    assert all(f.flexors["say_ah"] == 0.0 for f in frames if f.frame_ns > start + 1_020_000_000)


def test_headless_video_and_png_frames(bus, tmp_path: Path) -> None:  # noqa: ANN001
    config, pub, sub = bus
    video, pngs = tmp_path / "out" / "face.mp4", tmp_path / "png"
    svc = renderer(config, fps=30.0, size=(160, 120), frames=6, video=str(video), png_dir=str(pngs))
    with ServiceThread(svc):
        deadline = time.monotonic() + 20
        while not svc.stopping and time.monotonic() < deadline:
            sub.recv(0.1)
    assert svc.stopping, "the renderer stops by itself after --frames"
    images = read_video_frames(video)
    assert len(images) == svc.frame_count and 1 <= len(images) <= 6
    assert images[0].shape == (120, 160, 3)
    assert images[0].std() > 10  # a face, not a blank frame
    written = sorted(pngs.glob("frame_*.png"))
    assert len(written) == svc.frame_count
    from PIL import Image

    png = np.asarray(Image.open(written[0]))
    assert png.shape == (120, 160, 3) and png.std() > 10


def test_two_agents_side_by_side(bus, tmp_path: Path) -> None:  # noqa: ANN001
    config, pub, sub = bus
    pub.publish(EmotionState(agent="bob", name="surprised", intensity=1.0, transition_s=0.0))
    svc = renderer(config, agents=("ada", "bob"), size=(192, 72), frames=3, png_dir=str(tmp_path))
    with ServiceThread(svc):
        seen: dict[str, FaceFrame] = {}
        frames_until(sub, lambda f: seen.setdefault(f.agent, f) is not None and len(seen) == 2)
    assert seen["bob"].flexors["brow_l"] > 0.5 and seen["ada"].flexors["brow_l"] < 0.3
    from PIL import Image

    img = np.asarray(Image.open(sorted(tmp_path.glob("*.png"))[0])).astype(float)
    left, right = img[:, :96], img[:, 96:]
    assert left.std() > 10 and right.std() > 10  # a face in each half
    assert np.abs(left - right[:, ::-1]).mean() > 1  # not one face mirrored: different expressions and turns
