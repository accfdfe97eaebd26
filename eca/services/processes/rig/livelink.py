"""The Live Link Face packet: what Epic's Live Link Face app sends to Unreal's Apple ARKit Live Link source (UDP,
port 11111), one packet per subject per frame.

Epic does not publish the layout; this is the one JimWest/PyLiveLinkFace (pylivelinkface.py, `encode` and
`decode`) writes and reads, which Unreal accepts:

| bytes | what |
|---|---|
| 4 | packet version 6, uint32 little-endian |
| 37 | device id: `$` and a 36-character UUID, UTF-8, no length before it |
| 4 + n | subject name: its length (int32 big-endian), then n bytes UTF-8 |
| 4 | frame number, int32 big-endian |
| 4 | sub-frame, float32 big-endian (the fraction of a frame, 0 ≤ s < 1) |
| 4 + 4 | frame rate numerator and denominator, int32 big-endian each |
| 1 | value count, uint8: 61 |
| 61 × 4 | float32 big-endian: the 52 ARKit weights in EARFaceBlendShape order (0-51), head yaw, pitch, roll |
|        | (52-54), left eye yaw, pitch, roll (55-57), right eye yaw, pitch, roll (58-60) |

(Read as Unreal does, the first byte is the version and the next four, `00 00 00 24`, are the big-endian length 36
of the device id string that follows: hence exactly 36 characters after the `$`.)

Angles are in radians with the app's signs (`live_link_angles`, shared with the recorded CSV that `eca render`
writes, eca/services/tools/rig_csv.py): the app's recorded takes carry radians (PyLiveLinkFace keeps head angles
in -1..1, and importers of the app's recordings, Faceit's among them, read them as radians), yaw + toward the
face's right (as eca's), pitch + down (each eye's pitch grows with its EyeLookDown in the takes), roll + toward
the face's left shoulder (no take moves the head against a known direction: inferred from a mirror flipping yaw
and roll together); each eye's angles are in the head, its roll 0. Epic documents no sign convention for these
curves: a rig that turns the other way negates the curve in its Anim Blueprint.

The frame time is the frame's time on the master clock carried over to the time of day (local midnight), as a
timecode at the frame rate: the app stamps its frames with a time-of-day timecode (its system clock by default), and
Unreal's timecode-synchronised evaluation compares with that. The offset between the two clocks is taken once, so
the frame numbers never jump.

Several agents are several subjects of one source: each packet names its agent as the subject, with a device id
of its own (a UUID made from the instance and the agent, so it stays the same across restarts).
"""

from __future__ import annotations

import struct
import time
import uuid
from collections.abc import Sequence
from fractions import Fraction

import numpy as np

from eca.agent.rig.names import N_ARKIT

# eca's angles [head yaw, pitch, roll, left eye yaw, pitch, right eye yaw, pitch] (degrees; yaw + toward the
# agent's right, pitch + up, roll + toward the right shoulder) -> the app's (radians; pitch and roll reversed),
# at these places of the nine angles [head yaw, pitch, roll, left eye yaw, pitch, roll, right eye yaw, pitch, roll].
LIVE_LINK_SIGNS = np.array([1.0, -1.0, -1.0, 1.0, -1.0, 1.0, -1.0])
LIVE_LINK_ANGLE_PLACES = np.array([0, 1, 2, 3, 4, 6, 7], dtype=np.intp)  # 5 and 8, each eye's roll, stay 0

VERSION = 6
VALUE_COUNT = 61  # 52 ARKit weights + head yaw/pitch/roll + each eye's yaw/pitch/roll
NS_PER_DAY = 86_400 * 10**9
_FRAME = struct.Struct(f">ifiiB{VALUE_COUNT}f")


def device_id(instance: str, agent: str) -> str:
    """A stable device id for an agent of an instance: `$` and a 36-character UUID."""
    return "$" + str(uuid.uuid5(uuid.NAMESPACE_URL, f"eca:{instance}/{agent}"))


def frame_rate(rate_hz: float) -> tuple[int, int]:
    """The rate as a whole-number fraction (numerator, denominator): 60 -> (60, 1), 29.97 -> (2997, 100)."""
    exact = Fraction(rate_hz).limit_denominator(1001)
    return exact.numerator, exact.denominator


def wall_offset_ns() -> int:
    """Nanoseconds to add to the monotonic (master) clock to get the local time of day since the epoch."""
    local = time.localtime()
    return time.time_ns() - time.monotonic_ns() + local.tm_gmtoff * 10**9


class LiveLinkPacker:
    """Builds one subject's Live Link Face packet per frame; the subject's header is made once."""

    def __init__(self, subject: str, device: str, rate_hz: float, offset_ns: int | None = None) -> None:
        if not device.startswith("$") or len(device) != 37:
            raise ValueError(f"a device id is '$' and 36 characters, got {device!r}")
        name = subject.encode("utf-8")
        self.header = struct.pack("<I", VERSION) + device.encode("utf-8") + struct.pack(">i", len(name)) + name
        self.numerator, self.denominator = frame_rate(rate_hz)
        self.offset_ns = wall_offset_ns() if offset_ns is None else offset_ns
        self._values = np.zeros(VALUE_COUNT)

    def frame_time(self, frame_ns: int) -> tuple[int, float]:
        """(frame number, sub-frame) of a master-clock time: the time of day at the frame rate."""
        day_ns = (frame_ns + self.offset_ns) % NS_PER_DAY
        scaled = day_ns * self.numerator  # frames = day_ns * numerator / (denominator * 1e9)
        per_frame = self.denominator * 10**9
        return scaled // per_frame, (scaled % per_frame) / per_frame

    def pack(self, frame_ns: int, arkit: np.ndarray, head_deg: Sequence[float], eyes_deg: Sequence[float]) -> bytes:
        """The packet of one frame: 52 ARKit weights, head (yaw, pitch, roll) and eyes (left yaw, left pitch, right
        yaw, right pitch) in eca's degrees, sent as the app's angles (live_link_angles)."""
        values = self._values
        values[:N_ARKIT] = arkit
        values[N_ARKIT:] = live_link_angles(np.concatenate((head_deg, eyes_deg)))
        frame, sub = self.frame_time(frame_ns)
        return self.header + _FRAME.pack(frame, min(sub, 0.99999994), self.numerator, self.denominator,
                                         VALUE_COUNT, *values.tolist())


def live_link_angles(eca_deg: np.ndarray) -> np.ndarray:
    """The nine Live Link Face angles (head yaw, pitch, roll, then each eye's yaw, pitch, roll; radians, the app's
    signs) of eca's seven ([head yaw, pitch, roll, left eye yaw, pitch, right eye yaw, pitch], degrees), for one
    face (7,) or many (N, 7)."""
    eca_deg = np.asarray(eca_deg, dtype=np.float64)
    out = np.zeros((*eca_deg.shape[:-1], 9))
    out[..., LIVE_LINK_ANGLE_PLACES] = np.radians(eca_deg * LIVE_LINK_SIGNS)
    return out
