"""Reading BML blocks: the namespaces and dialects in use, the warnings for what a face cannot do, every bad input
refused with its position, the speech text as SSML, the face and head tables, and the feedback XML."""

from __future__ import annotations

import pickle
import xml.etree.ElementTree as ET

import pytest

from eca.agent.bml import (
    BEHAVIOR_TYPE_NOT_SUPPORTED,
    CANNOT_CREATE_BEHAVIOR,
    CUSTOM_ATTRIBUTE_NOT_SUPPORTED,
    CUSTOM_BEHAVIOUR_NOT_SUPPORTED,
    MAX_BML_CHARS,
    PARSING_FAILURE,
    Block,
    BmlError,
    EmotionParams,
    FaceParams,
    GazeParams,
    HeadDirectionParams,
    HeadParams,
    RoleParams,
    SpeechParams,
    SyncRef,
    WaitParams,
    block_progress_xml,
    bml_tables,
    parse_block,
    prediction_feedback_xml,
    sync_point_progress_xml,
    warning_feedback_xml,
)
from eca.agent.bml.model import parse_sync_ref

BML1 = "http://www.bml-initiative.org/bml/bml-1.0"


def block(body: str, attrs: str = f'xmlns="{BML1}" id="b1"') -> Block:
    return parse_block(f"<bml {attrs}>\n{body}\n</bml>")


def refused(text: str | bytes) -> BmlError:
    with pytest.raises(BmlError) as caught:
        parse_block(text, "req.xml")
    return caught.value


def only(parsed: Block) -> object:
    assert len(parsed.behaviours) == 1, parsed.behaviours
    return parsed.behaviours[0].params


# -- namespaces and dialects --


@pytest.mark.parametrize("attrs", [f'xmlns="{BML1}"', 'xmlns="http://www.mindmakers.org/projects/BML"', ""])
def test_the_three_namespaces_of_a_block(attrs: str) -> None:
    parsed = parse_block(f'<bml {attrs} id="b1" characterId="ada"><head id="h1" lexeme="NOD"/></bml>')
    assert (parsed.id, parsed.character, parsed.composition) == ("b1", "ada", "MERGE")
    assert parsed.behaviours[0].kind == "head" and parsed.warnings == ()


def test_a_prefixed_root_and_a_foreign_namespace_root() -> None:
    parsed = parse_block(f'<b:bml xmlns:b="{BML1}" id="b1" composition="APPEND"><b:head id="h" lexeme="NOD"/></b:bml>')
    assert parsed.composition == "APPEND" and parsed.behaviours[0].kind == "head"
    error = refused('<bml xmlns="urn:other" id="b1"/>')
    assert error.line == 1 and "root" in error.message


def test_smartbody_act_wrapper_with_participant_and_undeclared_sbm() -> None:
    parsed = parse_block('<?xml version="1.0" encoding="utf-16"?>\n<act><participant id="Brad" role="actor"/>\n'
                         '<bml id="sb1"><speech id="sp1" type="text/plain">Hello <mark name="T0"/>world<mark '
                         'name="T1"/></speech>\n<head id="h1" type="NOD" repeats="2" amount="0.5" sbm:smooth="0.3"/>\n'
                         '<gaze id="g1" target="Camera" sbm:joint-range="NECK EYES"/></bml></act>')
    assert parsed.warnings == ()  # participant, sbm:* and SmartBody's speech type pass without a word
    speech = parsed.behaviours[0].params
    assert isinstance(speech, SpeechParams) and speech.marks == ("T0", "T1") and speech.text == "Hello world"
    head = parsed.behaviours[1].params
    assert isinstance(head, HeadParams) and (head.lexeme, head.repetitions) == ("nod", 2)


def test_an_act_must_hold_exactly_one_bml() -> None:
    assert "holds 2" in refused('<act><bml id="a"/><bml id="b"/></act>').message


@pytest.mark.parametrize("element", ["gesture", "pointing", "posture", "postureShift", "locomotion", "gestureShift",
                                     "animation"])
def test_what_a_face_cannot_do_is_a_warning_naming_element_id_and_line(element: str) -> None:
    parsed = block(f'<head id="h1" lexeme="NOD"/>\n<{element} id="x1" lexeme="BEAT" start="h1:end"/>')
    (warning,) = parsed.warnings
    assert (warning.type, warning.behaviour, warning.line) == (BEHAVIOR_TYPE_NOT_SUPPORTED, "x1", 3)
    assert warning.block == "b1"
    assert element in warning.text and "x1" in warning.text and "line 3" in warning.text
    assert [b.id for b in parsed.behaviours] == ["h1"]
    assert [(u.id, u.kind, u.sync["start"].behaviour) for u in parsed.unrealized] == [("x1", element, "h1")]


def test_foreign_elements_attributes_and_enumerations_are_warnings() -> None:
    parsed = block('<head id="h1" lexeme="NOD" speed="2" x:y="1" xmlns:x="urn:x" xml:lang="en"/>\n'
                   '<x:dance id="d1" xmlns:x="urn:x"/>\n<sbm:reach id="r1" target="cup"/>\n'
                   '<faceLexeme id="f1" lexeme="WIGGLE_EARS"/>\n<faceFacs id="f2" au="99"/>\n'
                   '<head id="h2" lexeme="WAGGLE"/>\n<head id="h3" type="ORIENT"/>\n<gaze id="g1" target="a" '
                   'influence="TOES"/>\n<eca:emotion id="e1" name="smug"/>\n<eca:role id="r2" role="dancing"/>')
    found = [(w.type, w.behaviour, w.line) for w in parsed.warnings]
    assert found == [
        (CUSTOM_ATTRIBUTE_NOT_SUPPORTED, "h1", 2), (CUSTOM_ATTRIBUTE_NOT_SUPPORTED, "h1", 2),
        (CUSTOM_BEHAVIOUR_NOT_SUPPORTED, "d1", 3), (CUSTOM_BEHAVIOUR_NOT_SUPPORTED, "r1", 4),
        (CANNOT_CREATE_BEHAVIOR, "f1", 5), (CANNOT_CREATE_BEHAVIOR, "f2", 6), (CANNOT_CREATE_BEHAVIOR, "h2", 7),
        (CANNOT_CREATE_BEHAVIOR, "h3", 8), (CANNOT_CREATE_BEHAVIOR, "g1", 9), (CANNOT_CREATE_BEHAVIOR, "e1", 10),
        (CANNOT_CREATE_BEHAVIOR, "r2", 11),
    ]
    assert "speed" in parsed.warnings[0].text and "urn:x:y" in parsed.warnings[1].text
    assert [b.id for b in parsed.behaviours] == ["h1"]
    assert {u.id for u in parsed.unrealized} == {"f1", "f2", "h2", "h3", "g1", "e1", "r2"}  # references still hold


def test_unsupported_behaviour_without_an_id_is_only_a_warning() -> None:
    parsed = block('<gesture lexeme="BEAT"/>')
    assert [w.type for w in parsed.warnings] == [BEHAVIOR_TYPE_NOT_SUPPORTED] and parsed.unrealized == ()


def test_an_element_bml_does_not_know_keeps_only_start_and_end() -> None:
    parsed = block('<animation id="a1" name="wave" start="1" stroke="2"/>')
    (unrealized,) = parsed.unrealized
    assert list(unrealized.sync) == ["start"]
    with pytest.raises(BmlError, match="no sync point 'attackPeak'"):
        block('<gesture id="g1" lexeme="BEAT" attackPeak="2"/>')  # a core gesture has no attackPeak


# -- bad input, refused with its position --


def test_malformed_xml_names_line_and_column() -> None:
    error = refused(f'<bml xmlns="{BML1}" id="b1">\n<head id="h1" lexeme="NOD">\n</bml>')
    assert (error.line, error.warning_type) == (3, PARSING_FAILURE) and "mismatched tag" in error.message
    assert str(error).startswith("req.xml:3:")


def test_billion_laughs_is_refused_before_any_entity_expands() -> None:
    laughs = '<?xml version="1.0"?>\n<!DOCTYPE lolz [\n <!ENTITY lol "lol">\n' + "".join(
        f' <!ENTITY lol{i} "{("&lol" + str(i - 1) + ";") * 10 if i > 1 else "&lol;" * 10}">\n' for i in range(1, 10))
    error = refused(laughs + ']>\n<bml id="b1">&lol9;</bml>')
    assert error.line == 2 and "DOCTYPE" in error.message


def test_undeclared_entity_is_malformed() -> None:
    error = refused('<bml id="b1">\n<speech id="s"><text>&xxe;</text></speech></bml>')
    assert error.line == 2 and "entity" in error.message


def test_deep_nesting_is_refused() -> None:
    error = refused('<bml id="b1">' + "<a>" * 40 + "</a>" * 40 + "</bml>")
    assert "deeper than 32" in error.message and error.line == 1


def test_size_bound_is_checked_before_parsing() -> None:
    assert MAX_BML_CHARS == 65_536
    text = '<bml id="b1">' + " " * 70_000 + "</bml>"
    assert "at most 65536" in refused(text).message
    assert "at most 65536" in refused(text.encode()).message
    assert refused(b'<bml id="b1">\n\xff</bml>').line == 2  # not UTF-8
    assert refused('<bml id="b1">\n\n\ud800</bml>').line == 3  # not Unicode


def test_the_bound_is_the_bus_protocols() -> None:
    from eca.protocol.messages import MAX_BML_CHARS as PROTOCOL_MAX

    assert PROTOCOL_MAX == MAX_BML_CHARS


@pytest.mark.parametrize(("body", "attrs", "line", "words"), [
    ("", f'xmlns="{BML1}"', 1, "needs an 'id'"),
    ("", 'id="a b"', 1, "is not an id"),
    ("", 'id="b1" composition="MIX"', 1, "composition"),
    ('<head lexeme="NOD"/>', 'id="b1"', 2, "needs an 'id'"),
    ('<head id="h1" lexeme="NOD"/>\n<gaze id="h1" target="x"/>', 'id="b1"', 3, "line 2 and line 3"),
    ('<head id="bml" lexeme="NOD"/>', 'id="b1"', 2, "not 'bml' or 'self'"),
    ('<head id="h1" lexeme="NOD" start="h2:"/>', 'id="b1"', 2, "attribute 'start'"),
    ('<head id="h1" lexeme="NOD" start="nan"/>', 'id="b1"', 2, "attribute 'start'"),
    ('<head id="h1" lexeme="NOD" start="1e3"/>', 'id="b1"', 2, "attribute 'start'"),
    ('<head id="h1" lexeme="NOD" start="700"/>', 'id="b1"', 2, "beyond 600"),
    ('<head id="h1" lexeme="NOD" attackPeak="1"/>', 'id="b1"', 2, "no sync point 'attackPeak'"),
    ('<head id="h1" lexeme="NOD" repetition="1000"/>', 'id="b1"', 2, "repetition"),
    ('<head id="h1" lexeme="NOD" repetition="1.5"/>', 'id="b1"', 2, "repetition"),
    ('<faceLexeme id="f1" lexeme="RAISE_BROWS" amount="2"/>', 'id="b1"', 2, "attribute 'amount'"),
    ('<faceLexeme id="f1" lexeme="RAISE_BROWS" amount="nan"/>', 'id="b1"', 2, "attribute 'amount'"),
    ('<faceLexeme id="f1"/>', 'id="b1"', 2, "needs a 'lexeme'"),
    ('<head id="h1"/>', 'id="b1"', 2, "needs a 'lexeme'"),
    ('<faceFacs id="f1" au="twelve"/>', 'id="b1"', 2, "action unit number"),
    ('<gaze id="g1"/>', 'id="b1"', 2, "needs a 'target'"),
    ('<gaze id="g1" target="x" offsetAngle="inf"/>', 'id="b1"', 2, "offsetAngle"),
    ('<eca:emotion id="e1" name="happy" intensity="1.5"/>', 'id="b1"', 2, "intensity"),
    ('<speech id="s1"><text> </text></speech>', 'id="b1"', 2, "no words"),
    ('<speech id="s1"><text>a <sync id="x"/> b <sync id="x"/></text></speech>', 'id="b1"', 2, "twice"),
    ('<speech id="s1"><text>a <sync/></text></speech>', 'id="b1"', 2, "needs the attribute 'id'"),
    ('<speech id="s1"><text>a <sync id="end"/></text></speech>', 'id="b1"', 2, "own end"),
    ('<speech id="s1"><text>a <sync id="w-2"/></text></speech>', 'id="b1"', 2, "offset"),
    ('<constraint><synchronize><sync ref="a:start"/></synchronize></constraint>', 'id="b1"', 2, "2 to 50"),
    ('<constraint><before><sync ref="self:start"/><sync ref="1"/></before></constraint>', 'id="b1"', 2, "self"),
    ('<constraint><whenever/></constraint>', 'id="b1"', 2, "not a constraint"),
])
def test_bad_blocks_are_refused_with_their_line(body: str, attrs: str, line: int, words: str) -> None:
    error = refused(f"<bml {attrs}>\n{body}\n</bml>")
    assert error.line == line, str(error)
    assert words in error.message, str(error)
    assert str(error).startswith(f"req.xml:{line}:")


def test_too_many_marks_behaviours_and_constraints() -> None:
    marks = "".join(f'w<sync id="m{i}"/> ' for i in range(51))
    assert "at most 50 sync marks" in refused(f'<bml id="b"><speech id="s"><text>{marks}</text></speech></bml>').message
    heads = "".join(f'<head id="h{i}" lexeme="NOD"/>' for i in range(201))
    assert "at most 200 behaviours" in refused(f'<bml id="b">{heads}</bml>').message
    syncs = "".join('<synchronize><sync ref="1"/><sync ref="1"/></synchronize>' for _ in range(101))
    assert "at most 100 constraints" in refused(f'<bml id="b"><constraint>{syncs}</constraint></bml>').message


def test_error_text_and_pickling() -> None:
    error = refused('<bml id="b1">\n<head id="h1" lexeme="NOD" repetition="0"/></bml>')
    assert str(error) == ("req.xml:2:1: block 'b1', behaviour 'h1': attribute 'repetition' = '0' must be a whole "
                          "number in [1, 20]")
    again = pickle.loads(pickle.dumps(error))
    assert (str(again), again.line, again.behaviour, again.warning_type) == (str(error), 2, "h1", PARSING_FAILURE)
    assert str(BmlError("no root element")) == "bml: no root element"


# -- references --


@pytest.mark.parametrize(("text", "expected"), [
    ("6", SyncRef(None, None, None, 6.0, "6")),
    ("-2.5", SyncRef(None, None, None, -2.5, "-2.5")),
    ("speech1:syncstart1", SyncRef(None, "speech1", "syncstart1", 0.0, "speech1:syncstart1")),
    ("s1:and1end+0.25", SyncRef(None, "s1", "and1end", 0.25, "s1:and1end+0.25")),
    ("h2:start - 2", SyncRef(None, "h2", "start", -2.0, "h2:start - 2")),
    ("b0:h2:end", SyncRef("b0", "h2", "end", 0.0, "b0:h2:end")),
    ("b1:h2:end", SyncRef(None, "h2", "end", 0.0, "b1:h2:end")),  # this block, named
    ("b0:3", SyncRef("b0", "bml", "start", 3.0, "b0:3")),
    ("b1:3", SyncRef(None, None, None, 3.0, "b1:3")),
    ("bml:start+1", SyncRef(None, None, None, 1.0, "bml:start+1")),
    ("b0:bml:end", SyncRef("b0", "bml", "end", 0.0, "b0:bml:end")),
    ("self:start+2", SyncRef(None, "me", "start", 2.0, "self:start+2")),
    ("h1:stroke:2", SyncRef(None, "h1", "stroke:2", 0.0, "h1:stroke:2")),
    ("h1:stroke:1-0.5", SyncRef(None, "h1", "stroke", -0.5, "h1:stroke:1-0.5")),
    ("b0:h1:stroke:3", SyncRef("b0", "h1", "stroke:3", 0.0, "b0:h1:stroke:3")),
])
def test_reference_grammar(text: str, expected: SyncRef) -> None:
    assert parse_sync_ref(text, block_id="b1", carrier="me") == expected


@pytest.mark.parametrize("text", ["", ":start", "h1:", "h1:start+", "a:b:c:d:e", "h1:start+nan", "h1:relax:2",
                                  "bml:end", "h1:stroke:21", "x y:start", "1e5", "h1:start+inf", "a:b:c:d"])
def test_malformed_references(text: str) -> None:
    with pytest.raises(ValueError):
        parse_sync_ref(text, block_id="b1", carrier="me")


# -- speech --


def test_speech_marks_of_every_dialect_become_ssml_in_order() -> None:
    parsed = block('<speech id="s1"><text>Fish &amp; chips &lt;3 <sync id="a"/>are "good" <tm id="b"/>'
                   'for <mark name="c"/>you.</text></speech>')
    speech = only(parsed)
    assert isinstance(speech, SpeechParams)
    assert speech.text == 'Fish & chips <3 are "good" for you.' and speech.marks == ("a", "b", "c")
    root = ET.fromstring(speech.ssml)  # valid XML that an SSML engine reads
    assert root.tag == "speak" and [m.get("name") for m in root.iter("mark")] == ["a", "b", "c"]
    assert "".join(root.itertext()) == speech.text
    assert "&amp; chips &lt;3" in speech.ssml


def test_text_wins_over_an_ssml_description_and_the_description_serves_alone() -> None:
    description = ('<description priority="1" type="application/ssml+xml"><speak xmlns="http://www.w3.org/2001/10/'
                   'synthesis">Hi <prosody rate="slow">there <mark name="m1"/>friend</prosody><break/>now</speak>'
                   '</description>')
    both = only(block(f'<speech id="s1"><text>Plain <sync id="p1"/>words</text>{description}</speech>'))
    assert isinstance(both, SpeechParams) and both.text == "Plain words" and both.marks == ("p1",)
    alone = only(block(f'<speech id="s1">{description}</speech>'))
    assert isinstance(alone, SpeechParams) and alone.text == "Hi there friend now" and alone.marks == ("m1",)
    assert ET.fromstring(alone.ssml).find("mark") is not None


def test_recorded_audio_is_an_eca_extension() -> None:
    parsed = block('<speech id="s1" eca:audio="clips/hello.wav"><text>Hello</text></speech>')
    speech = only(parsed)
    assert isinstance(speech, SpeechParams) and speech.audio_path == "clips/hello.wav" and parsed.warnings == ()


# -- face, head, gaze, eca's own --


def test_face_lexeme_scaled_by_amount_and_facs_by_side() -> None:
    parsed = block('<faceLexeme id="f1" lexeme="RAISE_BROWS"/>\n<faceFacs id="f2" au="12" side="LEFT" amount="1" '
                   'xmlns="http://www.bml-initiative.org/bml/coreextensions-1.0"/>\n<face id="f3" type="facs" '
                   'au="1_right" amount="1"/>\n<face id="f4" type="LEXEME" lexeme="OPEN_MOUTH" amount="0.5"/>\n'
                   '<faceShift id="f5" lexeme="LOWER_MOUTH_CORNERS" amount="0.2"/>')
    f1, f2, f3, f4, f5 = (b.params for b in parsed.behaviours)
    assert isinstance(f1, FaceParams) and dict(f1.flexors) == {"brow_l": 0.5, "brow_r": 0.5, "brows_knit": -0.15}
    assert isinstance(f2, FaceParams) and dict(f2.flexors) == {"smile_l": 0.85} and f2.what == "faceFacs AU12 LEFT"
    assert isinstance(f3, FaceParams) and dict(f3.flexors) == {"brow_r": 0.6, "brows_knit": 0.2}
    assert isinstance(f4, FaceParams) and dict(f4.flexors) == {"say_ah": 0.5}
    assert isinstance(f5, FaceParams) and f5.shift and dict(f5.flexors) == pytest.approx({"smile_l": -0.2,
                                                                                            "smile_r": -0.2})
    assert [b.kind for b in parsed.behaviours] == ["faceLexeme", "faceFacs", "faceFacs", "faceLexeme", "faceShift"]


def test_every_core_lexeme_and_the_listed_action_units_are_in_the_table() -> None:
    tables = bml_tables()
    core = ("OBLIQUE_BROWS RAISE_BROWS RAISE_LEFT_BROW RAISE_RIGHT_BROW LOWER_BROWS LOWER_LEFT_BROW LOWER_RIGHT_BROW "
            "LOWER_MOUTH_CORNERS LOWER_LEFT_MOUTH_CORNER LOWER_RIGHT_MOUTH_CORNER RAISE_MOUTH_CORNERS "
            "RAISE_RIGHT_MOUTH_CORNER RAISE_LEFT_MOUTH_CORNER OPEN_MOUTH OPEN_LIPS WIDEN_EYES CLOSE_EYES").split()
    assert set(core) <= set(tables.lexemes)
    assert {1, 2, 4, 5, 6, 7, 9, 10, 12, 15, 17, 20, 23, 24, 25, 26, 27, 43, 45, 46} <= set(tables.action_units)


def test_head_lexemes_amounts_and_smartbody_forms() -> None:
    parsed = block('<head id="h1" lexeme="NOD" repetition="3" amount="0"/><head id="h2" lexeme="SHAKE" amount="1"/>'
                   '<head id="h3" type="TOSS"/><head id="h4" type="ORIENT" target="user" start="1"/>')
    h1, h2, h3, h4 = (b.params for b in parsed.behaviours)
    degrees = bml_tables().head_degrees
    assert isinstance(h1, HeadParams) and (h1.repetitions, h1.amplitude_deg) == (3, degrees["nod"][0])
    assert isinstance(h2, HeadParams) and h2.amplitude_deg == degrees["shake"][1]
    assert isinstance(h3, HeadParams) and (h3.lexeme, h3.what) == ("nod", "TOSS")
    assert isinstance(h4, HeadDirectionParams) and h4.target == "user"
    assert parsed.behaviours[3].kind == "headDirectionShift" and parsed.behaviours[3].sync["start"].offset_s == 1


def test_gaze_wait_blink_and_eca_extensions() -> None:
    parsed = block('<gaze id="g1" target="user" influence="eyes" offsetAngle="10" offsetDirection="UP"/>'
                   '<gazeShift id="g2" target="ada"/><headDirectionShift id="d1" target="bob"/>'
                   '<wait id="w1" max-wait="2.5"/><blink id="k1"/><eca:blink id="k2"/>'
                   '<eca:emotion id="e1" name="Half_Angry" intensity="0.4" transition="1"/>'
                   '<eca:role id="r1" role="listening"/>', f'xmlns="{BML1}" xmlns:eca="urn:eca:bml:1.0" id="b1"')
    params = [b.params for b in parsed.behaviours]
    assert params[0] == GazeParams("user", "EYES", 10.0, "UP", False)
    assert isinstance(params[1], GazeParams) and params[1].shift and params[1].influence == "HEAD"
    assert params[2] == HeadDirectionParams("bob") and params[3] == WaitParams(2.5)
    assert [b.kind for b in parsed.behaviours[4:6]] == ["blink", "blink"]
    assert params[6] == EmotionParams("half-angry", 0.4, 1.0) and params[7] == RoleParams("listening")
    assert parsed.warnings == ()


def test_sync_attributes_are_kept_as_written() -> None:
    parsed = block('<speech id="s1"><text>a <sync id="w"/> b</text></speech>'
                   '<head id="h1" lexeme="NOD" stroke="s1:w" end="self:stroke+1"/>')
    sync = parsed.behaviours[1].sync
    assert sync["stroke"] == SyncRef(None, "s1", "w", 0.0, "s1:w")
    assert sync["end"] == SyncRef(None, "h1", "stroke", 1.0, "self:stroke+1")


def test_constraints_read_their_anchor_first() -> None:
    parsed = block('<head id="a" lexeme="NOD"/><head id="b" lexeme="NOD"/><constraint>'
                   '<before ref="a:end"><sync ref="b:start"/></before><after><sync ref="a:start"/><sync ref="b:end"/>'
                   '</after><synchronize><sync ref="a:stroke"/><sync ref="b:stroke"/><sync ref="3"/></synchronize>'
                   '</constraint>')
    kinds = [(c.kind, [r.text for r in c.refs]) for c in parsed.constraints]
    assert kinds == [("before", ["a:end", "b:start"]), ("after", ["a:start", "b:end"]),
                     ("synchronize", ["a:stroke", "b:stroke", "3"])]


# -- feedback --


def test_feedback_is_well_formed_and_escaped() -> None:
    ns = "{" + BML1 + "}"
    progress = ET.fromstring(block_progress_xml("b1", "start", 12.5, "ada"))
    assert progress.tag == ns + "blockProgress" and progress.attrib == {"id": "b1:start", "globalTime": "12.5",
                                                                        "characterId": "ada"}
    sync = ET.fromstring(sync_point_progress_xml("b1", "h1", "stroke", 0.4, 12.9, ""))
    assert sync.attrib == {"id": "b1:h1:stroke", "time": "0.4", "globalTime": "12.9"}
    hostile = 'a < b & "c" \x01 ]]>'
    warning = ET.fromstring(warning_feedback_xml("b1", "h1", "IMPOSSIBLE_TO_SCHEDULE", hostile, 'x"y'))
    assert warning.text == 'a < b & "c" \ufffd ]]>' and warning.attrib["characterId"] == 'x"y'
    assert warning.attrib["id"] == "b1:h1"
    prediction = ET.fromstring(prediction_feedback_xml("b1", 10.0, 13.25, "ada"))
    (predicted,) = list(prediction)
    assert predicted.tag == ns + "bml" and predicted.attrib == {"id": "b1", "globalStart": "10",
                                                                "globalEnd": "13.25"}
    with pytest.raises(ValueError):
        block_progress_xml("b1", "end", float("nan"), "")
