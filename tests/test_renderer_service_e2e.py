"""End to end with real processes: broker, dialogue, gaze and a headless renderer, each started as
`python -m eca.services.processes.run`.

Commands go in on the bus like any dialogue manager's; what comes back is the renderer's published face
frames, which are exactly what it drew.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from contextlib import ExitStack

import numpy as np
import pytest
import zmq

from eca.agent.face.emotions import load_emotion_table
from eca.agent.face.flexors import FLEXOR_NAMES
from eca.agent.face.settings import load_flexor_units
from eca.agent.gaze.synth import eye_position_at
from eca.protocol.bus import Subscriber
from eca.protocol.client import AgentClient
from eca.protocol.endpoints import BusConfig
from eca.protocol.messages import EmotionState, FaceFrame, RoleState, Saccade
from tests.support.bus import private_bus_config, running

pytestmark = pytest.mark.gl  # draws: the renderer's compiled code is loaded first (conftest.py)

UNITS = load_flexor_units()
EXPRESSION = [n for n in FLEXOR_NAMES if n not in ("look_x", "look_y", "blink_l", "blink_r", "turn", "nod", "tilt")]

try:
    from eca.services.processes.renderer import create_headless_context

    create_headless_context().release()
except Exception as exc:  # pragma: no cover - depends on the machine
    pytest.skip(f"no headless OpenGL here: {exc}", allow_module_level=True)


SUBSCRIBED_NS = 250_000_000  # after its first frame, a renderer's subscriptions have surely reached the publishers


def service_argv(config: BusConfig, name: str, *extra: str) -> list[str]:
    return [sys.executable, "-m", "eca.services.processes.run", name, "--config", str(config.config_path),
            "--instance", config.instance, *extra]


def renderer_argv(config: BusConfig) -> list[str]:
    return service_argv(config, "renderer", "--headless", "--fps", "30", "--size", "96x72", "--no-idle")


class Recorder:
    """Face frames and saccade events, in arrival order."""

    def __init__(self, sub: Subscriber) -> None:
        self.sub = sub
        self.frames: list[FaceFrame] = []
        self.saccades: list[Saccade] = []
        # saccades published well after the renderer's first frame: it had subscribed before it drew, and by then the
        # subscription has reached every publisher (it travels on its own socket, so a saccade that merely arrived
        # after that frame may have left the gaze service before the renderer's subscription got there)
        self.known: list[Saccade] = []

    def clear(self) -> None:
        self.frames.clear()
        self.saccades.clear()
        self.known.clear()

    def until(self, predicate: Callable[[FaceFrame], bool], timeout_s: float = 15.0) -> FaceFrame:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            got = self.sub.recv(deadline - time.monotonic())
            if got is None:
                continue
            if isinstance(got.message, Saccade):
                self.saccades.append(got.message)
                if self.frames and got.message.t_ns > self.frames[0].t_ns + SUBSCRIBED_NS:
                    self.known.append(got.message)
            elif isinstance(got.message, FaceFrame):
                self.frames.append(got.message)
                if predicate(got.message):
                    return got.message
        raise AssertionError(f"no matching face frame within {timeout_s} s ({len(self.frames)} frames)")


def eyes_deg(frame: FaceFrame) -> np.ndarray:
    return np.array([frame.flexors["look_x"] * UNITS.look_x_deg, frame.flexors["look_y"] * UNITS.look_y_deg])


def expected_eyes(saccades: list[Saccade], t_ns: int) -> np.ndarray | None:
    before = [s for s in saccades if s.onset_ns <= t_ns]
    if not before:
        return None
    s = max(before, key=lambda s: s.onset_ns)
    pos = eye_position_at(t_ns, s.onset_ns, (s.from_yaw_deg, s.from_pitch_deg), (s.to_yaw_deg, s.to_pitch_deg),
                          s.duration_s)
    limits = np.array([UNITS.look_x_deg, UNITS.look_y_deg])
    return np.clip(pos, -limits, limits)


def check_trajectory(rec: Recorder) -> int:
    """Every frame from the first saccade the renderer surely knew shows the exact trajectory of the latest saccade
    with onset <= its time; a frame composed just before that saccade's event arrived may show the one before.
    Returns exact matches."""
    frames, saccades = rec.frames, rec.saccades
    exact = late = 0
    assert rec.known, "no saccade came after the renderer's first frame"
    first = min(s.onset_ns for s in rec.known)
    for f in frames:
        if f.frame_ns < first:
            continue
        want = expected_eyes(saccades, f.frame_ns)
        assert want is not None
        if np.allclose(eyes_deg(f), want, atol=1e-6):
            exact += 1
            continue
        # the saccade in force was announced after this frame was drawn: the previous one must be shown
        known = [s for s in saccades if s.onset_ns <= f.frame_ns]
        newest = max(known, key=lambda s: s.onset_ns)
        older = expected_eyes([s for s in saccades if s is not newest], f.frame_ns)
        start = np.array([newest.from_yaw_deg, newest.from_pitch_deg])
        # a renderer that surely knew no saccade before this one showed the gaze's eye states until its event came
        knew_none_before = not any(s.onset_ns < newest.onset_ns for s in rec.known)
        assert knew_none_before or np.allclose(eyes_deg(f), start, atol=1e-6) or (
            older is not None and np.allclose(eyes_deg(f), older, atol=1e-6)), (
            f"frame at {f.frame_ns} shows {eyes_deg(f)}, expected {want}")
        assert f.frame_ns - newest.onset_ns < 100_000_000, "a saccade was missed for more than 100 ms"
        late += 1
    assert exact >= 4 * late
    return exact


def test_commands_reach_the_drawn_face_and_a_killed_renderer_comes_back_with_the_state() -> None:
    surprised = load_emotion_table().pose("surprised")
    with private_bus_config() as config, ExitStack() as stack:
        for name in ("broker", "dialogue", "gaze"):
            _, out = stack.enter_context(running(service_argv(config, name)))
            out.wait_for("ready", 30)
        ctx = zmq.Context()
        sub = Subscriber(ctx, config, ["stream.ada.face_frame", "event.ada.saccade"])
        sub.wait_ready()
        rec = Recorder(sub)
        try:
            with AgentClient(config, agent="ada", ctx=ctx) as client:
                with running(renderer_argv(config)) as (renderer, _):
                    rec.until(lambda f: True, timeout_s=30)
                    # 1. an emotion: its flexors reach the table's targets in the drawn frames
                    client.set_emotion("surprised", 1.0, transition_s=0.2)
                    state = client.expect_state(EmotionState, lambda m: m.name == "surprised")
                    settled = rec.until(lambda f: f.frame_ns > state.t_ns + 1_000_000_000)
                    for name in EXPRESSION:
                        i = FLEXOR_NAMES.index(name)
                        if not np.isnan(surprised[i]):
                            assert settled.flexors[name] == pytest.approx(surprised[i], abs=1e-4), name
                    # 2. a role change: the gaze regime switches at once with a new saccade, drawn on its
                    # exact trajectory
                    client.set_role("talking", speaker="ada")
                    role = client.expect_state(RoleState, lambda m: m.role == "talking")
                    rec.until(lambda f: f.frame_ns > role.t_ns + 1_500_000_000)
                    at_switch = [s for s in rec.saccades if 0 <= s.onset_ns - role.t_ns < 200_000_000]
                    assert at_switch, "the role change started no saccade"
                    assert check_trajectory(rec) >= 20
                    # 3. SIGKILL: no goodbye, no cleanup
                    renderer.kill()
                    renderer.wait(timeout=10)
                killed_at = time.monotonic_ns()
                rec.clear()
                with running(renderer_argv(config)):
                    first = rec.until(lambda f: f.t_ns > killed_at, timeout_s=30)
                    # the restarted renderer's first frame already has the current expression
                    for name in EXPRESSION:
                        i = FLEXOR_NAMES.index(name)
                        if not np.isnan(surprised[i]):
                            assert first.flexors[name] == pytest.approx(surprised[i], abs=1e-4), name
                    rec.until(lambda f: f.t_ns > first.t_ns + SUBSCRIBED_NS)  # its subscriptions are through
                    rec.saccades.clear()
                    rec.known.clear()
                    client.set_role("listening", speaker="user")  # a saccade at once
                    rec.until(lambda f: len(rec.saccades) >= 1 and f.frame_ns > rec.saccades[0].onset_ns + 5e8)
                    assert check_trajectory(rec) >= 5
        finally:
            sub.close()
            ctx.term()
