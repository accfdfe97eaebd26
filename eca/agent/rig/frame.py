"""`RigFrame`: the composed face at one instant, as the weights and angles the world's rigs take.

One frame carries every vocabulary at once, so a sender picks what its receiver speaks:

- `arkit`: the 52 ARKit blendshape weights in 0..1, in Unreal's EARFaceBlendShape order (names.ARKIT_NAMES), the
  order of a Live Link Face packet's first 52 floats;
- head yaw, pitch, roll and each eye's yaw and pitch in degrees, straight from the `ComposedFace` (vergence kept),
  in the agent's own frame: yaw + = toward the agent's right, pitch + = up, roll + = toward the right shoulder;
- `visemes`: the 15 Oculus visemes in 0..1 (summing to 1), OVRLipSync order (names.VISEME_NAMES);
- `vrm`: the 18 VRM 1.0 expression presets in 0..1 (names.VRM_NAMES); `vrm_dict(version=0)` gives them under
  the VRM 0.x names.

Accessors take a name in any spelling (names.py). `RigBatch` is the same for many agents at once, as arrays.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from eca.agent.face.composed import EyeAngles
from eca.agent.rig.names import (
    N_ARKIT,
    N_VISEMES,
    N_VRM,
    VRM0_TO_VRM1,
    VRM_INDEX,
    ArkitSpelling,
    VisemeSpelling,
    arkit_index,
    arkit_names,
    viseme_index,
    viseme_names,
    vrm_index,
    vrm_names,
)


def _weights(values: object, size: int, what: str) -> np.ndarray:
    array = np.array(values, dtype=np.float64)
    if array.shape != (size,):
        raise ValueError(f"{what} needs shape ({size},), got {array.shape}")
    if not np.all(np.isfinite(array)) or np.any(array < 0.0) or np.any(array > 1.0):
        raise ValueError(f"{what} weights must be finite and within 0..1")
    array.flags.writeable = False
    return array


@dataclass(frozen=True, eq=False)
class RigFrame:
    """The face at `t_ns` for rigs; see the module docstring. Arrays are read-only."""

    t_ns: int
    arkit: np.ndarray  # (52,)
    head_yaw_deg: float
    head_pitch_deg: float
    head_roll_deg: float
    left_eye: EyeAngles
    right_eye: EyeAngles
    visemes: np.ndarray  # (15,)
    vrm: np.ndarray  # (18,)

    def __post_init__(self) -> None:
        object.__setattr__(self, "t_ns", int(self.t_ns))
        object.__setattr__(self, "arkit", _weights(self.arkit, N_ARKIT, "arkit"))
        object.__setattr__(self, "visemes", _weights(self.visemes, N_VISEMES, "visemes"))
        object.__setattr__(self, "vrm", _weights(self.vrm, N_VRM, "vrm"))
        for name in ("head_yaw_deg", "head_pitch_deg", "head_roll_deg"):
            value = float(getattr(self, name))
            if not np.isfinite(value):
                raise ValueError(f"{name} must be finite, got {value!r}")
            object.__setattr__(self, name, value)

    @classmethod
    def trusted(cls, t_ns: int, arkit: np.ndarray, head: tuple[float, float, float], left_eye: EyeAngles,
                right_eye: EyeAngles, visemes: np.ndarray, vrm: np.ndarray) -> RigFrame:
        """A frame of values a retargeter has just made (clipped, right shapes, read-only): taken as they are,
        without checking them again on every frame."""
        frame = object.__new__(cls)
        for name, value in (("t_ns", t_ns), ("arkit", arkit), ("head_yaw_deg", head[0]), ("head_pitch_deg", head[1]),
                            ("head_roll_deg", head[2]), ("left_eye", left_eye), ("right_eye", right_eye),
                            ("visemes", visemes), ("vrm", vrm)):
            object.__setattr__(frame, name, value)
        return frame

    @property
    def head_deg(self) -> tuple[float, float, float]:
        """(yaw, pitch, roll) in degrees."""
        return (self.head_yaw_deg, self.head_pitch_deg, self.head_roll_deg)

    def arkit_weight(self, name: str) -> float:
        """One ARKit weight by name in any spelling: `eyeBlinkLeft`, `EyeBlinkLeft`, `eyeBlink_L`."""
        return float(self.arkit[arkit_index(name)])

    def viseme_weight(self, name: str) -> float:
        """One viseme weight: `aa`, `viseme_aa`, `viseme_I` (= ih)."""
        return float(self.visemes[viseme_index(name)])

    def vrm_weight(self, name: str) -> float:
        """One VRM preset weight by its 1.0 name (`blinkLeft`) or 0.x name (`Blink_L`, `Joy`, `A`)."""
        return float(self.vrm[vrm_index(name)])

    def arkit_dict(self, spelling: ArkitSpelling = "pascal") -> dict[str, float]:
        return dict(zip(arkit_names(spelling), self.arkit.tolist(), strict=True))

    def viseme_dict(self, spelling: VisemeSpelling = "oculus") -> dict[str, float]:
        return dict(zip(viseme_names(spelling), self.visemes.tolist(), strict=True))

    def vrm_dict(self, version: int = 1) -> dict[str, float]:
        """The VRM presets under their 1.0 names, or (version=0) under the 0.x names (no `surprised` there)."""
        if version == 0:
            return {v0: float(self.vrm[VRM_INDEX[v1]]) for v0, v1 in VRM0_TO_VRM1.items()}
        return dict(zip(vrm_names(version), self.vrm.tolist(), strict=True))

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, RigFrame):
            return NotImplemented
        return (
            self.t_ns == other.t_ns
            and self.head_deg == other.head_deg
            and self.left_eye == other.left_eye
            and self.right_eye == other.right_eye
            and bool(np.array_equal(self.arkit, other.arkit))
            and bool(np.array_equal(self.visemes, other.visemes))
            and bool(np.array_equal(self.vrm, other.vrm))
        )

    __hash__ = None  # type: ignore[assignment]


@dataclass(frozen=True, eq=False)
class RigBatch:
    """Rig weights of N faces at `t_ns` (one row per agent): what `Retargeter.retarget_many` returns."""

    t_ns: int
    arkit: np.ndarray  # (N, 52)
    head_deg: np.ndarray  # (N, 3): yaw, pitch, roll
    eyes_deg: np.ndarray  # (N, 4): left yaw, left pitch, right yaw, right pitch
    visemes: np.ndarray  # (N, 15)
    vrm: np.ndarray  # (N, 18)

    def __post_init__(self) -> None:
        for array in (self.arkit, self.head_deg, self.eyes_deg, self.visemes, self.vrm):
            array.flags.writeable = False

    def __len__(self) -> int:
        return int(self.arkit.shape[0])

    def frame(self, i: int) -> RigFrame:
        """Row i as a RigFrame (its arrays are read-only views of the batch's)."""
        head, eyes = self.head_deg[i].tolist(), self.eyes_deg[i].tolist()
        return RigFrame.trusted(self.t_ns, self.arkit[i], (head[0], head[1], head[2]), EyeAngles(eyes[0], eyes[1]),
                                EyeAngles(eyes[2], eyes[3]), self.visemes[i], self.vrm[i])
