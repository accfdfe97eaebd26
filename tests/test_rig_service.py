"""The rig service on a real bus, in this process: states published as the dialogue service publishes them reach
the bus's `stream.<agent>.rig` and the VMC and Live Link receivers at the rig rate; a receiver that is not there
costs nothing; bad options are one line and a non-zero exit before anything starts."""

from __future__ import annotations

import socket
import subprocess
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import pytest
import zmq
from pythonosc.osc_packet import OscPacket

from eca.protocol.bus import Publisher, Subscriber
from eca.protocol.endpoints import BusConfig
from eca.protocol.messages import EmotionState, HeadState, RigPose
from eca.services.processes.rig.options import options_from, plan
from eca.services.processes.rig.service import RigService
from eca.services.tools.up import instance_running
from tests.support.bus import BrokerThread, ServiceThread, eca_command, private_bus_config
from tests.support.udp import Catcher, decode_live_link

ARKIT_SMILE_LEFT, LIVE_LINK_HEAD_YAW = 23, 52




@contextmanager
def rig_running(config: BusConfig, **cli: Any) -> Iterator[RigService]:
    service = RigService(config, plan(options_from({}, cli), config.agents))
    with ServiceThread(service):
        yield service


def vmc_values(data: bytes) -> dict[str, float]:
    return {m.message.params[0]: m.message.params[1] for m in OscPacket(data).messages
            if m.message.address == "/VMC/Ext/Blend/Val"}


def test_states_reach_the_bus_and_both_receivers_at_the_rig_rate() -> None:
    vmc, live = Catcher(), Catcher()
    with private_bus_config() as config, BrokerThread(config):
        ctx = zmq.Context()
        dialogue = Publisher(ctx, config, "dialogue")
        frames = Subscriber(ctx, config, ["stream.ada.rig"])
        try:
            dialogue.wait_ready()
            frames.wait_ready()
            with rig_running(config, vmc=f"127.0.0.1:{vmc.port}", livelink=f"127.0.0.1:{live.port}") as service:
                assert live.wait_for(lambda d: True, 5.0) is not None
                start, first = time.monotonic(), len(live.got)
                time.sleep(1.0)  # a measured interval to count packets in, not synchronisation
                rate = (len(live.got) - first) / (time.monotonic() - start)
                assert 40 <= rate <= 66, rate  # 60 Hz on a loaded 2-core machine

                dialogue.publish(EmotionState(agent="ada", name="happy", transition_s=0.0))
                dialogue.publish(HeadState(agent="ada", turn=0.8, duration_s=0.0))
                smiling = live.wait_for(lambda d: decode_live_link(d)["values"][ARKIT_SMILE_LEFT] > 0.5, 5.0)
                assert smiling is not None
                turned = live.wait_for(lambda d: decode_live_link(d)["values"][LIVE_LINK_HEAD_YAW] > 0.5, 5.0)
                assert turned is not None  # 0.8 of 40 degrees = 0.56 rad toward the agent's right
                assert vmc.wait_for(lambda d: vmc_values(d)["Joy"] > 0.5 and vmc_values(d)["MouthSmileLeft"] > 0.5,
                                    5.0) is not None
                seen: RigPose | None = None
                deadline = time.monotonic() + 5.0
                while time.monotonic() < deadline and seen is None:
                    got = frames.recv(0.2)
                    message = got.message if got is not None else None
                    # the turn settles at 0.8 of 40 degrees (a frame on its way there, under load, is not it)
                    if isinstance(message, RigPose) and message.head_deg[0] == pytest.approx(32.0, abs=0.5):
                        seen = message
                assert seen is not None and seen.source == "rig"
                assert abs(seen.frame_ns - time.monotonic_ns()) < 2 * 10**9  # on the master (monotonic) clock
                assert seen.head_deg[0] == pytest.approx(32.0, abs=0.5) and seen.vrm[0] > 0.5  # happy
                assert len(seen.arkit) == 52 and len(seen.visemes) == 15 and len(seen.vrm) == 18
                assert service.frames > 60
        finally:
            for sock in (dialogue, frames):
                sock.close()
            ctx.term()
            vmc.close()
            live.close()


def test_a_receiver_that_is_not_there_costs_nothing() -> None:
    closed = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    closed.bind(("127.0.0.1", 0))
    port = closed.getsockname()[1]
    closed.close()
    live = Catcher()
    with private_bus_config() as config, BrokerThread(config):
        try:
            with rig_running(config, vmc=f"127.0.0.1:{port}", livelink=f"127.0.0.1:{live.port}"):
                assert live.wait_for(lambda d: True, 5.0) is not None
                start, first = time.monotonic(), len(live.got)
                time.sleep(1.0)  # a measured interval, as above
                rate = (len(live.got) - first) / (time.monotonic() - start)
                assert rate >= 40, rate  # the Live Link receiver still gets every frame
        finally:
            live.close()


def _eca(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(eca_command(*args), capture_output=True, text=True, timeout=60)


@pytest.mark.parametrize("args, words", [
    (["--vmc", "127.0.0.1:0"], "eca rig: --vmc '127.0.0.1:0': port 0 is out of range"),
    (["--livelink", "no-such-host.invalid"], "cannot resolve host 'no-such-host.invalid'"),
    (["--vmc-names", "vrm0,perfect"], "unknown spelling 'perfect'"),
    (["--rate", "0"], "--rate: 0 Hz is out of range"),
    (["--agent", "zed"], "--agent: 'zed' is not an agent of this instance (ada)"),
])
def test_eca_rig_refuses_bad_options_in_one_line(args: list[str], words: str) -> None:
    with private_bus_config() as config:
        done = _eca("rig", "--config", str(config.config_path), "--instance", config.instance, *args)
    assert done.returncode == 2, done.stderr
    lines = [line for line in done.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and words in lines[0], done.stderr
    assert "Traceback" not in done.stderr


@pytest.mark.parametrize("args, words", [
    (["--rig-vmc", "127.0.0.1:99999"], "eca up: --rig-vmc '127.0.0.1:99999': port 99999 is out of range"),
    (["--rig-livelink", "no-such-host.invalid:11111"], "--rig-livelink no-such-host.invalid:11111: cannot resolve"),
    (["--rig-rate", "1000"], "--rig-rate: 1000 Hz is out of range"),
    (["--rig-agent", "zed"], "--rig-agent: 'zed' is not an agent"),
    (["--rig-vmc", "h:1", "--without", "rig"], "rig options given, but --without rig"),
])
def test_eca_up_refuses_bad_rig_options_before_anything_starts(args: list[str], words: str) -> None:
    with private_bus_config(services=["dialogue"]) as config:
        done = _eca("up", "--config", str(config.config_path), "--instance", config.instance, "--quiet", *args)
        assert not instance_running(config)
    assert done.returncode == 2, done.stderr
    lines = [line for line in done.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and words in lines[0], done.stderr


def test_eca_monitor_shows_a_rig_frame_in_one_short_line() -> None:
    from eca.protocol.bus import Received
    from eca.services.tools.commands.monitor import format_line

    arkit = [0.0] * 52
    arkit[17], arkit[23], arkit[24], arkit[0] = 0.62, 0.85, 0.84, 0.3
    frame = RigPose(agent="ada", t_ns=5 * 10**9, frame_ns=5 * 10**9, arkit=arkit, head_deg=[12.0, -3.0, 0.5],
                    eyes_deg=[4.0, 1.0, 3.5, 1.0], visemes=[0.3] + [0.0] * 9 + [0.7] + [0.0] * 4,
                    vrm=[0.8] + [0.0] * 16 + [0.2])
    line = format_line(Received("stream.ada.rig", frame), as_json=False, color=False)
    assert line == ("5.000 stream.ada.rig frame=5.000 head=+12.0/-3.0/+0.5 eyes=L+4.0/+1.0,R+3.5/+1.0 top "
                    "MouthSmileLeft=0.85 MouthSmileRight=0.84 JawOpen=0.62 viseme aa=0.70 vrm happy=0.80")
    assert len(line) < 200


def test_eca_rig_attaches_to_a_running_instance_and_stops_cleanly() -> None:
    import signal

    from tests.support.bus import running

    live = Catcher()
    try:
        with private_bus_config() as config, BrokerThread(config):
            argv = eca_command("rig", "--config", str(config.config_path), "--instance", config.instance,
                               "--livelink", f"127.0.0.1:{live.port}", "--rate", "30")
            with running(argv) as (proc, reader):
                reader.wait_for("[rig] INFO ready", 20.0)
                packet = live.wait_for(lambda d: True, 5.0)
                assert packet is not None and decode_live_link(packet)["rate"] == (30, 1)
                proc.send_signal(signal.SIGINT)
                assert proc.wait(timeout=10) == 0
                reader.wait_for("[rig] INFO sent", 5.0)
    finally:
        live.close()
