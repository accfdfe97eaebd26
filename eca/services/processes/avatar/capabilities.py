"""What an avatar can show, found once at load: three things a face must have, and what it lacks beyond them.

Required (one `AvatarError` names every one that is missing):

- eyes that turn: a VRM lookAt of expression type with look* expressions ("vrm lookAt"), or eye joints (the
  humanoid's or nodes named like eyes: "bones"), or ARKit's four horizontal eyeLook shapes ("arkit shapes");
- eyes that blink: ARKit's EyeBlinkLeft and EyeBlinkRight ("arkit shapes"), or VRM's blink, or its blinkLeft and
  blinkRight ("vrm blink");
- a mouth that opens: ARKit's JawOpen ("arkit jawOpen"), visemes ("visemes"), VRM's vowels ("vrm vowels"), or a
  jaw joint ("jaw bone").

Beyond that, `missing` lists what the face will not show (brows, smile, ... for an ARKit face; the VRM emotions
an expression face lacks; a head joint), which the loader says once and the driver simply leaves out.
"""

from __future__ import annotations

from dataclasses import dataclass

from eca.agent.rig.names import ARKIT_NAMES, VRM_EMOTIONS, VRM_VOWELS, viseme_names
from eca.services.processes.avatar.errors import AvatarError
from eca.services.processes.avatar.model import Capabilities, Expression, LookAt, LookAtType
from eca.services.processes.avatar.shapes import arkit_name

EYE_LOOKS_HORIZONTAL = ("EyeLookInLeft", "EyeLookOutLeft", "EyeLookInRight", "EyeLookOutRight")
EYE_LOOKS_VERTICAL = ("EyeLookUpLeft", "EyeLookDownLeft", "EyeLookUpRight", "EyeLookDownRight")
VRM_LOOKS = ("lookUp", "lookDown", "lookLeft", "lookRight")
VRM_BLINKS = ("blink", "blinkLeft", "blinkRight")
# ARKit shapes that are part of eyes, blinks or the jaw: a face with only these still shows emotions by VRM.
NOT_EMOTION = frozenset(EYE_LOOKS_HORIZONTAL + EYE_LOOKS_VERTICAL + ("EyeBlinkLeft", "EyeBlinkRight", "JawOpen"))
PERFECT_SYNC_MIN = 8  # ARKit emotion shapes from which a face is driven by ARKit though it has VRM emotions too
ARKIT_GROUPS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("brows", ("BrowDownLeft", "BrowDownRight", "BrowInnerUp", "BrowOuterUpLeft", "BrowOuterUpRight")),
    ("smile", ("MouthSmileLeft", "MouthSmileRight")),
    ("frown", ("MouthFrownLeft", "MouthFrownRight")),
    ("squint", ("EyeSquintLeft", "EyeSquintRight")),
    ("wide eyes", ("EyeWideLeft", "EyeWideRight")),
    ("cheeks", ("CheekSquintLeft", "CheekSquintRight", "CheekPuff")),
    ("sneer", ("NoseSneerLeft", "NoseSneerRight")),
    ("lips", ("MouthFunnel", "MouthPucker", "MouthClose", "MouthRollLower", "MouthRollUpper", "MouthShrugLower",
              "MouthShrugUpper", "MouthPressLeft", "MouthPressRight", "MouthStretchLeft", "MouthStretchRight",
              "MouthLowerDownLeft", "MouthLowerDownRight", "MouthUpperUpLeft", "MouthUpperUpRight",
              "MouthDimpleLeft", "MouthDimpleRight", "MouthLeft", "MouthRight")),
    ("jaw", ("JawForward", "JawLeft", "JawRight")),
)  # fmt: skip
GLTF_VISEMES = viseme_names("gltf")
_ARKIT = frozenset(ARKIT_NAMES)
_VISEMES = frozenset(GLTF_VISEMES)


@dataclass(frozen=True)
class Inventory:
    """The face parts an avatar has, by the names a driver uses."""

    arkit: frozenset[str]  # ARKit names shown: by a target's name, or by a custom expression so named
    arkit_expressions: dict[str, str]  # ARKit name -> the custom expression showing it
    visemes: frozenset[str]  # glTF spellings (viseme_aa ...) of targets
    expressions: frozenset[str]  # expressions that bind at least one morph target
    bones: dict[str, int]  # humanoid bone -> joint
    look_at: LookAt | None

    @property
    def arkit_emotions(self) -> bool:
        """Whether the face shows emotions by ARKit shapes (those beyond eyes, blinks and JawOpen) rather than by
        VRM emotion expressions: when it has such shapes and no VRM emotions, or a "Perfect Sync" set of them
        (PERFECT_SYNC_MIN or more); a VRM with one target that happens to carry an ARKit name keeps its VRM
        emotions."""
        shapes = len(self.arkit - NOT_EMOTION)
        if shapes >= PERFECT_SYNC_MIN:
            return True
        return shapes > 0 and not any(name in self.expressions for name in VRM_EMOTIONS)

    @property
    def look_by_expressions(self) -> bool:
        return (self.look_at is not None and self.look_at.type is LookAtType.EXPRESSION
                and any(name in self.expressions for name in VRM_LOOKS))


def inventory(shapes: dict[str, tuple[tuple[int, int], ...]], expressions: dict[str, Expression],
              bones: dict[str, int], look_at: LookAt | None) -> Inventory:
    """The inventory of an avatar's normalised shape names, expressions, humanoid joints and lookAt."""
    arkit_targets = {name for name in shapes if name in _ARKIT}
    by_expression: dict[str, str] = {}
    for name, expression in expressions.items():
        canonical = arkit_name(name) if expression.binds else None
        if canonical is not None and canonical not in by_expression:
            by_expression[canonical] = name
    return Inventory(
        arkit=frozenset(arkit_targets | set(by_expression)),
        arkit_expressions=by_expression,
        visemes=frozenset(name for name in shapes if name in _VISEMES),
        expressions=frozenset(name for name, e in expressions.items() if e.binds),
        bones=dict(bones),
        look_at=look_at,
    )



def check(inv: Inventory) -> Capabilities:
    """The avatar's capabilities, or one AvatarError naming every required part it lacks."""
    problems = []
    eyes = blink = mouth = ""
    if inv.look_by_expressions:
        eyes = "vrm lookAt"
    elif "leftEye" in inv.bones and "rightEye" in inv.bones:
        eyes = "bones"
    elif all(name in inv.arkit for name in EYE_LOOKS_HORIZONTAL):
        eyes = "arkit shapes"
    else:
        problems.append("eyes that turn: no eye joints (a humanoid leftEye and rightEye, or nodes named like eyes), "
                        "no ARKit eyeLookIn/Out shapes and no VRM lookAt of expression type")
    if "EyeBlinkLeft" in inv.arkit and "EyeBlinkRight" in inv.arkit:
        blink = "arkit shapes"
    elif "blink" in inv.expressions or ("blinkLeft" in inv.expressions and "blinkRight" in inv.expressions):
        blink = "vrm blink"
    else:
        problems.append("eyes that blink: no ARKit EyeBlinkLeft and EyeBlinkRight shapes and no VRM blink "
                        "expression")
    if "JawOpen" in inv.arkit:
        mouth = "arkit jawOpen"
    elif inv.visemes - {"viseme_sil"}:
        mouth = "visemes"
    elif any(name in inv.expressions for name in VRM_VOWELS):
        mouth = "vrm vowels"
    elif "jaw" in inv.bones:
        mouth = "jaw bone"
    else:
        problems.append("a mouth that opens: no ARKit JawOpen shape, no viseme_* shapes, no VRM vowel (aa, ih, ou, "
                        "ee, oh) expression and no jaw joint")
    if problems:
        raise AvatarError("cannot be driven as a face; it lacks " + "; and ".join(problems))
    return Capabilities(eyes=eyes, blink=blink, mouth=mouth, missing=tuple(_missing(inv, eyes, mouth)))


def _missing(inv: Inventory, eyes: str, mouth: str) -> list[str]:
    missing = []
    if inv.arkit_emotions:
        for group, names in ARKIT_GROUPS:
            lacking = [name for name in names if name not in inv.arkit]
            if len(lacking) == len(names):
                missing.append(f"{group}: no ARKit {group} shapes")
            elif lacking:
                missing.append(f"{group}: no {', '.join(lacking)}")
    else:
        lacking = [name for name in VRM_EMOTIONS if name not in inv.expressions]
        if len(lacking) == len(VRM_EMOTIONS):
            missing.append("emotions: no ARKit shapes and no VRM emotion expressions")
        elif lacking:
            missing.append(f"emotions: no VRM {', '.join(lacking)}")
    if eyes == "arkit shapes":
        lacking = [name for name in EYE_LOOKS_VERTICAL if name not in inv.arkit]
        if lacking:
            missing.append(f"eyes up and down: no {', '.join(lacking)}")
    if eyes == "vrm lookAt":
        lacking = [name for name in VRM_LOOKS if name not in inv.expressions]
        if lacking:
            missing.append(f"eyes: no VRM {', '.join(lacking)}")
    if mouth == "visemes":
        lacking = [name for name in GLTF_VISEMES if name not in inv.visemes]
        if lacking:
            missing.append(f"visemes: no {', '.join(lacking)}")
    if mouth == "vrm vowels":
        lacking = [name for name in VRM_VOWELS if name not in inv.expressions]
        if lacking:
            missing.append(f"vowels: no VRM {', '.join(lacking)}")
    if "head" not in inv.bones:
        missing.append("head turns: no head joint")
    return missing
