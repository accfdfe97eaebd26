"""The face drawn in the browser: what a page needs to draw an agent's avatar itself (three.js and three-vrm,
static/face3d.js), and each frame of it as a few bytes on an RTCDataChannel.

The server keeps doing what it does for its own head drawer (avatar/drive.py: a rig frame to the avatar's morph
weights and joint turns, VRM expressions and overrides included), so a face looks the same drawn here or there, and
the page only puts numbers in place: no retargeting, no expression logic in JavaScript.

The description (JSON, once, in the answer to the page's offer) names the avatar's URL (served from the file the
operator configured, never a path the page chose), its format, each primitive the frames drive (its glTF node and
index in the mesh, its number of morph targets, and which of them carry the voice), the joints they turn (glTF
nodes) and the camera (the head drawer's "full" framing: view and projection matrices).

Messages (binary, little-endian) start with the agent's slot (the description's) and their kind. A frame, one
per frame slot of the master clock:

    u16 slot | u8 kind (1: a frame) | u8 flags (1: the voice sounds at its time; 2: its time is a whole second
    of the master clock, where the calibration mode's click is: web/calibration.py) |
    u32 seq | f64 time (the frame's time on the sender's NTP clock, milliseconds: the clock of the voice's RTCP
    sender reports, so the page compares it with what the audio receiver says it plays) |
    u8 per morph target of each primitive, in the description's order (0..255 for weights 0..1) |
    4 x i16 per joint: its local rotation as a unit quaternion (x, y, z, w) x 32767

so the default head's frame is 16 + 7 x 52 + 4 x 8 = 412 bytes, 12.4 kB/s at 30 frames a second (its 7 face
primitives share one mesh's 52 targets, but the driver weighs each primitive's on its own).

And the voice's clock, a few times a second for each page (what an RTCP sender report says, for a page to read
with the RTP timestamps its audio receiver reports, since a browser does not give a page its sender reports):

    u16 slot | u8 kind (2: the voice's clock) | u8 0 | u32 the RTP timestamp of the last voice packet sent |
    f64 when it was sent, on the sender's NTP clock (milliseconds)

Through Janus, which numbers each viewer's voice afresh from the first packet it relays to it, the voice's clock
also says what the page needs to work out that first packet (static/face3d.js VoiceClock.rebase), at each talk
spurt's first packet and every 12 packets within one (the voice pauses in silence there too, so a spurt is a run
of packets sent one after another, 20 ms apart):

    the 16 bytes above with kind 3 (the voice's spurts) and, in place of the 0, K: the spurts that follow (1..8) |
    f32 the way from eca to Janus (milliseconds: half eca's quickest recent round trip to Janus's API) |
    u16 the RTP sequence number of the last voice packet sent |
    K x (u16 sequence number, u32 RTP timestamp) of the first packets of the latest K spurts, oldest first
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from eca.agent.rig.frame import RigBatch
from eca.agent.rig.names import ARKIT_NAMES, N_ARKIT, N_VISEMES, VRM_VOWELS
from eca.services.processes.avatar.drive import AvatarDriver
from eca.services.processes.avatar.model import Avatar

FRAME, VOICE_CLOCK, VOICE_SPURTS = 1, 2, 3  # message kinds
HEADER = struct.Struct("<HBBId")
_SPURTS_HEAD = struct.Struct("<fH")  # after the header: the way to Janus (ms), the last packet's sequence number
_SPURT = struct.Struct("<HI")
MAX_SPURTS = 8  # spurts a voice's clock through Janus names
VOICED = 1  # flags: the agent's voice sounds at the frame's time
MARK = 2  # flags: the frame's time is a whole second of the master clock (the calibration clicks' times)
NTP_UNIX_OFFSET_MS = 2_208_988_800_000.0  # NTP counts from 1900, Unix time from 1970
# ARKit shapes that speech moves: what the page shows in step with the voice as it plays (the rest as it arrives)
_SPEECH_PREFIXES = ("Jaw", "Mouth", "Tongue")
_TURN = np.diag([-1.0, 1.0, -1.0])  # a VRM 0.x file's frame from the Avatar's (avatar/meshes.py TURN)


def _quaternions(m: np.ndarray) -> np.ndarray:
    """(N, 4) the unit quaternions (x, y, z, w) of (N, 3, 3) rotation matrices, each column's scale taken out
    first; w >= 0, one sign for one rotation (the page may blend neighbours). Shepperd's method: from the trace
    where it is positive, else from the largest diagonal entry."""
    r = m / np.sqrt((m * m).sum(axis=1, keepdims=True))  # each column's scale out
    r00, r01, r02 = r[:, 0, 0], r[:, 0, 1], r[:, 0, 2]
    r10, r11, r12 = r[:, 1, 0], r[:, 1, 1], r[:, 1, 2]
    r20, r21, r22 = r[:, 2, 0], r[:, 2, 1], r[:, 2, 2]
    trace = r00 + r11 + r22
    case = np.full(len(m), 3)  # the scalar version's branches, in its order: trace, then the largest diagonal
    case[r11 > r22] = 2
    case[(r00 > r11) & (r00 > r22)] = 1
    case[trace > 0.0] = 0
    radicand = np.choose(case, [trace + 1.0, 1.0 + r00 - r11 - r22, 1.0 + r11 - r00 - r22, 1.0 + r22 - r00 - r11])
    s = 2.0 * np.sqrt(radicand)
    quarter = 0.25 * s
    q = np.stack([
        np.choose(case, [(r21 - r12) / s, quarter, (r01 + r10) / s, (r02 + r20) / s]),
        np.choose(case, [(r02 - r20) / s, (r01 + r10) / s, quarter, (r12 + r21) / s]),
        np.choose(case, [(r10 - r01) / s, (r02 + r20) / s, (r12 + r21) / s, quarter]),
        np.choose(case, [quarter, (r21 - r12) / s, (r02 - r20) / s, (r10 - r01) / s]),
    ], axis=-1)
    q[q[:, 3] < 0.0] *= -1.0  # one sign for one rotation
    return q


@dataclass(frozen=True)
class FrameLayout:
    """Sizes of one agent's frames."""

    n_weights: int
    n_joints: int

    @property
    def size(self) -> int:
        return HEADER.size + self.n_weights + 8 * self.n_joints


class BrowserFace:
    """One avatar as the page draws it: `description(slot, url)` once, `pack_many(batch, ...)` every frame."""

    def __init__(self, avatar: Avatar, size: tuple[int, int]) -> None:
        for prim in avatar.primitives:
            if prim.source[0] < 0:
                raise ValueError(f"{avatar.source}: a primitive not from the file cannot be found by a page")
        self.avatar = avatar
        self.driver = AvatarDriver(avatar)
        self.size = size
        d = self.driver
        self.joints = tuple(j for j in (d.neck, d.head, d.jaw, *d.eyes) if j >= 0)
        self._rest = np.asarray(avatar.skeleton.rest, dtype=np.float64)
        self._vrm0 = avatar.format == "vrm0"
        self.layout = FrameLayout(d.n_targets, len(self.joints))
        self.voiced = self._voiced_targets()
        self._described: dict[str, Any] | None = None

    def _voiced_targets(self) -> np.ndarray:
        """Which targets (flat, the driver's order) the voice moves: reached from an ARKit jaw, mouth or tongue
        shape, a viseme or a VRM vowel."""
        d = self.driver
        speech_sources = {i for i, name in enumerate(ARKIT_NAMES) if name.startswith(_SPEECH_PREFIXES)}
        speech_sources |= set(range(N_ARKIT, N_ARKIT + N_VISEMES))
        names = list(self.avatar.expressions)
        speech_sources |= {N_ARKIT + N_VISEMES + k for k, name in enumerate(names) if name in VRM_VOWELS}
        rows, cols = d.source_table()
        voiced = np.zeros(d.n_targets, dtype=bool)
        voiced[rows[np.isin(cols, sorted(speech_sources))]] = True
        return voiced

    def description(self, slot: int, url: str) -> dict[str, Any]:
        """What the page needs to draw this avatar (see the module docstring); the avatar's part is worked out once."""
        if self._described is None:
            self._described = self._describe()
        return {**self._described, "slot": slot, "url": url}

    def _describe(self) -> dict[str, Any]:
        from eca.services.processes.renderer import avatar_framing  # numpy only: the head's framing, no GL

        avatar = self.avatar
        width, height = self.size
        view_m, proj = avatar_framing(avatar, width / height)
        primitives = []
        for p, prim in enumerate(avatar.primitives):
            a, b = self.driver.target_slice(p)
            primitives.append({"node": prim.source[0], "primitive": prim.source[1], "targets": b - a,
                               "voiced": [int(v) for v in self.voiced[a:b]]})
        nodes = avatar.skeleton.nodes
        return {
            "format": avatar.format, "width": width, "height": height,
            # three-vrm refuses a VRM 1.0 whose licence URL is not the one it knows; the operator chose this file
            "license_url": avatar.license_url,
            "primitives": primitives,
            "joints": [{"node": nodes[j], "voiced": int(j == self.driver.jaw)} for j in self.joints],
            # column-major, as three.js' Matrix4.fromArray takes them
            "view": [float(v) for v in np.asarray(view_m).T.ravel()],
            "projection": [float(v) for v in np.asarray(proj).T.ravel()],
            "frame_bytes": self.layout.size,
        }

    def pack_many(self, batch: RigBatch, rows: Sequence[int], slots: Sequence[int], seq: int, time_ms: float,
                  voiced: Sequence[bool], mark: bool = False) -> list[bytes]:
        """The frames (see the module docstring) of many agents of this avatar at one instant, `batch`'s rows
        `rows`, posed and packed in one batch of array operations: many conversations share a face."""
        pose = self.driver.drive_many(batch, rows)
        n = len(rows)
        out = np.empty((n, self.layout.size), dtype=np.uint8)
        weights = np.rint(pose.flat * 255.0).astype(np.uint8)
        at = HEADER.size
        out[:, at:at + self.layout.n_weights] = weights
        at += self.layout.n_weights
        if self.joints:
            # every joint of every agent in one call: _quaternions is some forty array operations whatever the
            # rows, which one call per joint paid four or five times a frame slot (about 200 us at N = 1)
            posed = [pose.local.get(joint) for joint in self.joints]
            local = np.stack([np.broadcast_to(self._rest[joint, :3, :3], (n, 3, 3)) if m is None else m
                              for joint, m in zip(self.joints, posed, strict=True)]).astype(np.float64, copy=False)
            if self._vrm0:
                local = _TURN @ local @ _TURN
            q = np.rint(_quaternions(local.reshape(-1, 3, 3)) * 32767.0).astype("<i2")
            n_joints = len(self.joints)
            out[:, at:at + 8 * n_joints] = q.reshape(n_joints, n, 4).transpose(1, 0, 2).reshape(n, 4 * n_joints) \
                .view(np.uint8)
        frames = []
        for i in range(n):
            flags = (VOICED if voiced[i] else 0) | (MARK if mark else 0)
            row = out[i]
            HEADER.pack_into(row, 0, slots[i], FRAME, flags, seq & 0xFFFFFFFF, time_ms)
            frames.append(row.tobytes())
        return frames


def pack_voice_clock(slot: int, rtp_timestamp: int, ntp_ms: float) -> bytes:
    """The voice's clock message (see the module docstring)."""
    return HEADER.pack(slot, VOICE_CLOCK, 0, rtp_timestamp & 0xFFFFFFFF, ntp_ms)


def pack_voice_spurts(slot: int, rtp_timestamp: int, ntp_ms: float, way_ms: float, last_seq: int,
                      spurts: Sequence[tuple[int, int]]) -> bytes:
    """The voice's clock through Janus (see the module docstring): `spurts` (sequence number, RTP timestamp) of the
    latest spurts' first packets, oldest first."""
    if not 1 <= len(spurts) <= MAX_SPURTS:
        raise ValueError(f"a voice's clock names 1..{MAX_SPURTS} spurts, not {len(spurts)}")
    return b"".join((HEADER.pack(slot, VOICE_SPURTS, len(spurts), rtp_timestamp & 0xFFFFFFFF, ntp_ms),
                     _SPURTS_HEAD.pack(way_ms, last_seq & 0xFFFF),
                     *(_SPURT.pack(seq & 0xFFFF, ts & 0xFFFFFFFF) for seq, ts in spurts)))


def unpack_voice_spurts(data: bytes) -> tuple[int, int, float, float, int, list[tuple[int, int]]]:
    """(slot, RTP timestamp, NTP ms, way to Janus ms, last sequence number, spurts) of a voice's clock through Janus:
    the page's reading, for tests and tools. ValueError for bytes that are not one."""
    if len(data) < HEADER.size + _SPURTS_HEAD.size:
        raise ValueError(f"a voice's clock through Janus has at least {HEADER.size + _SPURTS_HEAD.size} bytes")
    slot, kind, count, rtp, ntp = HEADER.unpack_from(data, 0)
    if kind != VOICE_SPURTS or not 1 <= count <= MAX_SPURTS:
        raise ValueError(f"message kind {kind} with {count} spurts, not the voice's spurts ({VOICE_SPURTS})")
    at = HEADER.size + _SPURTS_HEAD.size
    if len(data) != at + count * _SPURT.size:
        raise ValueError(f"a voice's clock with {count} spurts has {at + count * _SPURT.size} bytes, not {len(data)}")
    way_ms, last_seq = _SPURTS_HEAD.unpack_from(data, HEADER.size)
    spurts = [_SPURT.unpack_from(data, at + i * _SPURT.size) for i in range(count)]
    return slot, rtp, ntp, way_ms, last_seq, spurts


def ntp_ms(ntp: int) -> float:
    """A 64-bit NTP timestamp (seconds since 1900 in the high 32 bits, the fraction in the low) in milliseconds."""
    return (ntp >> 32) * 1000.0 + (ntp & 0xFFFFFFFF) * 1000.0 / 2**32


def unpack(data: bytes, layout: FrameLayout) -> tuple[int, int, int, float, np.ndarray, np.ndarray]:
    """(slot, flags, seq, time_ms, weights 0..1, quaternions (J, 4)) of a packed frame: the page's reading, for
    tests and tools. ValueError for bytes that are not one."""
    if len(data) != layout.size:
        raise ValueError(f"a frame of this face has {layout.size} bytes, got {len(data)}")
    slot, kind, flags, seq, time_ms = HEADER.unpack_from(data, 0)
    if kind != FRAME:
        raise ValueError(f"message kind {kind}, not a frame ({FRAME})")
    at = HEADER.size
    weights = np.frombuffer(data, dtype=np.uint8, count=layout.n_weights, offset=at).astype(np.float64) / 255.0
    at += layout.n_weights
    quats = np.frombuffer(data, dtype="<i2", count=4 * layout.n_joints, offset=at).astype(np.float64) / 32767.0
    return slot, flags, seq, time_ms, weights, quats.reshape(layout.n_joints, 4)
