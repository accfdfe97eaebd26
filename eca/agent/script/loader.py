"""Loading script files by their content, deciding which agent they animate, and merging them.

A dialogue names the agent it animates; that is the agent of the run. A caller may name one too
(the commands' `--agent`): a dialogue for another agent is then an error, as is a second dialogue for
another agent than the first. Parameter files carry no agent of their own (unless a data line names
one): they drive the run's agent, which is the dialogues' agent, else the caller's, else DEFAULT_AGENT.

A dialogue of several agents (`agents="ada bob cy"`) animates them all: it is the run's only dialogue, no
agent may be asked for, and parameter files given with it drive its first agent. Callers that animate one
agent only refuse it (`several_agents=False`).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass
from functools import partial
from pathlib import Path

from eca.agent.script.dialogue import DurationOf, parse_dialogue
from eca.agent.script.elements import SayCue, Timeline, TurnCue, merge
from eca.agent.script.errors import ScriptError, ScriptErrors
from eca.agent.script.paramfile import AGENT_ID_RE, parse_params
from eca.agent.script.textfile import read_bytes
from eca.agent.script.vocab import DEFAULT_AGENT


@dataclass(frozen=True)
class Script:
    """One loaded file: what it is ("dialogue" or a parameter file's kind) and its timeline."""

    path: str
    kind: str
    timeline: Timeline
    summary: str


@dataclass(frozen=True)
class ScriptSet:
    """Several files loaded together: the agent they animate, each file, and their merged timeline.

    `agents` are all the agents the run animates, in seat order: (agent,), or a dialogue's several agents
    (then `agent` is the first of them)."""

    agent: str
    scripts: tuple[Script, ...]
    timeline: Timeline
    agents: tuple[str, ...] = ()


def is_xml(data: bytes) -> bool:
    """Dialogues are XML; parameter files start with the word `header`."""
    return data.lstrip(b"\xef\xbb\xbf \t\r\n").startswith(b"<")


def _names(agents: tuple[str, ...]) -> str:
    return ", ".join(repr(a) for a in agents)


class _OneAgent:
    """The agent of a run: the caller's if given, else the first dialogue's (or the agents of a dialogue of
    several, when the caller can animate them)."""

    def __init__(self, requested: str | None, several_agents: bool) -> None:
        self.agent = requested
        self.agents: tuple[str, ...] = (requested,) if requested is not None else ()
        self.source = "--agent" if requested is not None else ""
        self.several_agents = several_agents

    def check(self, path: str, own: str | tuple[str, ...]) -> str | None:
        """Why a dialogue animating `own` (a tuple: several agents) cannot be part of this run, or None."""
        if isinstance(own, tuple):
            return self._check_several(path, own)
        if len(self.agents) > 1:
            return (f"the dialogue animates {own!r} but {self.source} animates {_names(self.agents)}; a dialogue "
                    "of several agents is the only dialogue of its run")
        if self.agent is None:
            self.agent, self.agents, self.source = own, (own,), path
            return None
        if own == self.agent:
            return None
        if self.source == "--agent":
            return f"the dialogue animates {own!r} but --agent is {self.agent!r}"
        return (f"the dialogue animates {own!r} but {self.source} animates {self.agent!r}; "
                "the files of one run animate one agent")

    def _check_several(self, path: str, own: tuple[str, ...]) -> str | None:
        if not self.several_agents:
            return (f"the dialogue animates several agents ({_names(own)}) and this command animates one; "
                    "render it with `eca render`")
        if self.source == "--agent":
            return f"the dialogue animates {_names(own)} together; leave out --agent"
        if self.agent is not None:
            return (f"the dialogue animates {_names(own)} but {self.source} animates {_names(self.agents)}; a "
                    "dialogue of several agents is the only dialogue of its run")
        self.agent, self.agents, self.source = own[0], own, path
        return None


def check_agent_id(agent: str | None) -> None:
    """ValueError unless `agent` is None or a valid agent id."""
    if agent is not None and not AGENT_ID_RE.fullmatch(agent):
        raise ValueError(f"--agent {agent!r} must be 1-64 letters, digits, '_', '-' or '.'")


def load_scripts(paths: Iterable[str | Path], *, agent: str | None = None,
                 duration_of: DurationOf | None = None,
                 text_duration: Callable[[str], float] | None = None,
                 several_agents: bool = True) -> ScriptSet:
    """Load dialogues and parameter files (told apart by content) as one run.

    `agent` is the agent the caller asks for (the commands' --agent; None: the dialogues' own).
    `several_agents=False` refuses a dialogue of several agents (for callers that animate one).
    Every problem of every file is raised at once as ScriptErrors, file by file in the order given;
    nothing is returned unless all files are valid.
    """
    check_agent_id(agent)
    names = [str(p) for p in paths]
    found: dict[int, Script] = {}
    errors: dict[int, tuple[ScriptError, ...]] = {}
    data: dict[int, bytes] = {}
    for i, name in enumerate(names):
        try:
            data[i] = read_bytes(name)
        except ScriptError as exc:
            errors[i] = exc.errors
    dialogues = [i for i in data if is_xml(data[i]) or Path(names[i]).suffix.lower() == ".xml"]
    run = _OneAgent(agent, several_agents)
    for i in dialogues:  # first, so that the parameter files know the agent they drive
        name = names[i]
        try:
            dialogue = parse_dialogue(data[i], name, Path(name).resolve().parent, duration_of=duration_of,
                                      text_duration=text_duration,
                                      agent_check=partial(run.check, name))
        except ScriptError as exc:
            errors[i] = exc.errors
            continue
        t = dialogue.timeline
        summary = (f"dialogue: {', '.join(dialogue.agents)} with {dialogue.partner}, {dialogue.turns} turns, "
                   f"{dialogue.silences} silences, {len(dialogue.params)} parameter files, "
                   f"{len(t.elements)} elements, {len(t.cues)} cues, {t.length_s:.1f} s")
        found[i] = Script(name, "dialogue", t, summary)
    resolved = run.agent if run.agent is not None else DEFAULT_AGENT
    for i in data:
        if i in dialogues:
            continue
        try:
            params = parse_params(data[i], names[i], agent=resolved)
        except ScriptError as exc:
            errors[i] = exc.errors
            continue
        timeline = merge(params.elements)
        summary = f"{params.kind_title}: {len(params.elements)} elements, {timeline.length_s:.1f} s"
        found[i] = Script(names[i], params.kind, timeline, summary)
    if errors:
        raise ScriptErrors(e for i in sorted(errors) for e in errors[i])
    scripts = tuple(found[i] for i in range(len(names)))
    elements = [e for s in scripts for e in s.timeline.elements]
    says = [c for s in scripts for c in s.timeline.cues if isinstance(c, SayCue)]
    turns = [c for s in scripts for c in s.timeline.cues if isinstance(c, TurnCue)]
    timeline = merge(elements, says, min_length_s=max((s.timeline.length_s for s in scripts), default=0.0),
                     turns=turns)
    return ScriptSet(resolved, scripts, timeline, run.agents or (resolved,))


def load_script(path: str | Path, *, agent: str | None = None, duration_of: DurationOf | None = None,
                text_duration: Callable[[str], float] | None = None) -> Script:
    """One dialogue (of one agent or several) or parameter file; `agent` as for load_scripts."""
    return load_scripts([path], agent=agent, duration_of=duration_of, text_duration=text_duration).scripts[0]


def build_timeline(paths: Iterable[str | Path], *, agent: str | None = None,
                   duration_of: DurationOf | None = None,
                   text_duration: Callable[[str], float] | None = None) -> Timeline:
    """Every file's elements and cues merged into one timeline; all files parse or nothing plays."""
    return load_scripts(paths, agent=agent, duration_of=duration_of, text_duration=text_duration).timeline
