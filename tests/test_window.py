"""The interactive window under Xvfb: it opens, renders, turns key presses into bus commands, closes."""

from __future__ import annotations

import os
import shutil
import subprocess
import threading
import time
from collections.abc import Callable, Iterator

import glfw
import pytest
import zmq

from eca.protocol.bus import Publisher, Subscriber
from eca.protocol.messages import FaceFrame, Message, MoveHead, SetEmotion, SetEyes, SetRole
from eca.services.processes.dialogue import DialogueService
from eca.services.processes.renderer import read_rgb
from eca.services.processes.renderer.options import RendererOptions
from eca.services.processes.renderer.service import RendererService
from eca.services.processes.renderer.window import EMOTION_KEYS, AgentStatus, LocalAction, action_for_key
from tests.support.bus import BrokerThread, ServiceThread, private_bus_config

pytestmark = pytest.mark.gl  # draws: the renderer's compiled code is loaded first (conftest.py)


def test_keys_stand_for_commands_given_the_agent_state() -> None:
    st = AgentStatus(agent="ada", emotion="happy", intensity=0.5, role="listening", eye_mode="saccade+blink",
                     head=(0.0, 0.2, 0.0))
    assert action_for_key("3", st) == SetEmotion(agent="ada", name="surprised", intensity=0.5, transition_s=0.5)
    assert [action_for_key(str(k), st).name for k in range(1, 10)] == list(EMOTION_KEYS)  # type: ignore[union-attr]
    assert action_for_key("+", st).intensity == pytest.approx(0.6)  # type: ignore[union-attr]
    assert action_for_key("-", AgentStatus("ada", intensity=0.0)).intensity == 0.0  # type: ignore[union-attr]
    assert action_for_key("t", st) == SetRole(agent="ada", role="talking", speaker="ada")
    assert action_for_key("t", AgentStatus("ada", role="talking")).role == "listening"  # type: ignore[union-attr]
    assert action_for_key("e", st) == SetEyes(agent="ada", mode="saccade+noise+blink")
    last = AgentStatus("ada", eye_mode="saccade+noise+blink")
    assert action_for_key("e", last) == SetEyes(agent="ada", mode="static")
    assert action_for_key("e", AgentStatus("ada", eye_mode="noise")).mode == "saccade"  # type: ignore[union-attr]
    left = action_for_key("left", st)
    assert isinstance(left, MoveHead) and (left.turn, left.nod) == (0.25, 0.2)  # the agent's right: screen left
    assert action_for_key("down", AgentStatus("ada", head=(0.0, -1.0, 0.0))).nod == -1.0  # type: ignore[union-attr]
    assert action_for_key("0", st) == MoveHead(agent="ada", turn=0.0, nod=0.0, tilt=0.0, duration_s=0.6)
    assert action_for_key("w", st) == LocalAction("wireframe")
    assert action_for_key("v", st) == LocalAction("view")
    assert action_for_key("z", st) is None


@pytest.fixture
def xvfb_display(monkeypatch: pytest.MonkeyPatch) -> Iterator[str]:
    """A private Xvfb server on a display number it picks itself (-displayfd)."""
    if shutil.which("Xvfb") is None:
        pytest.skip("Xvfb is not installed (Debian: apt-get install xvfb)")
    read_fd, write_fd = os.pipe()
    proc = subprocess.Popen(["Xvfb", "-displayfd", str(write_fd), "-screen", "0", "800x600x24", "-nolisten", "tcp"],
                            pass_fds=(write_fd,), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    os.close(write_fd)
    try:
        with os.fdopen(read_fd) as pipe:
            number = pipe.readline().strip()  # Xvfb writes the number once it accepts connections
        if not number:
            pytest.skip("Xvfb did not start")
        monkeypatch.setenv("DISPLAY", f":{number}")
        monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
        yield f":{number}"
    finally:
        proc.terminate()
        proc.wait(timeout=10)


def pump(svc: RendererService, until, timeout_s: float = 10.0) -> None:  # noqa: ANN001
    deadline = time.monotonic() + timeout_s
    while not until():
        assert time.monotonic() < deadline, "timed out"
        svc.run_once()


def in_fresh_thread(fn: Callable[[], None], timeout_s: float = 60.0) -> None:
    """Run fn in a thread of its own and re-raise what it raised. A thread where another test made an EGL
    context current cannot make a GLX context current (X error BadAccess), so the window gets a clean one."""
    errors: list[BaseException] = []

    def run() -> None:
        try:
            fn()
        except BaseException as exc:  # re-raised in the test's thread
            errors.append(exc)

    thread = threading.Thread(target=run, name="window-test")
    thread.start()
    thread.join(timeout_s)
    assert not thread.is_alive(), "the window scenario hung"
    if errors:
        raise errors[0]


def test_window_opens_renders_sends_key_commands_and_closes(xvfb_display: str) -> None:
    in_fresh_thread(window_scenario)


def window_scenario() -> None:
    with private_bus_config() as config, BrokerThread(config), ServiceThread(DialogueService(config)):
        ctx = zmq.Context()
        sub = Subscriber(ctx, config, ["cmd.ada.", "stream.ada.face_frame"])
        sub.wait_ready()
        seen: list[Message] = []

        def seen_one(kind: type, check=lambda m: True) -> bool:  # noqa: ANN001
            seen.extend(r.message for r in sub.drain() if r.message is not None)
            return any(isinstance(m, kind) and check(m) for m in seen)

        svc = RendererService(config, RendererOptions(mode="window", size=(320, 240), fps=30.0, idle_noise=False))
        try:
            svc.connect()
            assert svc.mode == "window" and svc.window is not None
            pump(svc, lambda: svc.frame_count >= 3 and seen_one(FaceFrame))
            assert svc.window.frames >= 3
            assert svc.window.framebuffer_size() == (320, 240)
            screen = svc.window.screen
            svc.draw([v.face for v in svc.views], screen)  # the last frame again, read back before a swap
            pixels = read_rgb(screen)
            assert pixels.shape == (240, 320, 3) and pixels.std() > 10  # a face, not a cleared window
            # a key press, as glfw delivers it, goes out as a command; the face changes when the
            # dialogue service's state comes back
            svc.window._key_callback(svc.window.handle, glfw.KEY_3, 0, glfw.PRESS, 0)
            pump(svc, lambda: seen_one(SetEmotion, lambda m: m.name == "surprised"))
            pump(svc, lambda: seen_one(FaceFrame, lambda f: f.flexors["brow_l"] > 0.5))
            svc.window._key_callback(svc.window.handle, glfw.KEY_T, 0, glfw.PRESS, 0)
            pump(svc, lambda: seen_one(SetRole, lambda m: m.role == "talking"))
            pump(svc, lambda: svc.views[0].scene.role == "talking")
            svc.window._key_callback(svc.window.handle, glfw.KEY_LEFT, 0, glfw.PRESS, 0)
            pump(svc, lambda: seen_one(MoveHead, lambda m: m.turn == 0.25))
            # local keys change the drawing only: nothing is sent
            before = len([m for m in seen if m.CATEGORY == "cmd"])
            svc.window._key_callback(svc.window.handle, glfw.KEY_V, 0, glfw.PRESS, 0)
            svc.window._key_callback(svc.window.handle, glfw.KEY_W, 0, glfw.PRESS, 0)
            assert svc.view == "upper" and svc.toggles.wireframe
            frames = svc.frame_count
            pump(svc, lambda: svc.frame_count >= frames + 3)
            assert len([m for m in seen if m.CATEGORY == "cmd"]) == before
            assert "surprised" in svc.help_line() and "talking" in svc.help_line()
            # resizable: the next frames fill the new size
            glfw.set_window_size(svc.window.handle, 400, 300)
            pump(svc, lambda: svc.window.framebuffer_size() == (400, 300))
            frames = svc.frame_count
            pump(svc, lambda: svc.frame_count >= frames + 2)
            # q closes the window and ends the loop
            svc.window._key_callback(svc.window.handle, glfw.KEY_Q, 0, glfw.PRESS, 0)
            pump(svc, lambda: svc.stopping)
        finally:
            svc.teardown()
            svc.close()
            sub.close()
            ctx.term()
        assert svc.window is None


def test_auto_mode_falls_back_to_headless_without_a_display(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    with private_bus_config() as config, BrokerThread(config):
        ctx = zmq.Context()
        pub = Publisher(ctx, config, "test")
        pub.wait_ready()
        svc = RendererService(config, RendererOptions(mode="auto", size=(64, 48), fps=30.0, frames=2))
        with ServiceThread(svc):
            assert svc.mode == "headless"
        pub.close()
        ctx.term()
