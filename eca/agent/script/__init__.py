"""Scripts: the paper's PLY-like parameter files, XML dialogues, and the timeline they make."""

from eca.agent.script.audiofile import AudioFileError, UnmeasurableAudio, audio_file_problem, wav_duration
from eca.agent.script.dialogue import Dialogue, estimate_speech_s, load_dialogue, parse_dialogue
from eca.agent.script.elements import (
    AnimationElement,
    Cue,
    EmotionCue,
    GazeCue,
    HeadCue,
    RoleCue,
    SayCue,
    Timeline,
    TurnCue,
    merge,
)
from eca.agent.script.errors import ScriptError, ScriptErrors
from eca.agent.script.loader import Script, ScriptSet, build_timeline, check_agent_id, load_script, load_scripts
from eca.agent.script.paramfile import ParamFile, load_params, parse_params
from eca.agent.script.vocab import DEFAULT_AGENT

__all__ = [
    "DEFAULT_AGENT",
    "AnimationElement",
    "AudioFileError",
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
    "ScriptErrors",
    "ScriptSet",
    "Timeline",
    "TurnCue",
    "UnmeasurableAudio",
    "audio_file_problem",
    "build_timeline",
    "check_agent_id",
    "estimate_speech_s",
    "load_dialogue",
    "load_params",
    "load_script",
    "load_scripts",
    "merge",
    "parse_dialogue",
    "parse_params",
    "wav_duration",
]
