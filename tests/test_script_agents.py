"""Which agent a run of scripts animates: the dialogue's own, --agent only where it agrees, one default."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from eca.agent.script import DEFAULT_AGENT, HeadCue, ScriptError, load_script, load_scripts
from eca.services.tools.cli import main as eca

ROOT = Path(__file__).resolve().parent.parent
DATA = Path(__file__).parent / "data" / "scripts"
HEAD = DATA / "paper_head.txt"


def dialogue(tmp_path: Path, agent: str, name: str = "d.xml") -> Path:
    path = tmp_path / name
    path.write_text(f'<dialogue agent="{agent}">\n  <turn speaker="{agent}" duration="1">Hi.</turn>\n</dialogue>\n')
    return path


def test_the_one_default_agent_is_the_default_instance_agent() -> None:
    config = tomllib.loads((ROOT / "eca" / "configs" / "default.toml").read_text())
    assert DEFAULT_AGENT == config["agents"]["ids"][0] == "ada"
    assert load_scripts([HEAD]).agent == DEFAULT_AGENT


def test_parameter_files_drive_the_dialogues_agent(tmp_path: Path) -> None:
    run = load_scripts([HEAD, dialogue(tmp_path, "bob")])  # the order of the files does not matter
    assert run.agent == "bob"
    heads = [c for c in run.timeline.cues if isinstance(c, HeadCue)]
    assert len(heads) == 2 and {c.agent for c in heads} == {"bob"}
    assert run.timeline.agents == ("bob",)
    assert load_scripts([HEAD], agent="cy").timeline.agents == ("cy",)  # alone: --agent, if given


def test_an_agent_that_disagrees_with_the_dialogue_is_an_error_at_its_root(tmp_path: Path) -> None:
    path = dialogue(tmp_path, "bob")
    with pytest.raises(ScriptError) as info:
        load_script(path, agent="ada")
    assert str(info.value) == f"{path}:1:1: the dialogue animates 'bob' but --agent is 'ada'"
    assert load_script(path, agent="bob").timeline.agents == ("bob",)


def test_two_dialogues_for_different_agents_do_not_make_one_run(tmp_path: Path) -> None:
    first, second = dialogue(tmp_path, "ada", "a.xml"), dialogue(tmp_path, "bob", "b.xml")
    with pytest.raises(ScriptError) as info:
        load_scripts([first, second])
    assert info.value.file == str(second)
    assert f"the dialogue animates 'bob' but {first} animates 'ada'" in info.value.message


def test_a_bad_agent_option_is_refused(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="--agent 'no way'"):
        load_scripts([HEAD], agent="no way")


def test_every_command_defaults_to_the_dialogues_agent(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = dialogue(tmp_path, "bob")
    assert eca(["check", str(path)]) == 0
    assert "dialogue: bob with user" in capsys.readouterr().out
    assert eca(["check", str(path), "--agent", "ada"]) == 1
    assert "the dialogue animates 'bob' but --agent is 'ada'" in capsys.readouterr().err
    assert eca(["play", str(path), "--agent", "ada", "--no-voice"]) == 1  # refused before any bus is used
    err = capsys.readouterr().err
    assert "the dialogue animates 'bob' but --agent is 'ada'" in err and "nothing played" in err
    out = tmp_path / "experiment"
    assert eca(["experiment", str(path), "--agent", "ada", "--no-voice", "-o", str(out)]) == 1
    assert "the dialogue animates 'bob' but --agent is 'ada'" in capsys.readouterr().err
    assert not out.exists()


def test_no_command_hard_codes_an_agent_of_its_own() -> None:
    from eca.services.tools.cli import build_parser

    parser = build_parser()
    for command in ("render", "experiment", "check", "play"):
        args = parser.parse_args([command, "x.xml", *(["-o", "x.mp4"] if command == "render" else [])])
        assert args.agent is None, command  # None: the dialogue's own agent, else DEFAULT_AGENT
