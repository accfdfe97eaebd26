"""The rig frames of an offline render as a Live Link Face CSV: the take format Unreal and Blender import.

Epic's Live Link Face app records each take as a CSV of one header line and one line per captured frame:
`Timecode,BlendShapeCount,` then the 52 ARKit weights and nine angles (head yaw, pitch, roll, and each eye's
yaw, pitch, roll). Epic publishes no specification, but the layout is what the importers read, so it is the
de-facto interchange format for ARKit face animation:

- Unreal's LiveLinkFaceImporter plugin (Engine/Plugins/Experimental/LiveLinkFaceImporter,
  LiveLinkFaceImporterFactory.cpp) requires the first two columns to be named `Timecode` and `BlendShapeCount`,
  imports every other column as a Live Link property by its header name, and reads the timecode as
  `hh:mm:ss:ff.fff` with `ff.fff` counted in 60ths of a second (it divides by 60 whatever the take's rate);
- Blender add-ons read it: the Diffeomorphic DAZ importer's "Import Live Link File" (names from the header, the
  last nine columns as angles in radians), nmfisher/blender_livelinkface "Load from CSV" (columns by position,
  in the app's order); so do Maya and MotionBuilder scripts.

So this module writes that layout exactly: the app's header, word for word (its order differs from Unreal's
EARFaceBlendShape enum in two places: JawRight before JawLeft, MouthRight before MouthLeft), the app's
timecode (frames of 1/60 s with three decimals; the rows themselves are the render's frames), the count 61,
weights in 0..1 and angles in radians in the app's signs. The signs were read off recorded takes, where each
angle moves with the eyeLook weights of the same file: yaw grows toward the face's right (with EyeLookInLeft
and EyeLookOutRight), pitch grows downward (with EyeLookDown). No take we found moves the head against a known
motion, so the head's angles take the eyes' convention (the app writes both from one conversion, in which a
mirror flips yaw and roll together): roll is taken to grow toward the face's left shoulder. Eye roll is 0: eca's
eyes have no torsion.

One file holds one face (the importers make one subject of it), so a render of several agents writes one file
per agent. docs/scripts.md ("The rig CSV") and docs/rig.md say how to import it.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from eca.agent.rig import Retargeter
from eca.agent.rig.names import ARKIT_INDEX
from eca.services.processes.rig.livelink import live_link_angles

# The 52 shapes in the column order of the app's CSV (its takes, and the add-ons that index by position).
LIVE_LINK_FACE_SHAPES: tuple[str, ...] = (
    "EyeBlinkLeft", "EyeLookDownLeft", "EyeLookInLeft", "EyeLookOutLeft", "EyeLookUpLeft", "EyeSquintLeft",
    "EyeWideLeft",
    "EyeBlinkRight", "EyeLookDownRight", "EyeLookInRight", "EyeLookOutRight", "EyeLookUpRight", "EyeSquintRight",
    "EyeWideRight",
    "JawForward", "JawRight", "JawLeft", "JawOpen",
    "MouthClose", "MouthFunnel", "MouthPucker", "MouthRight", "MouthLeft",
    "MouthSmileLeft", "MouthSmileRight", "MouthFrownLeft", "MouthFrownRight", "MouthDimpleLeft", "MouthDimpleRight",
    "MouthStretchLeft", "MouthStretchRight", "MouthRollLower", "MouthRollUpper", "MouthShrugLower",
    "MouthShrugUpper", "MouthPressLeft", "MouthPressRight", "MouthLowerDownLeft", "MouthLowerDownRight",
    "MouthUpperUpLeft", "MouthUpperUpRight",
    "BrowDownLeft", "BrowDownRight", "BrowInnerUp", "BrowOuterUpLeft", "BrowOuterUpRight",
    "CheekPuff", "CheekSquintLeft", "CheekSquintRight", "NoseSneerLeft", "NoseSneerRight",
    "TongueOut",
)  # fmt: skip
LIVE_LINK_FACE_ANGLES: tuple[str, ...] = (
    "HeadYaw", "HeadPitch", "HeadRoll",
    "LeftEyeYaw", "LeftEyePitch", "LeftEyeRoll",
    "RightEyeYaw", "RightEyePitch", "RightEyeRoll",
)  # fmt: skip
RIG_CSV_COLUMNS: tuple[str, ...] = ("Timecode", "BlendShapeCount", *LIVE_LINK_FACE_SHAPES, *LIVE_LINK_FACE_ANGLES)
BLEND_SHAPE_COUNT = len(LIVE_LINK_FACE_SHAPES) + len(LIVE_LINK_FACE_ANGLES)  # 61, as the app writes it
TIMECODE_RATE = 60  # the timecode's frame field counts 60ths of a second (the app's and the importer's rate)

# RigFrame's ARKit order (Unreal's enum) -> the CSV's column order.
_COLUMN_ORDER = np.array([ARKIT_INDEX[name] for name in LIVE_LINK_FACE_SHAPES], dtype=np.intp)


def live_link_timecode(k: int, fps: float) -> str:
    """The timecode of frame k of a render at `fps`, as the app writes it: `hh:mm:ss:ff.fff`, counted from 0,
    with `ff.fff` the frames of 1/60 s into the second to a thousandth (exact for rates dividing 60 000:
    24, 25, 30, 50, 60 ...)."""
    thousandths = round(k * TIMECODE_RATE * 1000 / fps)  # of a 1/60 s frame, since the start
    seconds, rest = divmod(thousandths, TIMECODE_RATE * 1000)
    frame, fraction = divmod(rest, 1000)
    minutes, second = divmod(seconds, 60)
    hours, minute = divmod(minutes, 60)
    return f"{hours:02d}:{minute:02d}:{second:02d}:{frame:02d}.{fraction:03d}"


def _number(value: float) -> str:
    # Six decimals, as the flexor CSV (the same frames give the same bytes); -0 printed as 0.
    text = f"{value:.6f}"
    return text[1:] if text == "-0.000000" else text


def rig_table(flexors: np.ndarray, head_deg: np.ndarray, eyes_deg: np.ndarray,
              retargeter: Retargeter | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(weights (N, 52) in the CSV's column order, angles (N, 9) in radians in the CSV's signs) of N composed
    faces given as flexors (N, 21), head angles (N, 3) [yaw, pitch, roll] and eye angles (N, 4) [left yaw, left
    pitch, right yaw, right pitch], all in eca's degrees and signs (agent/face/composed.py)."""
    rig = retargeter if retargeter is not None else Retargeter.load()
    batch = rig.retarget_many(flexors, eyes_deg=eyes_deg, head_deg=head_deg)
    # The same angles as the live packets (one convention: eca/services/processes/rig/livelink.py).
    return batch.arkit[:, _COLUMN_ORDER], live_link_angles(np.hstack((batch.head_deg, batch.eyes_deg)))


def write_live_link_csv(path: Path, fps: float, flexors: np.ndarray, head_deg: np.ndarray, eyes_deg: np.ndarray,
                  retargeter: Retargeter | None = None) -> None:
    """One Live Link Face CSV (RIG_CSV_COLUMNS) of one face: a line per frame, frame k at k / fps."""
    weights, angles = rig_table(flexors, head_deg, eyes_deg, retargeter)
    count = str(BLEND_SHAPE_COUNT)
    with open(path, "w", newline="\n", encoding="utf-8") as fh:
        fh.write(",".join(RIG_CSV_COLUMNS) + "\n")
        for k in range(weights.shape[0]):
            numbers = (_number(v) for v in (*weights[k].tolist(), *angles[k].tolist()))
            fh.write(",".join((live_link_timecode(k, fps), count, *numbers)) + "\n")


def rig_csv_path(csv_path: Path, agent: str) -> Path:
    """Where the rig frames of `agent` go: beside the flexor CSV, `<its stem>_rig_<agent>.csv`."""
    return csv_path.with_name(f"{csv_path.stem}_rig_{agent}.csv")


def rig_csv_paths(csv_path: Path, agents: Sequence[str]) -> list[Path]:
    """The rig CSV of each agent, in the order given."""
    return [rig_csv_path(csv_path, agent) for agent in agents]

