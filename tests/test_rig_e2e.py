"""A live `eca up` with the rig service, heard by receivers that are not eca's: a VMC receiver built on python-osc's
own server (osc_server + dispatcher, as a Marionette would take the bundles) and a Live Link Face decoder on a
plain UDP socket. While the instance runs, an emotion, a head turn, a blink and a say are driven with `eca send`;
each shows up in the received values, in the order driven, at the configured rate."""

from __future__ import annotations

import subprocess
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
from pythonosc.dispatcher import Dispatcher
from pythonosc.osc_server import BlockingOSCUDPServer

from eca.agent.rig.names import ARKIT_INDEX
from tests.support.bus import eca_command, private_bus_config, running
from tests.support.udp import Catcher, decode_live_link

pytestmark = pytest.mark.slow

RATE_HZ = 60.0
HEAD_YAW, EYE_BLINK_LEFT, JAW_OPEN, SMILE_LEFT = 52, ARKIT_INDEX["EyeBlinkLeft"], ARKIT_INDEX["JawOpen"], \
    ARKIT_INDEX["MouthSmileLeft"]
VOWELS = ("A", "I", "U", "E", "O")


class VmcReceiver:
    """python-osc's blocking UDP server on a thread: every /VMC/Ext/Blend/Apply closes a frame of the blend values
    and bones received before it; /VMC/Ext/T gives the sender's time."""

    def __init__(self) -> None:
        self.frames: list[tuple[float, dict[str, float], dict[str, tuple[float, ...]]]] = []
        self.times: list[float] = []
        self._blends: dict[str, float] = {}
        self._bones: dict[str, tuple[float, ...]] = {}
        dispatcher = Dispatcher()
        dispatcher.map("/VMC/Ext/Blend/Val", self._on_value)
        dispatcher.map("/VMC/Ext/Bone/Pos", self._on_bone)
        dispatcher.map("/VMC/Ext/Blend/Apply", self._on_apply)
        dispatcher.map("/VMC/Ext/T", lambda _, t: self.times.append(t))
        self.server = BlockingOSCUDPServer(("127.0.0.1", 0), dispatcher)
        self.port = self.server.server_address[1]
        self._thread = threading.Thread(target=self.server.serve_forever, kwargs={"poll_interval": 0.05},
                                        daemon=True)
        self._thread.start()

    def _on_value(self, _: str, name: str, value: float) -> None:
        self._blends[name] = value

    def _on_bone(self, _: str, name: str, *pose: float) -> None:
        self._bones[name] = pose

    def _on_apply(self, _: str) -> None:
        self.frames.append((time.monotonic(), self._blends, self._bones))
        self._blends, self._bones = {}, {}

    def close(self) -> None:
        self.server.shutdown()
        self.server.server_close()




def first_time(frames: list[Any], since: float, predicate: Callable[[Any], bool], timeout_s: float) -> float:
    """The arrival time of the first frame from `since` on that meets `predicate`, polling up to `timeout_s`."""
    deadline = time.monotonic() + timeout_s
    checked = 0
    while True:
        for frame in frames[checked:]:
            checked += 1
            if frame[0] >= since and predicate(frame):
                return float(frame[0])
        if time.monotonic() > deadline:
            raise AssertionError(f"not seen within {timeout_s} s")
        time.sleep(0.02)  # pacing a poll of what the receiver threads collect, not synchronisation


def rates_over(seconds: float, *streams: list[Any]) -> list[float]:
    """Frames per second arriving at each stream over one measured interval of `seconds`."""
    start, first = time.monotonic(), [len(frames) for frames in streams]
    while time.monotonic() - start < seconds:
        time.sleep(0.05)  # waiting out the measured interval
    took = time.monotonic() - start
    return [(len(frames) - n) / took for frames, n in zip(streams, first, strict=True)]


def head_yaw_deg(bones: dict[str, tuple[float, ...]]) -> float:
    """The yaw of Neck then Head (Unity quaternions x, y, z, w), from where the face's forward axis points."""
    def rotate(q: tuple[float, ...], v: np.ndarray) -> np.ndarray:
        u, w = np.array(q[:3]), q[3]
        return 2 * np.dot(u, v) * u + (w * w - np.dot(u, u)) * v + 2 * w * np.cross(u, v)

    forward = rotate(bones["Neck"][3:], rotate(bones["Head"][3:], np.array([0.0, 0.0, 1.0])))
    return float(np.degrees(np.arctan2(forward[0], forward[2])))


def test_vmc_and_live_link_receivers_see_emotion_head_blink_and_speech_at_the_rate() -> None:
    vmc, live = VmcReceiver(), Catcher(decode_live_link)
    try:
        with private_bus_config(services=["dialogue", "gaze", "audio"]) as config:
            common = ["--config", str(config.config_path), "--instance", config.instance]
            argv = eca_command("up", *common, "--quiet", "--silent-audio", "--rig-vmc", f"127.0.0.1:{vmc.port}",
                               "--rig-livelink", f"127.0.0.1:{live.port}", "--rig-rate", f"{RATE_HZ:g}")

            def send(*args: str) -> float:
                sent_at = time.monotonic()
                done = subprocess.run(eca_command("send", *common, *args), capture_output=True, text=True,
                                      timeout=30)
                assert done.returncode == 0, done.stderr
                return sent_at

            with running(argv) as (_, reader):
                reader.wait_for("[up] ready in", 40.0)
                first_time(live.got, 0.0, lambda f: True, 10.0)
                first_time(vmc.frames, 0.0, lambda f: True, 10.0)
                eyes_at = send("eyes", "saccade+blink")

                # the rate: frames counted over a measured interval, at both receivers
                rates = rates_over(2.0, vmc.frames, live.got)
                assert all(0.75 * RATE_HZ <= rate <= 1.05 * RATE_HZ for rate in rates), rates
                before = time.monotonic()
                assert max(f[1]["Joy"] for f in vmc.frames) < 0.2  # not happy yet
                assert max(f[1]["values"][JAW_OPEN] for f in live.got) < 0.1  # mouth closed

                happy_at = send("emotion", "happy", "--transition", "0.2")
                happy_vmc = first_time(vmc.frames, happy_at, lambda f: f[1]["Joy"] > 0.5, 5.0)
                happy_live = first_time(live.got, happy_at, lambda f: f[1]["values"][SMILE_LEFT] > 0.5, 5.0)

                head_at = send("head", "--turn", "0.8", "--duration", "0.3")
                turned_vmc = first_time(vmc.frames, head_at, lambda f: head_yaw_deg(f[2]) > 25.0, 5.0)
                turned_live = first_time(live.got, head_at, lambda f: f[1]["values"][HEAD_YAW] > 0.45, 5.0)

                # a blink of saccade+blink (about 26 a minute in conversation, and a head turn's saccade often
                # brings one): the lids close in both streams (happy's lids alone are 0.14)
                blink_vmc = first_time(vmc.frames, eyes_at, lambda f: f[1]["Blink"] > 0.5, 20.0)
                blink_live = first_time(live.got, eyes_at, lambda f: f[1]["values"][EYE_BLINK_LEFT] > 0.5, 20.0)

                say_at = time.monotonic()
                with subprocess.Popen(eca_command("send", *common, "say", "--text",
                                                  "Hello there, I am glad to see you again today.", "--wait"),
                                      stdout=subprocess.DEVNULL, stderr=subprocess.PIPE) as say:
                    spoke_live = first_time(live.got, say_at, lambda f: f[1]["values"][JAW_OPEN] > 0.3, 20.0)
                    spoke_vmc = first_time(vmc.frames, say_at, lambda f: max(f[1][v] for v in VOWELS) > 0.4, 20.0)
                    assert say.wait(timeout=30) == 0, say.stderr.read() if say.stderr else ""

        # in the order driven, each after its command
        assert before < happy_vmc < turned_vmc < spoke_vmc and before < happy_live < turned_live < spoke_live
        assert blink_vmc > eyes_at and blink_live > eyes_at
        # the packets themselves in order: the sender's time and the Live Link frame numbers only go forward
        assert np.all(np.diff(vmc.times) > 0)
        day = 86_400 * RATE_HZ  # frame numbers are the time of day: they start again at midnight
        stamps = np.array([f[1]["frame"] + f[1]["sub"] for f in live.got])
        assert np.all(np.diff(stamps) % day > 0)
        assert all(f[1]["subject"] == "ada" and f[1]["count"] == 61 for f in live.got)
    finally:
        vmc.close()
        live.close()
