"""The rig service's senders without a bus: the Live Link Face packet read back by a decoder written here from
the layout (JimWest/PyLiveLinkFace), the VMC bundle read back by python-osc's own parser and compared with one
python-osc builds itself, the bone quaternions against Unity's conventions, the UDP sender's drops, and the
options' refusals."""

from __future__ import annotations

import math
import re
import socket
import struct
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from pythonosc.osc_bundle import OscBundle
from pythonosc.osc_bundle_builder import IMMEDIATELY, OscBundleBuilder
from pythonosc.osc_message_builder import OscMessageBuilder
from pythonosc.osc_packet import OscPacket

from eca.agent.rig.names import ARKIT_NAMES, VISEME_NAMES, VRM0_NAMES, VRM0_TO_VRM1, VRM_NAMES, arkit_names
from eca.services.processes.rig.livelink import LiveLinkPacker, device_id, frame_rate
from eca.services.processes.rig.options import (
    RigOptions,
    RigOptionsError,
    argv_from,
    flag_names,
    options_from,
    parse_target,
    plan,
)
from eca.services.processes.rig.udp import UdpSender
from eca.services.processes.rig.vmc import BONE_POSITIONS, VmcPacker, blend_names, bone_rotation, unity_euler
from tests.support.udp import decode_live_link

RNG = np.random.default_rng(7)
DOC = Path(__file__).resolve().parent.parent / "docs" / "protocol.md"


# --- Live Link Face --------------------------------------------------------------------------------




def test_the_live_link_packet_reads_back_as_the_layout_says() -> None:
    arkit = RNG.uniform(0, 1, 52)
    head, eyes = (20.0, -10.0, 5.0), (12.0, -3.0, 9.0, -3.5)
    device = device_id("default", "ada")
    packer = LiveLinkPacker("ada", device, 60.0, offset_ns=0)
    frame_ns = 3_600 * 10**9 + 10**9 // 4 + 10**9 // 120  # 01:00:00.258333...: frame 216015 and a half at 60 Hz
    got = decode_live_link(packer.pack(frame_ns, arkit, head, eyes))
    assert (got["version"], got["device"], got["subject"], got["count"]) == (6, device, "ada", 61)
    assert len(device) == 37 and device.startswith("$")
    assert got["rate"] == (60, 1)
    assert got["frame"] == 216015 and got["sub"] == pytest.approx(0.5, abs=1e-6)
    values = got["values"]
    assert values.size == 61
    np.testing.assert_allclose(values[:52], arkit, atol=1e-7)  # float32
    # Radians in the app's signs, as its recorded takes (and the CSV eca render writes): yaw as eca's, pitch + down,
    # roll + toward the left shoulder; each eye's roll 0.
    np.testing.assert_allclose(values[52:55], np.radians([20.0, 10.0, -5.0]), atol=1e-6)
    np.testing.assert_allclose(values[55:61], np.radians([12.0, 3.0, 0.0, 9.0, 3.5, 0.0]), atol=1e-6)


def test_read_as_unreal_reads_it_the_device_id_is_a_string_of_36_characters() -> None:
    packet = LiveLinkPacker("bo", device_id("x", "bo"), 60.0, offset_ns=0).pack(0, np.zeros(52), (0, 0, 0), (0,) * 4)
    # Unreal: a uint8 version, then an FString: int32 big-endian length, then the characters
    assert packet[0] == 6
    (length,) = struct.unpack(">i", packet[1:5])
    assert length == 36 and len(packet[5:5 + length].decode()) == 36


def test_live_link_frames_count_on_at_the_rate_and_subjects_keep_their_device_ids() -> None:
    packer = LiveLinkPacker("ada", device_id("i", "ada"), 60.0, offset_ns=123_456_789)
    frames = [packer.frame_time(10**12 + k * 10**9 // 60)[0] for k in range(120)]
    assert np.all(np.diff(frames) == 1)
    assert device_id("i", "ada") == device_id("i", "ada") != device_id("i", "bo") != device_id("j", "bo")
    assert frame_rate(29.97) == (2997, 100) and frame_rate(60) == (60, 1)


# --- VMC ---------------------------------------------------------------------------------------------


def reference_bundle(packer: VmcPacker, arkit: np.ndarray, vrm: np.ndarray, head: tuple[float, float, float],
                     eyes: tuple[float, ...], time_s: float) -> bytes:
    """The same frame built message by message with python-osc's own builders."""
    bundle = OscBundleBuilder(IMMEDIATELY)

    def add(address: str, *args: Any) -> None:
        builder = OscMessageBuilder(address)
        for arg in args:
            builder.add_arg(arg, "f" if isinstance(arg, float) else None)
        bundle.add_content(builder.build())

    s = packer.neck_share
    rotations = {"Neck": bone_rotation(head[0] * s, head[1] * s, head[2] * s),
                 "Head": bone_rotation(head[0] * (1 - s), head[1] * (1 - s), head[2] * (1 - s)),
                 "LeftEye": bone_rotation(eyes[0], eyes[1]), "RightEye": bone_rotation(eyes[2], eyes[3])}
    for bone, rotation in rotations.items():
        add("/VMC/Ext/Bone/Pos", bone, *(float(v) for v in BONE_POSITIONS[bone]), *rotation)
    source = np.concatenate((arkit, vrm))
    for name, index in blend_names(("vrm0", "vrm1", "arkit")):
        add("/VMC/Ext/Blend/Val", name, float(source[index]))
    add("/VMC/Ext/Blend/Apply")
    add("/VMC/Ext/OK", 1)
    add("/VMC/Ext/T", time_s)
    return bytes(bundle.build().dgram)


def test_the_vmc_bundle_is_what_python_osc_builds_and_parses_back() -> None:
    packer = VmcPacker(("vrm0", "vrm1", "arkit"), neck_share=0.3)
    arkit, vrm = RNG.uniform(0, 1, 52), RNG.uniform(0, 1, 18)
    head, eyes = (25.0, 10.0, -5.0), (8.0, 2.0, 6.0, 2.0)
    data = packer.pack(arkit, vrm, head, eyes, 12.5)
    assert data == reference_bundle(packer, arkit, vrm, head, eyes, 12.5)
    assert OscBundle.dgram_is_bundle(data)
    messages = [m.message for m in OscPacket(data).messages]
    addresses = [m.address for m in messages]
    assert addresses.count("/VMC/Ext/Blend/Val") == 17 + 18 + 52
    assert addresses.index("/VMC/Ext/Blend/Apply") == len(addresses) - 3  # after every value, then OK and T
    assert messages[-2].params == [1] and messages[-1].params == [pytest.approx(12.5)]
    values = {m.params[0]: m.params[1] for m in messages if m.address == "/VMC/Ext/Blend/Val"}
    # every spelling, case as each standard spells it, with the weight of its shape
    assert set(VRM0_NAMES) | set(VRM_NAMES) | set(ARKIT_NAMES) == set(values)
    for v0, v1 in VRM0_TO_VRM1.items():
        assert values[v0] == values[v1] == pytest.approx(vrm[VRM_NAMES.index(v1)], abs=1e-6)
    for i, name in enumerate(ARKIT_NAMES):
        assert values[name] == pytest.approx(arkit[i], abs=1e-6)
    bones = {m.params[0]: m.params[1:] for m in messages if m.address == "/VMC/Ext/Bone/Pos"}
    assert list(bones) == ["Neck", "Head", "LeftEye", "RightEye"]
    for bone, params in bones.items():
        assert len(params) == 7 and math.isclose(sum(q * q for q in params[3:]), 1.0, rel_tol=1e-5), bone


def test_the_default_names_are_vrm0_then_perfect_sync() -> None:
    names = VmcPacker().names
    assert names == list(VRM0_NAMES) + list(arkit_names("pascal"))
    assert "Blink_L" in names and "Joy" in names and "A" in names and "EyeBlinkLeft" in names


def rotate(q: tuple[float, float, float, float], v: tuple[float, float, float]) -> np.ndarray:
    """q * v * q^-1 with q = (x, y, z, w): what Unity's `quaternion * vector` gives."""
    x, y, z, w = q
    u = np.array([x, y, z])
    vec = np.array(v, dtype=float)
    return 2 * np.dot(u, vec) * u + (w * w - np.dot(u, u)) * vec + 2 * w * np.cross(u, vec)


FORWARD, UP = (0.0, 0.0, 1.0), (0.0, 1.0, 0.0)


def test_unity_euler_matches_unitys_own_results() -> None:
    # Unity: Quaternion.Euler(90, 0, 0) * Vector3.forward == (0, -1, 0); Euler(0, 90, 0) * forward == (1, 0, 0);
    # Euler(0, 0, 90) * Vector3.up == (-1, 0, 0); Euler applies z, then x, then y.
    np.testing.assert_allclose(rotate(unity_euler(90, 0, 0), FORWARD), (0, -1, 0), atol=1e-9)
    np.testing.assert_allclose(rotate(unity_euler(0, 90, 0), FORWARD), (1, 0, 0), atol=1e-9)
    np.testing.assert_allclose(rotate(unity_euler(0, 0, 90), UP), (-1, 0, 0), atol=1e-9)
    # order: z first, then x, then y: Euler(90, 90, 0) * up = Ry(90) * (Rx(90) * up) = Ry(90) * (0, 0, 1)
    np.testing.assert_allclose(rotate(unity_euler(90, 90, 0), UP), (1, 0, 0), atol=1e-9)


def test_bone_rotations_follow_the_agents_own_directions_in_unitys_frame() -> None:
    # Unity: +x the avatar's right, +y up, +z where it faces
    turned = rotate(bone_rotation(30.0, 0.0), FORWARD)
    assert turned[0] == pytest.approx(math.sin(math.radians(30)))  # yaw + : the face turns to the avatar's right
    raised = rotate(bone_rotation(0.0, 20.0), FORWARD)
    assert raised[1] == pytest.approx(math.sin(math.radians(20)))  # pitch + : chin (and the gaze) up
    rolled = rotate(bone_rotation(0.0, 0.0, 15.0), UP)
    assert rolled[0] == pytest.approx(math.sin(math.radians(15)))  # roll + : the top of the head to the right


def test_neck_and_head_together_turn_the_whole_head() -> None:
    packer = VmcPacker(("vrm0",), neck_share=0.3)
    data = packer.pack(np.zeros(52), np.zeros(18), (40.0, 0.0, 0.0), (0.0,) * 4, 0.0)
    bones = {m.message.params[0]: m.message.params[4:] for m in OscPacket(data).messages
             if m.message.address == "/VMC/Ext/Bone/Pos"}
    neck_then_head = rotate(tuple(bones["Neck"]), rotate(tuple(bones["Head"]), FORWARD))  # type: ignore[arg-type]
    np.testing.assert_allclose(neck_then_head, rotate(bone_rotation(40.0, 0.0), FORWARD), atol=1e-6)
    assert rotate(tuple(bones["Neck"]), FORWARD)[0] == pytest.approx(math.sin(math.radians(12)), abs=1e-6)


# --- the UDP sender -----------------------------------------------------------------------------------


class _FullSocket:
    def sendto(self, data: bytes, address: object) -> int:
        raise BlockingIOError

    def close(self) -> None:
        pass


def test_a_send_that_would_block_is_dropped_and_counted_not_waited_for() -> None:
    sender = UdpSender()
    sender.socket.close()
    sender.socket = _FullSocket()  # type: ignore[assignment]
    assert not sender.send(b"x", ("127.0.0.1", 9))
    assert (sender.sent, sender.dropped, sender.last_error) == (0, 1, "the send buffer is full")


def test_a_receiver_that_is_not_there_costs_nothing_and_nothing_is_read() -> None:
    sender = UdpSender()
    try:
        closed = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        closed.bind(("127.0.0.1", 0))
        port = closed.getsockname()[1]
        closed.close()  # nobody listens there now: the kernel answers with ICMP, which is never read
        for _ in range(200):
            sender.send(b"frame", ("127.0.0.1", port))
        assert sender.sent + sender.dropped == 200
        assert not sender.send(b"x" * 70_000, ("127.0.0.1", port))  # too long for a datagram: dropped
        assert sender.last_error
    finally:
        sender.close()


# --- options ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("cli, words", [
    ({"vmc": "127.0.0.1:0"}, "--vmc '127.0.0.1:0': port 0 is out of range"),
    ({"vmc": "127.0.0.1:70000"}, "port 70000 is out of range"),
    ({"livelink": "host:abc"}, "--livelink 'host:abc': the port 'abc' is not a whole number"),
    ({"livelink": "no-such-host.invalid:11111"}, "--livelink no-such-host.invalid:11111: cannot resolve host"),
    ({"vmc": "::1:39539"}, "write an IPv6 address in brackets"),
    ({"vmc_names": "vrm0,vrm2"}, "--vmc-names: unknown spelling 'vrm2'; known: vrm0, vrm1, arkit"),
    ({"vmc_names": ","}, "--vmc-names: give at least one"),
    ({"rate_hz": "500"}, "--rate: 500 Hz is out of range; give a rate in 1..120 Hz"),
    ({"rate_hz": "nan"}, "--rate: nan Hz is out of range"),
    ({"rate_hz": "fast"}, "--rate 'fast': not a number"),
    ({"agents": ["bob"]}, "--agent: 'bob' is not an agent of this instance (ada, eve)"),
    ({"agents": ["ada", "ada"]}, "--agent: an agent is named twice"),
    ({"vmc": "127.0.0.1:65535"}, "2 agents need the ports 65535..65536"),
])
def test_bad_options_are_one_line_naming_the_option(cli: dict[str, Any], words: str) -> None:
    with pytest.raises(RigOptionsError) as info:
        plan(options_from({}, cli), ("ada", "eve"), flag_names(cli))
    assert words in str(info.value) and "\n" not in str(info.value)


def test_a_bad_value_in_the_config_is_named_by_its_key() -> None:
    with pytest.raises(RigOptionsError, match=r"\[rig\] vmc_names: unknown spelling 'Joy'"):
        plan(options_from({"vmc_names": ["Joy"]}, {}), ("ada",), flag_names({}))
    with pytest.raises(RigOptionsError, match="unknown key 'port'"):
        options_from({"port": 1}, {})


def test_targets_resolve_and_several_agents_get_consecutive_vmc_ports() -> None:
    got = plan(options_from({}, {"vmc": "localhost:40000", "livelink": ":11112"}), ("ada", "eve"))
    assert [t.port for t in got.vmc] == [40000, 40001]
    assert got.vmc[1].sockaddr[1] == 40001 and got.livelink is not None and got.livelink.port == 11112
    assert got.livelink.host == "127.0.0.1"
    assert parse_target("[::1]:5", 1, "--vmc").host == "::1"
    assert parse_target("example", 39539, "--vmc").port == 39539
    assert plan(RigOptions(), ("ada",)).vmc == () and plan(RigOptions(), ("ada",)).livelink is None


def test_eca_up_hands_the_rig_service_its_options_in_its_own_spelling() -> None:
    assert argv_from({"vmc": "h:1", "agents": ["a", "b"], "rate_hz": "30"}) == [
        "--vmc", "h:1", "--agent", "a", "--agent", "b", "--rate", "30"]


# --- the protocol document lists the names in the order the rig frame's lists have -------------------


def test_the_protocol_document_lists_the_rig_names_in_order() -> None:
    text = DOC.read_text(encoding="utf-8")
    section = text.split("#### `rig`", 1)[1].split("\n#### ", 1)[0]
    arkit = re.findall(r"^\| (\d+) \| `(\w+)` \| `(\w+)` \| `(\w+)` \|$", section, flags=re.MULTILINE)
    assert [(int(i), p, c, r) for i, p, c, r in arkit] == [
        (i, p, c, r) for i, (p, c, r) in enumerate(zip(ARKIT_NAMES, arkit_names("camel"), arkit_names("raw"),
                                                        strict=True))]
    oculus = re.search(r"^\| Oculus \|(.*)\|$", section, flags=re.MULTILINE)
    assert oculus and [c.strip(" `") for c in oculus.group(1).split("|")] == list(VISEME_NAMES)
    vrm = re.findall(r"^\| (\d+) \| `(\w+)` \| (`\w+`|— \(none\)) \|$", section, flags=re.MULTILINE)
    assert [name for _, name, _ in vrm] == list(VRM_NAMES)
    inverse = {v1: v0 for v0, v1 in VRM0_TO_VRM1.items()}
    assert [v0.strip("`") for _, _, v0 in vrm] == [inverse.get(n, "— (none)") for n in VRM_NAMES]
