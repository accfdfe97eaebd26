"""`eca up` with real processes: readiness, restart after SIGKILL with current state, clean stop."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import av
import pytest
import zmq

from eca.protocol.bus import Subscriber
from eca.protocol.client import AgentClient
from eca.protocol.endpoints import BusConfig
from eca.protocol.messages import EmotionState, Heartbeat
from eca.services.tools.cli import main as eca_main
from eca.services.tools.up import instance_running
from tests.support.bus import LineReader, eca_command, private_bus_config, running

pytestmark = pytest.mark.slow


@pytest.fixture
def config() -> Iterator[BusConfig]:
    with private_bus_config(services=["dialogue"]) as cfg:
        yield cfg


def up_argv(config: BusConfig) -> list[str]:
    return eca_command("up", "--config", str(config.config_path), "--instance", config.instance, "--quiet")


def pid_of(reader: LineReader, service: str, start: int = 0) -> tuple[int, int]:
    i = reader.wait_for(f"[{service}] INFO ready (pid", 20.0, start)
    match = re.search(r"pid (\d+)", reader.lines[i])
    assert match
    return int(match.group(1)), i


def alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/status") as fh:
            return "zombie" not in fh.read()
    except FileNotFoundError:
        return False


def test_killed_service_is_back_with_the_current_state(config: BusConfig) -> None:
    with running(up_argv(config)) as (proc, reader):
        reader.wait_for("[up] ready in", 30.0)
        old_pid, line = pid_of(reader, "dialogue")
        with AgentClient(config, agent="ada") as client:
            client.set_emotion("frightened", 0.6)
            client.expect_state(EmotionState, lambda m: m.name == "frightened")
        ctx = zmq.Context()
        beats = Subscriber(ctx, config, ["sys."])
        beats.wait_ready()
        try:
            killed_at = time.monotonic()
            os.kill(old_pid, signal.SIGKILL)
            new_pid = None
            while time.monotonic() - killed_at < 10.0 and new_pid is None:
                got = beats.recv(0.5)
                if got and isinstance(got.message, Heartbeat) and got.message.service == "dialogue" \
                        and got.message.pid != old_pid:
                    new_pid = got.message.pid
            back_after = time.monotonic() - killed_at
        finally:
            beats.close()
            ctx.term()
        assert new_pid is not None, "dialogue did not come back"
        assert back_after < 3.0, f"dialogue took {back_after:.2f} s to come back"
        reader.wait_for("dialogue is back", 5.0, line)
        # The restarted service adopted the current state from the cache instead of resetting it.
        with AgentClient(config, agent="ada") as client:
            client.set_role("talking")  # something it must handle, so it is surely running
            client.wait_for(lambda m: m.TYPE == "role" and m.role == "talking", 5.0)
            assert client.state["emotion"].name == "frightened"
            assert client.state["emotion"].intensity == 0.6


def test_sigint_stops_everything_and_leaves_no_process(config: BusConfig) -> None:
    with running(up_argv(config)) as (proc, reader):
        reader.wait_for("[up] ready in", 30.0)
        pids = [pid_of(reader, name)[0] for name in ("broker", "dialogue")]
        assert all(alive(p) for p in pids)
        asked_at = time.monotonic()
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=10)
        took = time.monotonic() - asked_at
        assert proc.returncode == 0
        assert not [p for p in pids if alive(p)]
        assert took < 2.0, f"eca up took {took:.2f} s to stop"
        assert reader.wait_for("[up] stopped", 2.0) >= 0


def test_monitor_sees_what_send_sends(config: BusConfig) -> None:
    common = ["--config", str(config.config_path), "--instance", config.instance]
    with running(up_argv(config)) as (_, up_reader):
        up_reader.wait_for("[up] ready in", 30.0)
        with running(eca_command("monitor", *common, "--topic", "state.ada.emotion", "--topic", "cmd.")) as (
                _, mon):
            mon.wait_for("# monitoring", 15.0)
            done = subprocess.run(eca_command("send", *common, "emotion", "surprised", "--intensity", "0.7"),
                                  capture_output=True, text=True, timeout=30, cwd=Path(__file__).parent.parent)
            assert done.returncode == 0, done.stderr
            assert "name='surprised'" in done.stdout
            mon.wait_for("cmd.ada.set_emotion", 10.0)
            mon.wait_for("name=surprised intensity=0.7", 10.0)
            bad = subprocess.run(eca_command("send", *common, "emotion", "grumpy"), capture_output=True, text=True,
                                 timeout=30)
            assert bad.returncode == 1 and "unknown emotion 'grumpy'" in bad.stderr


def test_a_second_broker_for_the_same_instance_refuses_to_start(config: BusConfig) -> None:
    with running(up_argv(config)) as (_, reader):
        reader.wait_for("[up] ready in", 30.0)
        second = subprocess.run(eca_command("up", "--config", str(config.config_path), "--instance",
                                            config.instance, "--quiet", "--seconds", "5"),
                                capture_output=True, text=True, timeout=60)
        assert second.returncode == 1
        assert f"instance '{config.instance}' is already running" in second.stdout


@pytest.mark.parametrize(("extra", "says"), [
    (["--only", "renderer", "--headless", "--window"], "--headless and --window exclude each other"),
    (["--only", "renderer", "--size", "12x3"], "size must lie between 16x16 and 8192x8192, got 12x3"),
    (["--only", "renderer", "--fps", "0"], "fps must lie in [1, 240], got 0.0"),
    (["--headless", "--only", "dialogue"], "renderer options (--headless) given, but the renderer is not started"),
])
def test_bad_renderer_options_are_refused_before_anything_starts(
        config: BusConfig, extra: list[str], says: str, capsys: pytest.CaptureFixture[str]) -> None:
    code = eca_main(["up", "--config", str(config.config_path), "--instance", config.instance, *extra])
    assert code == 2
    assert says in capsys.readouterr().err
    assert not instance_running(config)


def test_up_headless_records_the_live_face(config: BusConfig, tmp_path: Path) -> None:
    video = tmp_path / "live.mp4"
    argv = eca_command("up", "--config", str(config.config_path), "--instance", config.instance, "--quiet",
                       "--only", "dialogue", "--only", "renderer", "--headless", "--video", str(video),
                       "--size", "160x120", "--fps", "10")
    with running(argv) as (proc, reader):
        reader.wait_for("[up] ready in", 60.0)
        line = reader.lines[reader.wait_for("[renderer] INFO headless mode (EGL, forced): 160x120 at 10 fps", 5.0)]
        assert f"writing video {video}" in line
        with AgentClient(config, agent="ada") as client:
            client.set_emotion("surprised", 1.0, transition_s=0.0)
            client.expect_state(EmotionState, lambda m: m.name == "surprised")
        frames = Subscriber(zmq.Context.instance(), config, ["stream.ada.face_frame"])
        try:
            frames.wait_ready()
            assert frames.recv(10.0) is not None  # the face is being drawn
        finally:
            frames.close()
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=15)
        assert proc.returncode == 0
    with av.open(str(video)) as container:
        stream = container.streams.video[0]
        decoded = [frame for frame in container.decode(stream)]
    assert (stream.codec_context.name, stream.width, stream.height) == ("h264", 160, 120)
    assert len(decoded) >= 1
