"""Loading any script file by its content, and merging several into one timeline."""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

from agent.script.dialogue import DurationOf, load_dialogue
from agent.script.elements import SayCue, Timeline, merge
from agent.script.paramfile import DEFAULT_AGENT, load_params
from agent.script.textfile import read_bytes


@dataclass(frozen=True)
class Script:
    """One loaded file: what it is ("dialogue" or a parameter file's kind) and its timeline."""

    path: str
    kind: str
    timeline: Timeline
    summary: str


def is_xml(data: bytes) -> bool:
    """Dialogues are XML; parameter files start with the word `header`."""
    return data.lstrip(b"\xef\xbb\xbf \t\r\n").startswith(b"<")


def load_script(path: str | Path, *, agent: str = DEFAULT_AGENT, duration_of: DurationOf | None = None,
                text_duration: Callable[[str], float] | None = None) -> Script:
    """A dialogue or a parameter file, told apart by content; `agent` is who a parameter file drives."""
    data = read_bytes(path)
    if is_xml(data) or Path(path).suffix.lower() == ".xml":
        dialogue = load_dialogue(path, duration_of=duration_of, text_duration=text_duration)
        t = dialogue.timeline
        summary = (f"dialogue: {dialogue.agent} with {dialogue.partner}, {dialogue.turns} turns, "
                   f"{dialogue.silences} silences, {len(dialogue.params)} parameter files, "
                   f"{len(t.elements)} elements, {len(t.cues)} cues, {t.length_s:.1f} s")
        return Script(str(path), "dialogue", t, summary)
    params = load_params(path, agent=agent)
    timeline = merge(params.elements)
    summary = f"{params.kind_title}: {len(params.elements)} elements, {timeline.length_s:.1f} s"
    return Script(str(path), params.kind, timeline, summary)


def build_timeline(paths: Iterable[str | Path], *, agent: str = DEFAULT_AGENT,
                   duration_of: DurationOf | None = None,
                   text_duration: Callable[[str], float] | None = None) -> Timeline:
    """Every file's elements and cues merged into one timeline; all files parse or nothing plays."""
    scripts = [load_script(p, agent=agent, duration_of=duration_of, text_duration=text_duration)
               for p in paths]
    elements = [e for s in scripts for e in s.timeline.elements]
    says = [c for s in scripts for c in s.timeline.cues if isinstance(c, SayCue)]
    return merge(elements, says, min_length_s=max((s.timeline.length_s for s in scripts), default=0.0))
