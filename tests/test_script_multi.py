"""Dialogue scripts of several agents (`<dialogue agents="ada bob cy">`): the turns, roles and per-agent cues they
build, and every mistake reported with its position."""

from __future__ import annotations

from pathlib import Path

import pytest

from eca.agent.gaze.situated import USER
from eca.agent.script import (
    EmotionCue,
    HeadCue,
    RoleCue,
    ScriptError,
    TurnCue,
    load_scripts,
    parse_dialogue,
)
from eca.agent.script.dialogue import USER as SCRIPT_USER
from eca.services.tools.cli import main as eca

ROOT = Path(__file__).resolve().parent.parent
THREE = ROOT / "eca" / "configs" / "demo" / "three.xml"
DATA = Path(__file__).parent / "data" / "scripts"


def _doc(body: str, root: str = '<dialogue agents="ada bob cy" gap="0">') -> bytes:
    return f'<?xml version="1.0"?>\n{root}\n{body}\n</dialogue>\n'.encode()


def test_the_user_is_named_alike_in_scripts_and_in_the_gaze_model() -> None:
    assert SCRIPT_USER == USER


def test_turns_set_every_agents_role_and_say_who_speaks_to_whom() -> None:
    d = parse_dialogue(_doc(
        "  <turn speaker='bob' duration='2'>Hi all.</turn>\n"
        "  <turn speaker='user' to='cy' duration='1'>Cy?</turn>\n"
        "  <silence duration='1'/>\n"
        "  <turn speaker='cy' to='user ada' duration='3'>Yes.</turn>"), "d.xml")
    assert (d.agents, d.agent, d.partner, d.turns, d.silences) == (("ada", "bob", "cy"), "ada", USER, 3, 1)
    turns = [c for c in d.timeline.cues if isinstance(c, TurnCue)]
    assert turns == [TurnCue(0.0, "bob", ("ada", "cy", USER), 2.0), TurnCue(2.0, "user", ("cy",), 1.0),
                     TurnCue(3.0, None, (), 1.0), TurnCue(4.0, "cy", (USER, "ada"), 3.0)]
    roles = {(c.t_s, c.agent): c.role for c in d.timeline.cues if isinstance(c, RoleCue)}
    assert roles == {(0.0, "ada"): "listening", (0.0, "bob"): "talking", (0.0, "cy"): "listening",
                     (2.0, "bob"): "listening",  # a restated role is no cue
                     (3.0, "ada"): "silence", (3.0, "bob"): "silence", (3.0, "cy"): "silence",
                     (4.0, "ada"): "listening", (4.0, "bob"): "listening", (4.0, "cy"): "talking"}
    assert d.timeline.length_s == 7.0
    # at one instant the agents' own cues come first, then the turn, then the speech
    at_zero = [type(c).__name__ for c in d.timeline.cues if c.t_s == 0.0]
    assert at_zero == ["RoleCue", "RoleCue", "RoleCue", "TurnCue", "SayCue"]


def test_emotions_heads_and_parameters_go_to_the_speaker_or_the_agent_named(tmp_path: Path) -> None:
    head = tmp_path / "head.txt"
    head.write_text("header\nelement transition 1\nproperty double duration\nproperty double turn\nend_header\n1;0.5\n")
    (tmp_path / "d.xml").write_bytes(_doc(
        "  <turn speaker='bob' emotion='happy' duration='2'>Hi.\n"
        "    <head nod='0.2'/><head agent='cy' turn='-0.3'/><params href='head.txt'/>\n  </turn>\n"
        "  <turn speaker='user' agent='ada' emotion='angry' intensity='0.5' role='silence' duration='1'>Hm.</turn>\n"
        "  <silence duration='1' agent='cy' emotion='surprised'/>\n"
        "  <params href='head.txt' agent='ada' offset='5'/>"))
    d = load_scripts([tmp_path / "d.xml"])
    cues = d.timeline.cues
    emotions = {(c.t_s, c.agent, c.name) for c in cues if isinstance(c, EmotionCue)}
    assert emotions == {(0.0, "bob", "happy"), (2.0, "ada", "angry"), (3.0, "cy", "surprised")}
    heads = {(c.t_s, c.agent, c.turn, c.nod) for c in cues if isinstance(c, HeadCue)}
    assert heads == {(0.0, "bob", None, 0.2), (0.0, "bob", 0.5, None), (0.0, "cy", -0.3, None), (5.0, "ada", 0.5, None)}
    roles = {(c.t_s, c.agent): c.role for c in cues if isinstance(c, RoleCue) and c.t_s == 2.0}
    assert roles == {(2.0, "ada"): "silence", (2.0, "bob"): "listening"}  # role= is the turn's agent's
    assert (d.agent, d.agents) == ("ada", ("ada", "bob", "cy"))


def test_a_dialogue_of_one_agent_has_no_turn_cues() -> None:
    d = parse_dialogue(b'<dialogue agent="ada"><turn speaker="user" duration="1">Hi</turn></dialogue>', "d.xml")
    assert d.agents == ("ada",)
    assert not any(isinstance(c, TurnCue) for c in d.timeline.cues)


MISTAKES = [
    ("<turn speaker='dora' duration='1'>Hi</turn>", 3, 1,
     "speaker 'dora' is not in this dialogue (ada, bob, cy or user)"),
    ("<turn speaker='ada' to='zed' duration='1'>Hi</turn>", 3, 1, "to names 'zed', who is not in this dialogue"),
    ("<turn speaker='ada' to='ada' duration='1'>Hi</turn>", 3, 1, "to names the speaker 'ada'"),
    ("<turn speaker='ada' to='bob bob' duration='1'>Hi</turn>", 3, 1, "to names 'bob' twice"),
    ("<turn speaker='ada' to=' ' duration='1'>Hi</turn>", 3, 1, "attribute to is empty"),
    ("<turn speaker='user' emotion='happy' duration='1'>Hi</turn>", 3, 1, "say whose emotion this is with agent="),
    ("<turn speaker='user' role='talking' duration='1'>Hi</turn>", 3, 1, "say whose role this is"),
    ("<turn speaker='ada' agent='dora' emotion='happy' duration='1'>Hi</turn>", 3, 1,
     "agent 'dora' is not one of the dialogue's agents (ada, bob, cy)"),
    ("<silence duration='1'><head nod='0.1'/></silence>", 3, 23, "say whose head this is with agent="),
    ("<turn speaker='bob' duration='1'>Hi <gaze agent='eve' yaw='1' pitch='0'/></turn>", 3, 37,
     "agent 'eve' is not one of the dialogue's agents"),
    ("<silence duration='1' speaker='zed'/>", 3, 1, "speaker 'zed' is not in this dialogue"),
    ("<params href='x.txt' agent='ada'/>", 3, 1, "href file 'x.txt' not found"),
    ("<turn speaker='user' duration='1'>Hi <params href='paper_head.txt'/></turn>", 3, 38,
     "say whose parameters this is with agent= (ada, bob, cy)"),
]


@pytest.mark.parametrize(("body", "line", "column", "fragment"), MISTAKES)
def test_each_mistake_names_its_place(body: str, line: int, column: int, fragment: str) -> None:
    with pytest.raises(ScriptError) as info:
        parse_dialogue(_doc(body), "d.xml", DATA)
    err = info.value
    assert len(err.errors) == 1, str(err)
    assert fragment in err.message, str(err)
    assert (err.file, err.line, err.column) == ("d.xml", line, column), str(err)


ROOT_MISTAKES = [
    ('<dialogue agents="ada bob ada">', "agents: 'ada' is named twice"),
    ('<dialogue agents="ada user">', "agents: 'user' is the user"),
    ('<dialogue agents="ada">', "agents names two or more agents"),
    ('<dialogue agents="ada b/b">', "agents: 'b/b' must be 1-64 letters"),
    ('<dialogue agent="ada" agents="ada bob">', "give agent (one agent) or agents (several), not both"),
    ('<dialogue agents="ada bob" partner="bo">', "partner is for a dialogue of one agent"),
    ('<dialogue>', "missing attribute 'agent' (one agent) or 'agents' (several)"),
]


@pytest.mark.parametrize(("root", "fragment"), ROOT_MISTAKES)
def test_each_mistake_in_the_agents_is_reported_at_the_root(root: str, fragment: str) -> None:
    with pytest.raises(ScriptError) as info:
        parse_dialogue(_doc("<turn speaker='user' duration='1'>Hi</turn>", root), "d.xml")
    err = info.value
    assert len(err.errors) == 1 and err.message.startswith(f"<dialogue>: {fragment}"), str(err)
    assert (err.line, err.column) == (2, 1)


def test_several_agent_attributes_are_refused_in_a_dialogue_of_one() -> None:
    doc = _doc("<turn speaker='ada' to='user' duration='1'>Hi <head agent='ada' nod='1'/></turn>",
               '<dialogue agent="ada">')
    with pytest.raises(ScriptError) as info:
        parse_dialogue(doc, "d.xml")
    assert [(e.line, e.column, e.message) for e in info.value.errors] == [
        (3, 1, "<turn>: attribute 'to' is for a dialogue of several agents (<dialogue agents=...>)"),
        (3, 47, "<head>: attribute 'agent' is for a dialogue of several agents (<dialogue agents=...>)"),
    ]


def test_every_problem_is_collected_in_file_order() -> None:
    doc = _doc("<turn speaker='dora' duration='1'>Hi</turn>\n<turn speaker='ada' to='zed' emotion='glad'>Yo</turn>\n"
               "<params href='p.txt' agent='bob'/>")
    with pytest.raises(ScriptError) as info:
        parse_dialogue(doc, "d.xml")
    found = [(e.line, e.message.split(":")[1].strip()[:22]) for e in info.value.errors]
    assert [line for line, _ in found] == [3, 4, 4, 5], found
    assert len(info.value.errors) == 4


def test_a_top_level_parameter_file_names_the_agent_it_drives(tmp_path: Path) -> None:
    (tmp_path / "p.txt").write_text("header\nelement transition 1\nproperty double duration\nproperty double nod\n"
                                    "end_header\n1;0.5\n")
    (tmp_path / "d.xml").write_bytes(_doc("<params href='p.txt'/>\n<turn speaker='ada' duration='1'>Hi</turn>"))
    with pytest.raises(ScriptError) as info:
        load_scripts([tmp_path / "d.xml"])
    assert "say whose parameters this is with agent= (ada, bob, cy)" in info.value.message


def test_runs_that_animate_one_agent_refuse_a_dialogue_of_several(tmp_path: Path) -> None:
    single = tmp_path / "one.xml"
    single.write_text('<dialogue agent="ada"><turn speaker="ada" duration="1">Hi</turn></dialogue>')
    with pytest.raises(ScriptError, match="animates several agents \\('ada', 'bob', 'cy'\\) and this command "
                                          "animates one"):
        load_scripts([THREE], several_agents=False)
    with pytest.raises(ScriptError, match="leave out --agent"):
        load_scripts([THREE], agent="ada")
    with pytest.raises(ScriptError, match="a dialogue of several agents is the only dialogue of its run"):
        load_scripts([THREE, single])
    with pytest.raises(ScriptError, match="a dialogue of several agents is the only dialogue of its run"):
        load_scripts([single, THREE])


def test_eca_check_accepts_the_demo_of_three_agents(capsys: pytest.CaptureFixture[str]) -> None:
    assert eca(["check", str(THREE)]) == 0
    out = capsys.readouterr().out
    assert out.startswith(f"{THREE}: OK: dialogue: ada, bob, cy with user, ")
    d = load_scripts([THREE]).scripts[0].timeline
    turns = [c for c in d.cues if isinstance(c, TurnCue)]
    speakers = [t.speaker for t in turns if t.speaker is not None]
    assert 6 <= len(speakers) <= 10 and set(speakers) == {"ada", "bob", "cy", USER}
    assert any(len(t.addressees) == 1 for t in turns) and max(t.duration_s for t in turns) > 5.0


def test_eca_play_and_experiment_refuse_a_dialogue_of_several(capsys: pytest.CaptureFixture[str]) -> None:
    for command in (["play", str(THREE), "--no-voice"], ["experiment", str(THREE), "--no-voice"]):
        assert eca(command) == 1
        err = capsys.readouterr().err
        assert "this command animates one; render it with `eca render`" in err, err
