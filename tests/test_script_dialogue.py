"""XML dialogue scripts: the cue sequence they build, their hooks, and their errors."""

from __future__ import annotations

from pathlib import Path

import pytest

from eca.agent.script import (
    EmotionCue,
    GazeCue,
    HeadCue,
    RoleCue,
    SayCue,
    ScriptError,
    build_timeline,
    estimate_speech_s,
    load_dialogue,
    parse_dialogue,
)

DATA = Path(__file__).parent / "data" / "scripts"
CLIP = str((DATA / "clip.wav").resolve())


def test_table_like_dialogue_builds_the_expected_cues() -> None:
    dialogue = load_dialogue(DATA / "table.xml")
    assert (dialogue.agent, dialogue.partner, dialogue.turns, dialogue.silences) == ("ada", "bo", 3, 1)
    t = dialogue.timeline
    # wpm=120: 0.5 s a word; gap 0.5 s between speech turns only; the clip lasts 1.5 s
    assert list(t.cues) == [
        RoleCue(0.0, "ada", "talking"),
        EmotionCue(0.0, "ada", "half-angry", 1.0, 0.5),
        SayCue(0.0, "ada", "table-01", "Well done, Bo.", None, 1.5),
        HeadCue(1.0, "ada", 1.0, 0.8, 0.0, 2.0),  # the paper's head file, offset by 1 s
        RoleCue(2.0, "ada", "listening"),
        EmotionCue(2.0, "ada", "natural", 1.0, 0.5),
        SayCue(2.0, "bo", "table-02", "What? It was not my fault.", None, 2.0),
        HeadCue(3.0, "ada", -1.0, -1.0, 0.7, 3.0),
        RoleCue(4.0, "ada", "silence"),
        EmotionCue(4.0, "ada", "disappointed", 1.0, 0.5),
        GazeCue(4.5, "ada", None, -10.0, -5.0),
        RoleCue(6.0, "ada", "talking"),
        EmotionCue(6.0, "ada", "angry", 0.5, 0.5),
        SayCue(6.0, "ada", "last", "It was.", CLIP, 1.5),
        HeadCue(6.1, "ada", None, -0.2, None, 0.5),
    ]
    assert t.length_s == 7.5
    assert t.agents == ("ada", "bo")
    assert [c.t_s for c in t.cues_between(2.0, 4.0)] == [2.0, 2.0, 2.0, 3.0]


def test_elements_carry_the_role_in_force_and_span_until_the_next_change() -> None:
    t = load_dialogue(DATA / "table.xml").timeline
    head = [e for e in t.elements if e.kind == "head"]
    assert [e.role for e in head] == ["talking", "listening", "talking"]
    emotions = [(e.start_s, e.duration_s, e.emotion) for e in t.elements if e.kind == "emotion"]
    assert emotions == [(0.0, 2.0, "half-angry"), (2.0, 2.0, "natural"), (4.0, 2.0, "disappointed"),
                        (6.0, 1.5, "angry")]
    assert t.elements_at(5.0, "emotion", "ada").emotion == "disappointed"
    assert t.elements_at(5.0, "status", "ada").role == "silence"
    starts = [e.start_s for e in t.elements]
    assert starts == sorted(starts)


def test_duration_hooks_measure_audio_and_text() -> None:
    seen: list[Path] = []

    def fake_audio(path: Path) -> float:
        seen.append(path)
        return 4.0

    t = load_dialogue(DATA / "table.xml", duration_of=fake_audio,
                      text_duration=lambda text: 1.0).timeline
    assert seen == [Path(CLIP)]
    says = [(c.t_s, c.duration_s) for c in t.cues if isinstance(c, SayCue)]
    assert says == [(0.0, 1.0), (1.5, 2.0), (3.5 + 2.0, 4.0)]


def test_text_estimate_scales_with_words() -> None:
    assert estimate_speech_s("one two three four", wpm=120) == 2.0
    assert estimate_speech_s("Hi.", wpm=160) == 0.6  # never shorter than a short syllable run


def test_several_files_merge_into_one_timeline() -> None:
    t = build_timeline([DATA / "table.xml", DATA / "paper_head.txt"], agent="ada")
    heads = [c.t_s for c in t.cues if isinstance(c, HeadCue)]
    assert heads == [0.0, 1.0, 2.0, 3.0, 6.1]
    assert t.length_s == 7.5


def _doc(body: str, root: str = '<dialogue agent="ada">') -> bytes:
    return f'<?xml version="1.0"?>\n{root}\n{body}\n</dialogue>\n'.encode()


XML_ERRORS = [
    (_doc("<turn speaker='ada'>Hi"), 4, 3, "not well-formed XML: mismatched tag"),
    (b'<!DOCTYPE d [<!ENTITY x "y">]>\n<dialogue agent="a"/>', 1, 1, "DOCTYPE declarations are not allowed"),
    (b'<?xml version="1.0"?>\n<script/>', 2, 1, "the root element must be <dialogue>"),
    (b'<dialogue partner="u"/>', 1, 1, "missing attribute 'agent'"),
    (_doc("  <turn speaker='ada' mood='x'>Hi</turn>"), 3, 3, "unknown attribute 'mood'"),
    (_doc("  <turn speaker='zed'>Hi</turn>"), 3, 3, "speaker 'zed' is neither the agent 'ada'"),
    (_doc("  <turn speaker='ada' emotion='glad'>Hi</turn>"), 3, 3, "unknown emotion 'glad'"),
    (_doc("  <turn speaker='ada' role='singing'>Hi</turn>"), 3, 3, "unknown role 'singing'"),
    (_doc("  <turn speaker='ada' emotion='happy' intensity='2'>Hi</turn>"), 3, 3,
     "attribute intensity=2 is out of range [0, 1]"),
    (_doc("  <turn speaker='ada' duration='soon'>Hi</turn>"), 3, 3, "attribute duration='soon' is not a number"),
    (_doc("  <turn speaker='ada'/>"), 3, 3, "a turn needs text, an audio file or a duration"),
    (_doc("  <turn speaker='ada' audio='missing.wav'>Hi</turn>"), 3, 3, "audio 'missing.wav' not found"),
    (_doc("  <silence/>"), 3, 3, "<silence>: missing attribute 'duration'"),
    (_doc("  <silence duration='1'>psst</silence>"), 3, 3, "a silence holds no text"),
    (_doc("  <pause duration='1'/>"), 3, 3, "unknown element"),
    (_doc("  <turn speaker='ada'>Hi\n    <head nod='3'/></turn>"), 4, 5, "attribute nod=3 is out of range"),
    (_doc("  <turn speaker='ada'>Hi <head/></turn>"), 3, 26, "give at least one of turn, nod, tilt"),
    (_doc("  <turn speaker='ada'>Hi <gaze yaw='5'/></turn>"), 3, 26, "needs both yaw and pitch"),
    (_doc("  <turn speaker='ada'>Hi <gaze mode='wild'/></turn>"), 3, 26, "unknown eye mode 'wild'"),
    (_doc("  <turn speaker='ada' id='a'>Hi</turn>\n  <turn speaker='ada' id='a'>Yo</turn>"), 4, 3,
     "utterance id 'a' is used twice"),
    (_doc("  <params href='nothing.txt'/>"), 3, 3, "href file 'nothing.txt' not found"),
    (_doc("stray words"), 2, 1, "text directly inside <dialogue>"),
]


@pytest.mark.parametrize(("data", "line", "column", "fragment"), XML_ERRORS)
def test_dialogue_errors_name_line_and_column(data: bytes, line: int, column: int, fragment: str) -> None:
    with pytest.raises(ScriptError) as info:
        parse_dialogue(data, "d.xml", DATA)
    err = info.value
    assert fragment in err.message, str(err)
    assert (err.file, err.line, err.column) == ("d.xml", line, column), str(err)
    assert len(err.errors) == 1, str(err)  # one mistake, one error: nothing reported as its consequence


def test_entity_expansion_is_refused_even_without_a_doctype_elsewhere() -> None:
    bomb = (b'<?xml version="1.0"?>\n<!DOCTYPE lolz [\n <!ENTITY lol "lol">\n'
            b' <!ENTITY lol2 "&lol;&lol;&lol;&lol;">\n]>\n<dialogue agent="a">&lol2;</dialogue>')
    with pytest.raises(ScriptError, match="DOCTYPE declarations are not allowed"):
        parse_dialogue(bomb, "bomb.xml")


def test_an_error_in_an_included_parameter_file_names_that_file(tmp_path: Path) -> None:
    (tmp_path / "head.txt").write_text("header\nelement transition 1\nproperty int duration\n"
                                       "property double nod\nend_header\n1;x\n")
    (tmp_path / "d.xml").write_text('<dialogue agent="ada">\n<params href="head.txt"/>\n</dialogue>\n')
    with pytest.raises(ScriptError) as info:
        load_dialogue(tmp_path / "d.xml")
    assert info.value.file == str(tmp_path / "head.txt")
    assert (info.value.line, info.value.column) == (6, 3)


def test_parameter_files_inside_a_turn_count_from_its_start(tmp_path: Path) -> None:
    (tmp_path / "s.txt").write_text("header\nelement transition 2\nproperty double duration\n"
                                    "property string role\nend_header\n0.5;silence\n1;listening\n")
    (tmp_path / "d.xml").write_text('<dialogue agent="ada"><turn speaker="ada" duration="2">Hi</turn>'
                                    '<silence duration="3"><params href="s.txt" offset="1"/></silence>'
                                    '</dialogue>')
    t = load_dialogue(tmp_path / "d.xml").timeline
    roles = [(c.t_s, c.role) for c in t.cues if isinstance(c, RoleCue)]
    # the dialogue's own silence at 2.0 and the file's restatement at 3.0 merge into one cue
    assert roles == [(0.0, "talking"), (2.0, "silence"), (3.5, "listening")]
    assert t.length_s == 5.0


def test_cues_that_leave_an_axis_alone_keep_the_current_value() -> None:
    from eca.agent.script import GazeCue, HeadCue

    head = HeadCue(0.0, "ada", turn=None, nod=-0.3, tilt=None, duration_s=1.0)
    assert head.targets((0.5, 0.2, 0.1)) == (0.5, -0.3, 0.1)
    assert GazeCue(0.0, "ada", "saccade", None, None).target((4.0, 2.0)) is None
    assert GazeCue(0.0, "ada", None, -7.0, None).target((4.0, 2.0)) == (-7.0, 2.0)


def test_every_problem_of_a_dialogue_and_its_parameter_files_is_reported_in_file_order(tmp_path: Path) -> None:
    (tmp_path / "head.txt").write_text("header\nelement transition 2\nproperty int duration\n"
                                       "property double nod\nend_header\n1;x\n1;9\n")
    (tmp_path / "d.xml").write_text('<dialogue agent="ada" wpm="1">\n'
                                    '  <params href="head.txt"/>\n'
                                    '  <turn speaker="ada" mood="x" emotion="glad">Hi\n'
                                    '    <head nod="2"/></turn>\n'
                                    '  <silence duration="-1"/>\n'
                                    '</dialogue>\n')
    with pytest.raises(ScriptError) as info:
        load_dialogue(tmp_path / "d.xml")
    found = [(Path(e.file).name, e.line, e.column, e.message.split(";")[0]) for e in info.value.errors]
    assert found == [
        ("d.xml", 1, 1, "<dialogue>: attribute wpm=1 is out of range [40, 400] words per minute"),
        ("d.xml", 3, 3, "<turn>: unknown attribute 'mood'"),
        ("d.xml", 3, 3, "<turn>: unknown emotion 'glad'"),
        ("d.xml", 4, 5, "<head>: attribute nod=2 is out of range [-1, 1]"),
        ("d.xml", 5, 3, "<silence>: attribute duration=-1 is out of range [0.01, 3600] seconds"),
        ("head.txt", 6, 3, "value 'x' does not parse as double for property nod"),
        ("head.txt", 7, 3, "value 9.0 for property nod is out of range [-1, 1]"),
    ]
    assert str(info.value).count("\n") == len(found) - 1  # str() lists them all, one per line


def test_xml_that_is_not_well_formed_stops_at_its_first_problem() -> None:
    with pytest.raises(ScriptError) as info:
        parse_dialogue(b'<dialogue agent="ada">\n<turn speaker="zed">Hi</trun>\n<silence/>\n</dialogue>', "d.xml")
    assert [(e.line, e.message) for e in info.value.errors] == [(2, "not well-formed XML: mismatched tag")]
