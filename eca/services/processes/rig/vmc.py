"""The VMC protocol's frame: one OSC bundle per agent per frame, for a VMC receiver ("Marionette": VSeeFace,
Warudo, VMagicMirror, EVMC4U in Unity, VMC4UE in Unreal, VMC4B in Blender), commonly on UDP port 39539.

What a bundle holds (sh-akira/VirtualMotionCaptureProtocol, docs/english.markdown, "Marionette"):

- `/VMC/Ext/Bone/Pos (s name, f p.x, f p.y, f p.z, f q.x, f q.y, f q.z, f q.w)` for Neck, Head, LeftEye and
  RightEye: each bone's *local* pose (relative to its parent bone), as the spec's own samples send
  `Transform.localPosition` / `localRotation` of a Unity humanoid (sample/VRM1/SampleBonesSendBundle.cs);
- `/VMC/Ext/Blend/Val (s name, f value)` for each blend shape in the chosen spellings, then
  `/VMC/Ext/Blend/Apply` (a receiver accumulates the values and applies them together);
- `/VMC/Ext/OK (i 1)` (a model is loaded: the values are live) and `/VMC/Ext/T (f time)` (the sender's relative
  time in seconds: here since the rig service started).

Blend names are case-sensitive. Spellings: "vrm0" the 17 VRM 0.x presets (Joy, Angry, Sorrow, Fun, A, I, U, E,
O, Blink, Blink_L, Blink_R, LookUp, LookDown, LookLeft, LookRight, Neutral), which the spec says a sender must
send for the receivers built on VRM 0; "vrm1" VRM 1.0's 18 presets (happy ... neutral, surprised among them);
"arkit" the 52 ARKit names in PascalCase (EyeBlinkLeft ...), the clip names of "Perfect Sync" models.

Bones, in Unity's frame (the VMC protocol is Unity's: UniVRM, HumanBodyBones names): left-handed, +x the
avatar's right, +y up, +z the way the avatar faces. A rotation of +a about +y turns +z toward +x, so a head yaw
toward the agent's right is +yaw about y; +a about +x turns +z toward -y (the nose down), so a chin up is
-pitch about x; +a about +z turns +y toward -x (the top of the head to the avatar's left), so a roll toward the
right shoulder is -roll about z. The three compose in Unity's Euler order (z, then x, then y), so a bone's
rotation is exactly `Quaternion.Euler(-pitch, yaw, -roll)` in Unity: q = q_y(yaw) * q_x(-pitch) * q_z(-roll),
components (x, y, z, w), each q_axis(a) = (axis * sin(a/2), cos(a/2)). Rotations are relative to the rest pose
(identity: looking straight ahead), as a normalised humanoid's bones are (UniVRM's VRM 0.x import, VRM 1.0's
normalised control rig); a sender with no skeleton of its own can give nothing else.

The head's rotation is split between Neck (a share, `neck_share`) and Head (the rest), each the Euler rotation
of its share of the angles; for a turn about one axis the two add up exactly. The eyes turn by their own yaw and
pitch (no roll) in the head. Positions are a typical adult humanoid's rest offsets in metres (BONE_POSITIONS): VMC
requires them, most receivers apply only rotations, and one that applies positions (EVMC4U's "bone position
synchronize") should be told not to, since no model's offsets are known here.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Sequence

import numpy as np
from pythonosc.osc_message_builder import OscMessageBuilder

from eca.agent.rig.names import ARKIT_NAMES, N_ARKIT, VRM0_TO_VRM1, VRM_INDEX, VRM_NAMES

BUNDLE_HEADER = b"#bundle\x00" + struct.pack(">Q", 1)  # OSC time tag 1: "immediately"
BLEND_VAL, BLEND_APPLY, BONE_POS = "/VMC/Ext/Blend/Val", "/VMC/Ext/Blend/Apply", "/VMC/Ext/Bone/Pos"
OK, TIME = "/VMC/Ext/OK", "/VMC/Ext/T"
BONES = ("Neck", "Head", "LeftEye", "RightEye")

# Unity HumanBodyBones names -> local rest position (metres, Unity's frame): a typical adult humanoid's offsets
# from the parent bone (Neck from UpperChest, Head from Neck, each eye from Head; the left eye on the avatar's
# left, -x). Receivers that follow rotations only (the usual) ignore them.
BONE_POSITIONS: dict[str, tuple[float, float, float]] = {
    "Neck": (0.0, 0.10, 0.0),
    "Head": (0.0, 0.08, 0.0),
    "LeftEye": (-0.032, 0.065, 0.03),
    "RightEye": (0.032, 0.065, 0.03),
}


def unity_euler(pitch_deg: float, yaw_deg: float, roll_deg: float) -> tuple[float, float, float, float]:
    """Unity's `Quaternion.Euler(x, y, z)` (degrees; z applied first, then x, then y) as (x, y, z, w)."""
    hx, hy, hz = math.radians(pitch_deg) * 0.5, math.radians(yaw_deg) * 0.5, math.radians(roll_deg) * 0.5
    cx, sx, cy, sy, cz, sz = math.cos(hx), math.sin(hx), math.cos(hy), math.sin(hy), math.cos(hz), math.sin(hz)
    # q_y * q_x * q_z, Hamilton products written out
    return (cy * sx * cz + sy * cx * sz, sy * cx * cz - cy * sx * sz, cy * cx * sz - sy * sx * cz,
            cy * cx * cz + sy * sx * sz)


def bone_rotation(yaw_deg: float, pitch_deg: float, roll_deg: float = 0.0) -> tuple[float, float, float, float]:
    """The local rotation (x, y, z, w) of a bone turned by eca's angles (yaw + = the agent's right, pitch + = up,
    roll + = toward the right shoulder) in Unity's left-handed frame: Quaternion.Euler(-pitch, yaw, -roll)."""
    return unity_euler(-pitch_deg, yaw_deg, -roll_deg)


def blend_names(spellings: Sequence[str]) -> list[tuple[str, int]]:
    """(name, index into the vector [52 ARKit weights, 18 VRM 1.0 weights]) of every blend shape sent, in the
    order of `spellings` (vrm0, vrm1, arkit)."""
    out: list[tuple[str, int]] = []
    for spelling in spellings:
        if spelling == "vrm0":
            out += [(v0, N_ARKIT + VRM_INDEX[v1]) for v0, v1 in VRM0_TO_VRM1.items()]
        elif spelling == "vrm1":
            out += [(v1, N_ARKIT + i) for i, v1 in enumerate(VRM_NAMES)]
        elif spelling == "arkit":
            out += [(name, i) for i, name in enumerate(ARKIT_NAMES)]
        else:
            raise ValueError(f"unknown VMC spelling {spelling!r}; spellings: vrm0, vrm1, arkit")
    return out


def _message(address: str, *args: str | int | float) -> bytes:
    """One OSC message, built by python-osc (strings as 's', floats as 32-bit 'f', ints as 'i')."""
    builder = OscMessageBuilder(address)
    for arg in args:
        builder.add_arg(arg, "f" if isinstance(arg, float) else None)
    return bytes(builder.build().dgram)


def _element(message: bytes) -> bytes:
    """A bundle element: its size, then the message."""
    return struct.pack(">i", len(message)) + message


class VmcPacker:
    """Builds one agent's VMC bundle per frame. The bundle is built once by python-osc, with every value a
    placeholder; OSC aligns every argument to 4 bytes, so each float of the bundle is one slot of a big-endian
    float32 view of it, and a frame only writes its values into those slots."""

    def __init__(self, spellings: Sequence[str] = ("vrm0", "arkit"), neck_share: float = 0.3,
                 bone_positions: dict[str, tuple[float, float, float]] | None = None) -> None:
        if not 0.0 <= neck_share <= 1.0:
            raise ValueError(f"neck_share must lie in 0..1, got {neck_share}")
        self.neck_share = neck_share
        names = blend_names(spellings)
        self.names = [name for name, _ in names]
        self._index = np.array([i for _, i in names], dtype=np.intp)
        positions = bone_positions or BONE_POSITIONS
        parts: list[bytes] = [BUNDLE_HEADER]
        size = len(BUNDLE_HEADER)
        bone_slots: list[int] = []
        blend_slots: list[int] = []

        def add(message: bytes, floats: int, slots: list[int]) -> None:
            nonlocal size
            parts.append(_element(message))
            size += 4 + len(message)
            slots.extend(range((size - 4 * floats) // 4, size // 4))  # the message's last `floats` arguments

        for bone in BONES:
            add(_message(BONE_POS, bone, *(float(p) for p in positions[bone]), 0.0, 0.0, 0.0, 1.0), 7, bone_slots)
        for name in self.names:
            add(_message(BLEND_VAL, name, 0.0), 1, blend_slots)
        add(_message(BLEND_APPLY), 0, [])
        add(_message(OK, 1), 0, [])
        time_slot: list[int] = []
        add(_message(TIME, 0.0), 1, time_slot)
        self._template = b"".join(parts)
        self._bone_slots = np.array(bone_slots, dtype=np.intp).reshape(len(BONES), 7)
        self._blend_slots = np.array(blend_slots, dtype=np.intp)
        self._time_slot = time_slot[0]
        self._bones = np.zeros((len(BONES), 7))
        self._bones[:, :3] = [positions[bone] for bone in BONES]
        self._source = np.zeros(N_ARKIT + len(VRM_NAMES))

    def pack(self, arkit: np.ndarray, vrm: np.ndarray, head_deg: Sequence[float], eyes_deg: Sequence[float],
             time_s: float) -> bytes:
        """The bundle of one frame: `arkit` (52) and `vrm` (18) weights, head (yaw, pitch, roll) and eyes (left
        yaw, left pitch, right yaw, right pitch) in degrees, the sender's relative time in seconds."""
        source = self._source
        source[:N_ARKIT] = arkit
        source[N_ARKIT:] = vrm
        yaw, pitch, roll = (float(a) for a in head_deg)
        share = self.neck_share
        bones = self._bones
        bones[0, 3:] = bone_rotation(yaw * share, pitch * share, roll * share)
        bones[1, 3:] = bone_rotation(yaw * (1 - share), pitch * (1 - share), roll * (1 - share))
        bones[2, 3:] = bone_rotation(float(eyes_deg[0]), float(eyes_deg[1]))
        bones[3, 3:] = bone_rotation(float(eyes_deg[2]), float(eyes_deg[3]))
        bundle = bytearray(self._template)
        floats = np.frombuffer(bundle, dtype=">f4")
        floats[self._blend_slots] = source[self._index]
        floats[self._bone_slots] = bones
        floats[self._time_slot] = time_s
        return bytes(bundle)
