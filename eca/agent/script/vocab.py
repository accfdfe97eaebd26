"""The names a script may use: roles, eye modes, element kinds, emotions, and their spellings."""

from __future__ import annotations

from typing import Literal

from eca.agent.script.poses import emotion_table
from eca.agent.vocabulary import EYE_MODES, ROLES, EyeMode, Role

# The agent scripts animate when neither a dialogue nor the caller names one: the default agent of
# configs/default.toml (`[agents] ids`), so a parameter file played on its own moves the face `eca up`
# starts. Every command's default comes from here.
DEFAULT_AGENT = "ada"

__all__ = ["DEFAULT_AGENT", "EYE_MODES", "ROLES", "EyeMode", "Role", "ROLE_ALIASES", "ELEMENT_KINDS", "ElementKind"]

# The paper's Table 1 says "Speaking" where the rest of the paper says talking.
ROLE_ALIASES: dict[str, Role] = {"speaking": "talking"}

ElementKind = Literal["emotion", "gaze", "head", "status"]
ELEMENT_KINDS: tuple[ElementKind, ...] = ("emotion", "gaze", "head", "status")


def emotion_names() -> tuple[str, ...]:
    """The emotions in the face's table order (configs/emotions.toml)."""
    return emotion_table().names


def normalise_name(text: str) -> str:
    """Case-insensitive, with spaces and underscores as hyphens: the paper writes "Half Angry"."""
    return "-".join(text.strip().lower().replace("_", " ").split())


def parse_role(text: str) -> Role | None:
    """The role `text` names, or None."""
    name = normalise_name(text)
    name = ROLE_ALIASES.get(name, name)
    return name if name in ROLES else None


def parse_emotion(text: str) -> str | None:
    """The emotion `text` names, or None."""
    name = normalise_name(text)
    return name if name in emotion_names() else None


def parse_eye_mode(text: str) -> EyeMode | None:
    name = text.strip().lower()
    return name if name in EYE_MODES else None
