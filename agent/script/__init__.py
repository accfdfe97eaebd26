"""Scripts: the paper's PLY-like parameter files, XML dialogues, and the timeline they make."""

from agent.script.dialogue import Dialogue, estimate_speech_s, load_dialogue, parse_dialogue, wav_duration
from agent.script.elements import (
    AnimationElement,
    Cue,
    EmotionCue,
    GazeCue,
    HeadCue,
    RoleCue,
    SayCue,
    Timeline,
    merge,
)
from agent.script.errors import ScriptError
from agent.script.loader import Script, build_timeline, load_script
from agent.script.paramfile import DEFAULT_AGENT, ParamFile, load_params, parse_params

__all__ = [
    "DEFAULT_AGENT",
    "AnimationElement",
    "Cue",
    "Dialogue",
    "EmotionCue",
    "GazeCue",
    "HeadCue",
    "ParamFile",
    "RoleCue",
    "SayCue",
    "Script",
    "ScriptError",
    "Timeline",
    "build_timeline",
    "estimate_speech_s",
    "load_dialogue",
    "load_params",
    "load_script",
    "merge",
    "parse_dialogue",
    "parse_params",
    "wav_duration",
]
