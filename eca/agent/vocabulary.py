"""The names every part of eca shares: conversational roles, eye modes and kinds of saccade.

Defined once here; the models, the script language, the services and the command line read them from
here. The bus protocol spells the same names in its own message types (protocol/ knows nothing of the
models), and a test holds the two alike.
"""

from __future__ import annotations

from typing import Literal, get_args

Role = Literal["talking", "listening", "silence"]
ROLES: tuple[Role, ...] = get_args(Role)

# The paper's conditions (a) static eyes, (b) Perlin noise, (c) saccades; the statistical blink model coupled
# to them (the paper's future work); and the paper's recommendation, saccades with context-aware fixational
# noise and the blink model, the default for live use (configs/gaze.toml [modes]).
EyeMode = Literal["static", "noise", "saccade", "saccade+blink", "saccade+noise+blink"]
EYE_MODES: tuple[EyeMode, ...] = get_args(EyeMode)
SACCADE_MODES: frozenset[EyeMode] = frozenset(m for m in EYE_MODES if m.startswith("saccade"))
# The modes whose listeners answer a partner's pauses with nods and blinks (agent/gaze/backchannel.py): the
# recommendation's; the paper's conditions stay as they were.
BACKCHANNEL_MODES: frozenset[EyeMode] = frozenset({"saccade+noise+blink"})

# The Eyes Alive decisions (mutual, away), head-led saccades, and the small saccades of the fixational noise:
# scans between a partner's eyes and mouth, and microsaccades.
SaccadeKind = Literal["mutual", "away", "head", "scan", "micro"]
SACCADE_KINDS: tuple[SaccadeKind, ...] = get_args(SaccadeKind)
