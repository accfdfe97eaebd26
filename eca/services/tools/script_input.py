"""What the commands that check, play or render scripts share: loading a run of script files with the
voices and the sound-file measure the audio services use, and printing the problems found.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path

from eca.agent.script import DEFAULT_AGENT, ScriptError, ScriptSet, load_scripts
from eca.services.processes.audio.files import open_sound_file
from eca.services.processes.audio.tts import espeak_available
from eca.services.tools.playback import VoiceCache, prepare_voices

AGENT_HELP = ("the agent the scripts animate; by default a dialogue's own agent (a dialogue for another "
              f"agent is an error), and {DEFAULT_AGENT!r} for parameter files given alone")


def sound_duration(path: Path) -> float:
    """Seconds of sound in any file soundfile reads (what the offline render and the audio service
    play); AudioFileError naming the cause otherwise, never an empty one."""
    with open_sound_file(path) as fh:
        return fh.frames / float(fh.samplerate)


def open_voices(command: str, no_voice: bool) -> VoiceCache | None:
    """The espeak-ng voices for lines with only text, or None (with a note when espeak-ng is missing)."""
    if no_voice:
        return None
    if not espeak_available():
        print(f"eca {command}: espeak-ng not found: lines with only text stay silent", file=sys.stderr)
        return None
    return VoiceCache()


def load_run(paths: Sequence[str | Path], agent: str | None, voices: VoiceCache | None,
             several_agents: bool = False) -> ScriptSet:
    """The scripts as one run, their text lines measured (and spoken ahead) with `voices` if given; a
    dialogue of several agents only where the caller animates them (`several_agents`)."""
    run = load_scripts(paths, agent=agent, duration_of=sound_duration,
                       text_duration=voices.duration_of_text if voices is not None else None,
                       several_agents=several_agents)
    if voices is not None and len(run.agents) == 1:  # several agents speak with voices of their own
        prepare_voices(run.timeline, voices, run.agent)
    return run


def print_failure(command: str, exc: Exception, consequence: str) -> None:
    """A script's problems one per line (`file:line:column: message`, as editors read them), then what
    did not happen; any other refusal on one line."""
    if isinstance(exc, ScriptError):
        problems = exc.errors
        for problem in problems:
            print(problem, file=sys.stderr)
        count = f"{len(problems)} problem{'s' if len(problems) != 1 else ''}"
        print(f"eca {command}: {count} in the scripts; {consequence}", file=sys.stderr)
    else:
        print(f"eca {command}: {exc}", file=sys.stderr)
