"""Morph-target names, normalised so a driver finds a shape whatever its file calls it.

- An ARKit blendshape in any spelling (`eyeBlinkLeft`, `EyeBlinkLeft`, `eyeBlink_L`, `eye_blink_left`, also after a
  `blendShape1.` style prefix) becomes its PascalCase name (`EyeBlinkLeft`), through eca/agent/rig/names.py.
- A viseme named `viseme_*` (`viseme_aa`, `viseme_AA`, `viseme_I`) becomes its glTF spelling (`viseme_aa`,
  `viseme_I`: names.viseme_names("gltf")). A bare `aa` stays as it is: it may as well be VRM's vowel.
- Anything else (VRM expression names, a modeller's own names) is kept as the file has it.

A target the file leaves unnamed (`target<k>`) takes the name of a VRM expression that binds it: one named as an
ARKit shape first ("Perfect Sync" VRMs name their ARKit shapes only as custom expressions), else the one binding it
most strongly (presets before custom ones).
"""

from __future__ import annotations

from eca.agent.rig.names import canonical_arkit_name, viseme_index, viseme_names
from eca.services.processes.avatar.model import Expression, Primitive

MAX_LOOKUP_CHARS = 48  # longer names are no ARKit or viseme name: kept as they are, without a lookup
_GLTF_VISEMES = viseme_names("gltf")


def arkit_name(name: str) -> str | None:
    """The PascalCase ARKit name a morph target or expression name spells, if any."""
    if len(name) > MAX_LOOKUP_CHARS:
        return None
    tail = name.rpartition(".")[2]
    for candidate in (name, tail) if tail != name else (name,):
        if len(candidate) > 2:  # ".L" alone is a side, not a name
            try:
                return canonical_arkit_name(candidate)
            except ValueError:
                pass
    return None


def viseme_name(name: str) -> str | None:
    """The glTF spelling (`viseme_aa`) of a `viseme*` name, if it is one."""
    if len(name) > MAX_LOOKUP_CHARS or not name.strip().lower().startswith("viseme"):
        return None
    try:
        return _GLTF_VISEMES[viseme_index(name)]
    except ValueError:
        return None


class ShapeNamer:
    """Normalises names, each distinct name looked up once (a lookup that fails costs a fuzzy match)."""

    def __init__(self) -> None:
        self._cache: dict[str, str] = {}

    def normalise(self, name: str) -> str:
        found = self._cache.get(name)
        if found is None:
            found = arkit_name(name) or viseme_name(name) or name
            self._cache[name] = found
        return found


def is_unnamed(name: str, index: int) -> bool:
    return name == f"target{index}"


def shape_table(primitives: list[Primitive], expressions: dict[str, Expression],
                namer: ShapeNamer) -> dict[str, tuple[tuple[int, int], ...]]:
    """Normalised name -> the (primitive, target) pairs carrying it; see the module docstring."""
    # (mesh, target) -> (named as ARKit, weight, -rank), expression
    bound: dict[tuple[int, int], tuple[tuple[bool, float, int], str]] = {}
    for rank, (name, expression) in enumerate(expressions.items()):
        is_arkit = arkit_name(name) is not None
        for bind in expression.binds:
            key = (bind.mesh, bind.target)
            score = (is_arkit, bind.weight, -rank)
            if bind.weight > 0.0 and (key not in bound or score > bound[key][0]):
                bound[key] = (score, name)
    table: dict[str, list[tuple[int, int]]] = {}
    for p, prim in enumerate(primitives):
        for t, target in enumerate(prim.targets):
            name = target.name
            if is_unnamed(name, t) and (prim.mesh, t) in bound:
                name = bound[(prim.mesh, t)][1]
            table.setdefault(namer.normalise(name), []).append((p, t))
    return {name: tuple(pairs) for name, pairs in table.items()}
