"""The names the rigs of the world use for face weights, in every spelling they come in.

Three vocabularies, each in one canonical order that the arrays of a `RigFrame` follow:

- ARKit's 52 blendshapes, in Unreal's `EARFaceBlendShape` order (EyeBlinkLeft ... TongueOut). The Live Link Face
  packet carries them in this order (JimWest/PyLiveLinkFace `FaceBlendShape` 0-51; Epic's API reference of
  EARFaceBlendShape in ARTrackable.h), so a sender can pack the array as it is. Spellings in the wild: PascalCase
  `EyeBlinkLeft` (Unreal, Live Link, Audio2Face-3D, VRM "Perfect Sync"), camelCase `eyeBlinkLeft` (Apple's
  constant names, MediaPipe, TalkingHead) and ARKit's raw string values `eyeBlink_L` (where the four whole-mouth
  or whole-jaw names jawLeft, jawRight, mouthLeft, mouthRight keep their spelling: they are no sides).
  "Left" is the face's own left (ARFaceAnchor: +x is the face's left), as eca's `_l` flexors are.
- The 15 Oculus/Meta visemes (OVRLipSync; OpenXR XrFaceTrackingVisemeMETA order), also spelled as glTF shape
  keys `viseme_sil` ... `viseme_E`, `viseme_I`, `viseme_O`, `viseme_U` (Ready Player Me, TalkingHead).
- VRM 1.0's 18 expression presets (vrm-specification VRMC_vrm-1.0/expressions.md), and the 17 VRM 0.x
  blend-shape presets they replace (three-vrm's 0.x loader: a->aa, joy->happy, sorrow->sad, fun->relaxed ...;
  0.x has no `surprised`).

Lookups are case-insensitive and ignore `_`, `-`, `.` and spaces; a `_L`/`_R` (or `.L`/`.R`) ending means
Left/Right. An unknown name raises ValueError listing the closest known names.
"""

from __future__ import annotations

import difflib
import re
from collections.abc import Mapping
from typing import Literal

import numpy as np

ArkitSpelling = Literal["pascal", "camel", "raw"]
VisemeSpelling = Literal["oculus", "gltf"]

ARKIT_NAMES: tuple[str, ...] = (
    "EyeBlinkLeft", "EyeLookDownLeft", "EyeLookInLeft", "EyeLookOutLeft", "EyeLookUpLeft", "EyeSquintLeft",
    "EyeWideLeft",
    "EyeBlinkRight", "EyeLookDownRight", "EyeLookInRight", "EyeLookOutRight", "EyeLookUpRight", "EyeSquintRight",
    "EyeWideRight",
    "JawForward", "JawLeft", "JawRight", "JawOpen",
    "MouthClose", "MouthFunnel", "MouthPucker", "MouthLeft", "MouthRight",
    "MouthSmileLeft", "MouthSmileRight", "MouthFrownLeft", "MouthFrownRight", "MouthDimpleLeft", "MouthDimpleRight",
    "MouthStretchLeft", "MouthStretchRight", "MouthRollLower", "MouthRollUpper", "MouthShrugLower",
    "MouthShrugUpper", "MouthPressLeft", "MouthPressRight", "MouthLowerDownLeft", "MouthLowerDownRight",
    "MouthUpperUpLeft", "MouthUpperUpRight",
    "BrowDownLeft", "BrowDownRight", "BrowInnerUp", "BrowOuterUpLeft", "BrowOuterUpRight",
    "CheekPuff", "CheekSquintLeft", "CheekSquintRight", "NoseSneerLeft", "NoseSneerRight",
    "TongueOut",
)  # fmt: skip
N_ARKIT = len(ARKIT_NAMES)
ARKIT_INDEX: dict[str, int] = {name: i for i, name in enumerate(ARKIT_NAMES)}

# Whole-jaw / whole-mouth movements whose names end in Left/Right without being one side of a pair.
_NOT_SIDED = frozenset({"JawLeft", "JawRight", "MouthLeft", "MouthRight"})

VISEME_NAMES: tuple[str, ...] = (
    "sil", "PP", "FF", "TH", "DD", "kk", "CH", "SS", "nn", "RR", "aa", "E", "ih", "oh", "ou",
)  # fmt: skip
N_VISEMES = len(VISEME_NAMES)
VISEME_INDEX: dict[str, int] = {name: i for i, name in enumerate(VISEME_NAMES)}
_GLTF_VISEME = {"ih": "I", "oh": "O", "ou": "U"}  # Ready Player Me's shape-key names of the three vowels

VRM_NAMES: tuple[str, ...] = (
    "happy", "angry", "sad", "relaxed", "surprised",
    "aa", "ih", "ou", "ee", "oh",
    "blink", "blinkLeft", "blinkRight",
    "lookUp", "lookDown", "lookLeft", "lookRight",
    "neutral",
)  # fmt: skip
N_VRM = len(VRM_NAMES)
VRM_INDEX: dict[str, int] = {name: i for i, name in enumerate(VRM_NAMES)}
VRM_EMOTIONS: tuple[str, ...] = VRM_NAMES[:5]
VRM_VOWELS: tuple[str, ...] = VRM_NAMES[5:10]

# VRM 0.x preset -> VRM 1.0 preset (three-vrm's VRM 0.x importer); 0.x has no "surprised".
VRM0_TO_VRM1: dict[str, str] = {
    "A": "aa", "I": "ih", "U": "ou", "E": "ee", "O": "oh",
    "Joy": "happy", "Angry": "angry", "Sorrow": "sad", "Fun": "relaxed",
    "Blink": "blink", "Blink_L": "blinkLeft", "Blink_R": "blinkRight",
    "LookUp": "lookUp", "LookDown": "lookDown", "LookLeft": "lookLeft", "LookRight": "lookRight",
    "Neutral": "neutral",
}  # fmt: skip
VRM0_NAMES: tuple[str, ...] = tuple(VRM0_TO_VRM1)

_SIDE_SUFFIX = re.compile(r"[._]([LR])$", re.IGNORECASE)
_SEPARATORS = re.compile(r"[\s_.\-]+")


def _key(name: str) -> str:
    """The comparison key of a name: a `_L`/`_R` ending spelled out, then lower case without separators."""
    stripped = name.strip()
    stripped = _SIDE_SUFFIX.sub(lambda m: "Left" if m.group(1) in "lL" else "Right", stripped)
    return _SEPARATORS.sub("", stripped).lower()


def _camel(name: str) -> str:
    return name[0].lower() + name[1:]


def _raw(name: str) -> str:
    if name in _NOT_SIDED:
        return _camel(name)
    for side, suffix in (("Left", "_L"), ("Right", "_R")):
        if name.endswith(side):
            return _camel(name[: -len(side)]) + suffix
    return _camel(name)


_ARKIT_SPELLINGS: dict[str, tuple[str, ...]] = {
    "pascal": ARKIT_NAMES,
    "camel": tuple(_camel(n) for n in ARKIT_NAMES),
    "raw": tuple(_raw(n) for n in ARKIT_NAMES),
}
_ARKIT_KEYS: dict[str, int] = {_key(n): i for i, n in enumerate(ARKIT_NAMES)}

_VISEME_KEYS: dict[str, int] = {name.lower(): i for i, name in enumerate(VISEME_NAMES)}
_VISEME_KEYS.update({gltf.lower(): VISEME_INDEX[ovr] for ovr, gltf in _GLTF_VISEME.items()})

_VRM_KEYS: dict[str, int] = {_key(n): i for i, n in enumerate(VRM_NAMES)}
_VRM_KEYS.update({_key(v0): VRM_INDEX[v1] for v0, v1 in VRM0_TO_VRM1.items()})


def _resolve(name: object, keys: Mapping[str, int], display: tuple[str, ...], what: str, key: str) -> int:
    if not isinstance(name, str):
        raise ValueError(f"a {what} name must be a string, got {name!r}")
    index = keys.get(key)
    if index is not None:
        return index
    close = difflib.get_close_matches(key, list(keys), n=4, cutoff=0.6)
    hint = ", ".join(dict.fromkeys(display[keys[c]] for c in close))
    suggestion = f"; did you mean {hint}?" if hint else f"; known names: {', '.join(display)}"
    raise ValueError(f"unknown {what} name {name!r}{suggestion}")


def arkit_names(spelling: ArkitSpelling = "pascal") -> tuple[str, ...]:
    """The 52 ARKit names in canonical order: "pascal" `EyeBlinkLeft`, "camel" `eyeBlinkLeft`, "raw" `eyeBlink_L`."""
    try:
        return _ARKIT_SPELLINGS[spelling]
    except KeyError:
        raise ValueError(f"unknown ARKit spelling {spelling!r}; spellings: {', '.join(_ARKIT_SPELLINGS)}") from None


def arkit_index(name: str) -> int:
    """The position of an ARKit blendshape in any spelling (`eyeBlink_L`, `EyeBlinkLeft`, `eye_blink_left`)."""
    return _resolve(name, _ARKIT_KEYS, ARKIT_NAMES, "ARKit blendshape", _key(name) if isinstance(name, str) else "")


def canonical_arkit_name(name: str) -> str:
    """The PascalCase (Unreal / Live Link) spelling of an ARKit name given in any spelling."""
    return ARKIT_NAMES[arkit_index(name)]


def viseme_names(spelling: VisemeSpelling = "oculus") -> tuple[str, ...]:
    """The 15 visemes in OVRLipSync order: "oculus" (sil, PP, ... ou) or "gltf" (viseme_sil ... viseme_U)."""
    if spelling == "oculus":
        return VISEME_NAMES
    if spelling == "gltf":
        return tuple(f"viseme_{_GLTF_VISEME.get(n, n)}" for n in VISEME_NAMES)
    raise ValueError(f"unknown viseme spelling {spelling!r}; spellings: oculus, gltf")


def viseme_index(name: str) -> int:
    """The position of a viseme: `aa`, `AA`, `viseme_aa`; Ready Player Me's `viseme_I`/`O`/`U` are ih/oh/ou."""
    key = ""
    if isinstance(name, str):
        key = name.strip().lower()
        key = key.removeprefix("viseme_").removeprefix("viseme")
    return _resolve(name, _VISEME_KEYS, VISEME_NAMES, "viseme", key)


def vrm_names(version: int = 1) -> tuple[str, ...]:
    """VRM expression presets: version 1 gives the 18 of VRM 1.0 (RigFrame.vrm's order), version 0 the 17
    blend-shape presets of VRM 0.x (VSeeFace and other VMC receivers still expect these)."""
    if version == 1:
        return VRM_NAMES
    if version == 0:
        return VRM0_NAMES
    raise ValueError(f"unknown VRM version {version!r}; versions: 0, 1")


def vrm_index(name: str) -> int:
    """The position in RigFrame.vrm of a VRM 1.0 preset (`blinkLeft`) or its VRM 0.x name (`Blink_L`, `Joy`)."""
    return _resolve(name, _VRM_KEYS, VRM_NAMES, "VRM expression", _key(name) if isinstance(name, str) else "")


def mirror_name(name: str) -> str:
    """The left/right mirror image of a PascalCase or camelCase name: EyeBlinkLeft <-> EyeBlinkRight,
    MouthLeft <-> MouthRight, lookLeft <-> lookRight; a name without a side is its own mirror."""
    for side, other in (("Left", "Right"), ("Right", "Left")):
        if name.endswith(side):
            return name[: -len(side)] + other
    return name


def _mirror_permutation(names: tuple[str, ...]) -> np.ndarray:
    index = {n: i for i, n in enumerate(names)}
    return np.array([index[mirror_name(n)] for n in names], dtype=np.intp)


# weights[MIRROR] are the weights of the mirrored face's names (Left <-> Right swapped).
ARKIT_MIRROR = _mirror_permutation(ARKIT_NAMES)
VRM_MIRROR = _mirror_permutation(VRM_NAMES)
