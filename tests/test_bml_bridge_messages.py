"""The BML bridge's pure parts, without ActiveMQ or a bus: reading blocks and VHMsg lines, the limits, where each
feedback goes (eca/services/processes/bml_bridge.py has the mapping), and the command line's one-line refusals."""

from __future__ import annotations

import urllib.parse
import xml.etree.ElementTree as ET

import pytest

from eca.protocol.messages import Bml, BmlFeedback, Error
from eca.services.processes.bml_bridge import (
    ASAP_FEEDBACK,
    GRETA_FEEDBACK,
    MAX_BODY_CHARS,
    UNKNOWN_CHARACTER,
    FeedbackRouter,
    Frame,
    InboundQueue,
    Origin,
    Refused,
    Routes,
    Translator,
    VhAddress,
    block_head,
    decode_body,
    feedback_xml,
    parse_host_port,
    parse_transports,
    parse_vhmsg,
    vhmsg_line,
    vhmsg_split,
    warning_xml,
)
from eca.services.tools import cli

NS = "http://www.bml-initiative.org/bml/bml-1.0"
BLOCK = f'<bml xmlns="{NS}" id="b1" characterId="ada"><head id="h1" lexeme="NOD"/></bml>'


# --- arguments ---


def test_host_and_port_are_read_and_checked() -> None:
    assert parse_host_port("127.0.0.1:61613") == ("127.0.0.1", 61613)
    assert parse_host_port("[::1]:61613") == ("::1", 61613)
    for bad in ("61613", "host", "host:", ":61613", "host:0", "host:70000", "host:x1"):
        with pytest.raises(ValueError, match="--stomp"):
            parse_host_port(bad)


def test_transports_are_named() -> None:
    assert parse_transports("asap,greta,vhmsg") == {"asap", "greta", "vhmsg"}
    assert parse_transports(" VHMSG ") == {"vhmsg"}
    with pytest.raises(ValueError, match="unknown transport 'smartbody'"):
        parse_transports("asap,smartbody")
    with pytest.raises(ValueError, match="names no transport"):
        parse_transports(",")


@pytest.mark.parametrize(("argv", "said"), [
    (["bml-bridge"], "--stomp HOST:PORT is required"),
    (["bml-bridge", "--stomp", "nowhere"], "expected HOST:PORT"),
    (["bml-bridge", "--stomp", "h:1", "--topics", "asap,mqtt"], "unknown transport 'mqtt'"),
    (["bml-bridge", "--stomp", "h:1", "--agent", "no one"], "is not an agent id"),
    (["bml-bridge", "--stomp", "h:1", "--vhmsg-scope", "a b"], "is not a topic name"),
])
def test_bad_arguments_are_one_line_and_exit_2(argv: list[str], said: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("eca bml-bridge: ") and said in err[0]


# --- bodies and blocks ---


def test_bodies_must_be_utf8_and_within_the_limit() -> None:
    assert decode_body("é".encode()) == "é"
    with pytest.raises(Refused, match="not UTF-8") as bad:
        decode_body(b"caf\xe9")
    assert bad.value.kind == "PARSING_FAILURE"
    assert len(decode_body(("é" * MAX_BODY_CHARS).encode())) == MAX_BODY_CHARS  # characters count, not bytes
    with pytest.raises(Refused, match="over the limit"):
        decode_body(b"x" * (MAX_BODY_CHARS + 1))
    with pytest.raises(Refused, match="over the limit"):  # refused before it is decoded
        decode_body(b"x" * (4 * MAX_BODY_CHARS + 1))


@pytest.mark.parametrize(("xml", "block", "character"), [
    (BLOCK, "b1", "ada"),
    ("<bml id='b2'/>", "b2", ""),
    (f'<?xml version="1.0" encoding="UTF-8"?>\n<!-- a block -->\n<b:bml xmlns:b="{NS}" id="b3"></b:bml>', "b3", ""),
    ('\ufeff  <bml characterId="ada" note="a &gt; b, 1>0" id="b&amp;4"></bml>', "b&4", "ada"),
    ('<act><participant id="brad"/><bml id="sb1" characterId="brad"><head type="NOD"/></bml></act>', "sb1", "brad"),
])
def test_a_blocks_id_and_character_are_read_off_its_start_tag(xml: str, block: str, character: str) -> None:
    head = block_head(xml)
    assert (head.block, head.character) == (block, character)


@pytest.mark.parametrize("xml", ["hello", "{\"bml\": 1}", "<speech id='s1'/>", "<bml id='b1'", "<bmlx id='b'/>",
                                 "<act><speech/></act>", "<!-- only a comment -->"])
def test_what_is_not_a_block_is_refused(xml: str) -> None:
    with pytest.raises(Refused) as refused:
        block_head(xml)
    assert refused.value.kind == "PARSING_FAILURE"


# --- VHMsg ---


def encoded(args: str) -> str:
    return "vrAgentBML " + urllib.parse.quote_plus(args, safe="")


def test_a_vhmsg_request_is_read_encoded_or_plain() -> None:
    for line in (encoded(f"ada m1 request {BLOCK}"), f"vrAgentBML ada m1 request {BLOCK}"):
        request = parse_vhmsg(line)
        assert request is not None
        assert request.address == VhAddress("ada", "m1") and request.xml == BLOCK


def test_the_older_form_with_a_recipient_and_quoted_xml() -> None:
    request = parse_vhmsg(encoded(f'brad ALL m7 request "{BLOCK}"'))
    assert request is not None
    assert request.address == VhAddress("brad", "m7", recipient="ALL") and request.xml == BLOCK
    assert vhmsg_split(request.address.reply("start")) == ("vrAgentBML", "brad ALL m7 start")


@pytest.mark.parametrize("line", [encoded("ada m1 start"), encoded("ada m1 end complete"), "vrSpeak brad all m1 <x/>",
                                  encoded("ada ALL m1 end interrupted"), "vrAgentBML", "sbm set camera", ""])
def test_other_vhmsg_traffic_is_not_a_request(line: str) -> None:
    assert parse_vhmsg(line) is None


def test_a_request_without_xml_is_refused_with_whom_to_answer() -> None:
    with pytest.raises(Refused, match="without XML") as refused:
        parse_vhmsg(encoded("ada m2 request"))
    assert refused.value.vh == VhAddress("ada", "m2")


def test_reply_lines_are_encoded_as_vhmsg_clients_decode_them() -> None:
    line = VhAddress("ada", "m1").reply("end error PARSING_FAILURE: a <b> & 100% wrong")
    prefix, _, rest = line.partition(" ")
    assert prefix == "vrAgentBML" and " " not in rest
    assert urllib.parse.unquote_plus(rest) == "ada m1 end error PARSING_FAILURE: a <b> & 100% wrong"
    assert vhmsg_line("vrAgentBML", "ada m1 start") == "vrAgentBML ada+m1+start"


# --- frames to commands ---


def test_the_agent_is_the_blocks_character_the_vhmsg_char_or_the_default() -> None:
    t = Translator("ada", prefix="p")
    t.agents = frozenset({"ada", "bob"})
    bob = BLOCK.replace('"ada"', '"bob"')
    forward = t.translate(Frame("asap", bob.encode()))
    assert forward is not None and isinstance(forward.command, Bml)
    assert (forward.command.agent, forward.command.request_id, forward.command.xml) == ("bob", "p-1", bob)
    assert forward.origin == Origin("asap", "bob", "b1")
    forward = t.translate(Frame("greta", b"<bml id='g1'/>"))
    assert forward is not None and forward.command.agent == "ada" and forward.command.request_id == "p-2"
    forward = t.translate(Frame("vhmsg", encoded(f"bob m3 request {BLOCK}").encode()))  # the line's char wins
    assert forward is not None and forward.command.agent == "bob" and forward.origin.vh == VhAddress("bob", "m3")
    assert t.translate(Frame("vhmsg", b"vrSpeak brad all m1 hello")) is None
    assert t.translate(Frame("vhmsg", b"wsp \xff\xfe" + b"x" * (4 * MAX_BODY_CHARS))) is None  # others' traffic
    assert t.translate(Frame("vhmsg", b"vrAgentBMLx ada m1 request <bml id='x'/>")) is None


@pytest.mark.parametrize("character", ["nobody", "not an id", "*", "x" * 40])
def test_an_agent_the_instance_lacks_is_refused(character: str) -> None:
    t = Translator("ada")
    t.agents = frozenset({"ada"})
    with pytest.raises(Refused) as refused:
        t.translate(Frame("asap", f'<bml id="b9" characterId="{character}"/>'.encode()))
    assert refused.value.kind == UNKNOWN_CHARACTER and refused.value.block == "b9"


def test_before_the_agents_are_known_any_valid_id_goes_on() -> None:
    forward = Translator("ada").translate(Frame("asap", b'<bml id="b" characterId="zoe"/>'))
    assert forward is not None and forward.command.agent == "zoe"


def test_a_refused_frame_names_its_block_when_one_shows() -> None:
    with pytest.raises(Refused) as refused:
        Translator("ada").translate(Frame("asap", b'<bml id="late">caf\xe9</bml>'))
    assert refused.value.block == "late"
    with pytest.raises(Refused) as refused:
        Translator("ada").translate(Frame("vhmsg", encoded("ada m4 request not xml").encode()))
    assert refused.value.vh == VhAddress("ada", "m4")


def test_a_vhmsg_line_may_be_three_times_the_limit_for_its_escapes() -> None:
    xml = "<bml id='big'>" + "<" * (MAX_BODY_CHARS - 40) + "</bml>"
    line = encoded(f"ada m5 request {xml}")
    assert len(line) > 2 * MAX_BODY_CHARS
    assert Translator("ada").translate(Frame("vhmsg", line.encode())) is not None
    with pytest.raises(Refused, match="over the limit"):
        Translator("ada").translate(Frame("vhmsg", encoded(f"ada m6 request {xml}{'x' * 100}").encode()))


# --- feedback back ---


def fb(kind: str, request_id: str = "r1", sync: str = "", behaviour: str = "", text: str = "", xml: str = "",
       global_ns: int = 0) -> BmlFeedback:
    return BmlFeedback(agent="ada", kind=kind, block="b1", request_id=request_id, sync=sync, behaviour=behaviour,
                       text=text, xml=xml, global_ns=global_ns)  # type: ignore[arg-type]


def routed(transport: str, vh: VhAddress | None = None) -> FeedbackRouter:
    router = FeedbackRouter(Routes())
    router.open("r1", Origin(transport, "ada", "b1", vh))
    return router


def vh_lines(out: list) -> list[str]:  # type: ignore[type-arg]
    return [" ".join(vhmsg_split(o.body)) for o in out]


def test_asap_gets_every_feedback_as_the_standards_xml() -> None:
    router = routed("asap")
    for f in (fb("blockProgress", sync="start", xml="<blockProgress id='b1:start'/>"),
              fb("syncPointProgress", behaviour="h1", sync="stroke", xml="<syncPointProgress id='b1:h1:stroke'/>"),
              fb("predictionFeedback", xml="<predictionFeedback/>"),
              fb("warningFeedback", behaviour="g1", sync="BEHAVIOR_TYPE_NOT_SUPPORTED", xml="<warningFeedback/>")):
        (out,) = router.feedback(f, 0)
        assert out.destination == f"/topic/{ASAP_FEEDBACK}" and out.body == f.xml and out.headers == {}
    assert router.feedback(fb("blockProgress", sync="end", xml="<blockProgress id='b1:end'/>"), 0)
    assert "r1" not in router.pending and router.feedback(fb("blockProgress", sync="end"), 0) == []


def test_vhmsg_gets_start_and_one_end() -> None:
    router = routed("vhmsg", VhAddress("ada", "m1"))
    out = router.feedback(fb("blockProgress", sync="start"), 0)
    assert vh_lines(out) == ["vrAgentBML ada m1 start"]
    assert out[0].headers == {"ELVISH_SCOPE": "DEFAULT_SCOPE", "MESSAGE_PREFIX": "vrAgentBML"}
    assert router.feedback(fb("syncPointProgress", behaviour="h1", sync="stroke"), 0) == []
    assert router.feedback(fb("warningFeedback", behaviour="g1", sync="BEHAVIOR_TYPE_NOT_SUPPORTED"), 0) == []
    assert vh_lines(router.feedback(fb("blockProgress", sync="end"), 0)) == ["vrAgentBML ada m1 end complete"]
    assert router.feedback(fb("blockProgress", sync="end"), 0) == []


@pytest.mark.parametrize(("status", "line", "greta"), [("DONE", "end complete", "end"),
                                                      ("INTERRUPTED", "end interrupted", "stopped"),
                                                      ("REVOKED", "end interrupted", "stopped"),
                                                      ("FAILED", "end error", "dead")])
def test_an_ends_status_says_how_it_ended(status: str, line: str, greta: str) -> None:
    end = fb("blockProgress", sync="end",
             xml=f'<blockProgress xmlns:bmla="http://www.asap-project.org/bmla" id="b1:end" bmla:status="{status}"/>')
    assert vh_lines(routed("vhmsg", VhAddress("ada", "m1")).feedback(end, 0)) == [f"vrAgentBML ada m1 {line}"]
    (out,) = routed("greta").feedback(end, 0)
    assert out.headers["feedback-type"] == greta


def test_an_interruption_warning_marks_the_end_or_ends_a_block_not_started() -> None:
    router = routed("vhmsg", VhAddress("ada", "m1"))
    router.feedback(fb("blockProgress", sync="start"), 0)
    assert router.feedback(fb("warningFeedback", sync="INTERRUPTED", text="by block b2"), 0) == []
    assert vh_lines(router.feedback(fb("blockProgress", sync="end"), 0)) == ["vrAgentBML ada m1 end interrupted"]
    router = routed("greta")
    (out,) = router.feedback(fb("warningFeedback", sync="INTERRUPTED"), 0)
    assert out.headers["feedback-type"] == "stopped" and "r1" not in router.pending


def test_a_warning_that_only_mentions_an_interrupt_is_no_interruption() -> None:
    router = routed("vhmsg", VhAddress("ada", "m1"))
    assert router.feedback(fb("warningFeedback", sync="CUSTOM_BEHAVIOUR_NOT_SUPPORTED",
                              text="<bmla:interrupt> ignored"), 0) == []
    router.feedback(fb("blockProgress", sync="start"), 0)
    assert vh_lines(router.feedback(fb("blockProgress", sync="end"), 0)) == ["vrAgentBML ada m1 end complete"]


def test_an_end_with_a_reason_is_ecas_realizer_cutting_a_block_short() -> None:
    router = routed("vhmsg", VhAddress("ada", "m1"))
    router.feedback(fb("blockProgress", sync="start"), 0)
    end = fb("blockProgress", sync="end", text="replaced by block 'b2'")
    assert vh_lines(router.feedback(end, 0)) == ["vrAgentBML ada m1 end interrupted"]


def test_a_block_level_refusal_before_the_start_ends_the_block_with_an_error() -> None:
    router = routed("vhmsg", VhAddress("ada", "m1"))
    (out,) = router.feedback(fb("warningFeedback", sync="PARSING_FAILURE", text="line 3: unclosed tag"), 0)
    assert vh_lines([out]) == ["vrAgentBML ada m1 end error PARSING_FAILURE: line 3: unclosed tag"]
    assert "r1" not in router.pending
    router = routed("vhmsg", VhAddress("ada", "m1"))  # about one behaviour: the block goes on
    assert router.feedback(fb("warningFeedback", behaviour="s1", sync="PARSING_FAILURE"), 0) == []
    assert "r1" in router.pending


def test_greta_gets_block_callbacks_with_its_properties() -> None:
    router = routed("greta")
    (start,) = router.feedback(fb("blockProgress", sync="start", global_ns=5_000_000_000), 42)
    assert start.destination == f"/topic/{GRETA_FEEDBACK}"
    assert start.headers == {"feedback-type": "start", "feedback-id": "b1", "feedback-time": "5000"}
    assert router.feedback(fb("syncPointProgress", behaviour="h1", sync="stroke"), 0) == []
    (end,) = router.feedback(fb("blockProgress", sync="end"), 7000)
    assert end.headers["feedback-type"] == "end" and end.headers["feedback-time"] == "7000"
    assert end.body.startswith("<blockProgress")


def test_feedback_of_blocks_the_bridge_did_not_send_goes_nowhere() -> None:
    assert routed("asap").feedback(fb("blockProgress", request_id="someone-else", sync="start"), 0) == []


def test_a_bus_error_about_a_blocks_command_is_a_warning_and_its_end() -> None:
    router = routed("asap")
    error = Error(agent="ada", reason="busy: 4 blocks are being voiced", kind="busy", request_id="r1", service="bml")
    (out,) = router.rejected(error, 0)
    assert 'type="IMPOSSIBLE_TO_SCHEDULE"' in out.body and "busy: 4 blocks" in out.body and not router.pending
    router = routed("vhmsg", VhAddress("ada", "m1"))
    assert vh_lines(router.rejected(error, 0))[0].startswith("vrAgentBML ada m1 end error IMPOSSIBLE_TO_SCHEDULE")


def test_a_refusal_the_realizer_explained_is_passed_on_once_with_its_type() -> None:
    """eca's realizer refuses a block with a warningFeedback and then an error with the same text."""
    warning = fb("warningFeedback", behaviour="s1", sync="NO_SUCH_TARGET", text="<gaze> 's1': no target 'moon'",
                 xml="<warningFeedback id='b1:s1' type='NO_SUCH_TARGET'/>")
    error = Error(agent="ada", reason=warning.text, kind="rejected", request_id="r1", service="bml")
    router = routed("asap")
    assert [o.body for o in router.feedback(warning, 0)] == [warning.xml]
    assert router.rejected(error, 0) == [] and not router.pending  # no second warning
    router = routed("vhmsg", VhAddress("ada", "m1"))
    assert router.feedback(warning, 0) == []
    assert vh_lines(router.rejected(error, 0)) == ["vrAgentBML ada m1 end error NO_SUCH_TARGET: <gaze> 's1': no "
                                                   "target 'moon'"]


def test_the_bridges_own_refusals_per_transport() -> None:
    router = FeedbackRouter(Routes(vhmsg_scope="MY_SCOPE"))
    problem = Refused("PARSING_FAILURE", "not a <bml> block", block="b1")
    (asap,) = router.refused("asap", problem, 0)
    assert asap.destination == f"/topic/{ASAP_FEEDBACK}"
    assert ET.fromstring(asap.body).attrib == {"id": "b1", "type": "PARSING_FAILURE"}
    (greta,) = router.refused("greta", problem, 9)
    assert greta.headers == {"feedback-type": "dead", "feedback-id": "b1", "feedback-time": "9"}
    assert router.refused("vhmsg", problem, 0) == []  # no address: the log line is all
    problem.vh = VhAddress("ada", "m1")
    (vh,) = router.refused("vhmsg", problem, 0)
    assert vh.destination == "/topic/MY_SCOPE" and vh.headers["ELVISH_SCOPE"] == "MY_SCOPE"
    assert " ".join(vhmsg_split(vh.body)) == "vrAgentBML ada m1 end error PARSING_FAILURE: not a <bml> block"


def test_warnings_are_well_formed_and_short() -> None:
    body = warning_xml("", "PARSING_FAILURE", "a <b> & \"c\"\n" + "x" * 5000, character="ada")
    element = ET.fromstring(body)
    assert element.tag == f"{{{NS}}}warningFeedback"
    assert element.attrib == {"id": "unknown", "characterId": "ada", "type": "PARSING_FAILURE"}
    assert element.text is not None and element.text.startswith('a <b> & "c" x') and len(element.text) <= 500


@pytest.mark.parametrize(("kind", "sync", "behaviour", "tag", "ident"), [
    ("blockProgress", "start", "", "blockProgress", "b1:start"),
    ("syncPointProgress", "stroke", "h1", "syncPointProgress", "b1:h1:stroke"),
    ("warningFeedback", "NO_SUCH_TARGET", "g1", "warningFeedback", "b1:g1"),
    ("predictionFeedback", "", "", "predictionFeedback", None),
])
def test_feedback_without_xml_is_built_from_its_fields(kind: str, sync: str, behaviour: str, tag: str,
                                                       ident: str | None) -> None:
    element = ET.fromstring(feedback_xml(fb(kind, sync=sync, behaviour=behaviour)))
    assert element.tag == f"{{{NS}}}{tag}" and element.get("id") == ident


def test_the_pending_blocks_are_bounded() -> None:
    router = FeedbackRouter(max_pending=3)
    for i in range(5):
        router.open(f"r{i}", Origin("asap", "ada", f"b{i}"))
    assert list(router.pending) == ["r2", "r3", "r4"] and router.forgotten == 2


def test_a_flood_is_dropped_and_counted_past_the_queue() -> None:
    q = InboundQueue(maxsize=3)
    assert [q.put(Frame("asap", b"x")) for _ in range(5)] == [True, True, True, False, False]
    assert q.dropped == 2 and len(q) == 3
    assert len(q.take(2)) == 2 and len(q.take(10)) == 1 and q.take(10) == []
