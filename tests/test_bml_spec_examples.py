"""The BML 1.0 spec editor's own example blocks, scheduled: each row is a block, the speech timings a TTS would
report for it, and the times its sync points must take (or the error it must raise).

The blocks are those of the reference parser's and tester's test resources (saiba/OpenBMLParser
test/resource/bmltest/, saiba/BMLRealizerTester testcases/bml-1/core/, both MIT), whose comments give the required
timing, plus the reference forms quoted in docs (`end="s1:and1end+0.25"`, `start="h2:start-2"`, `start="6"`).
Default durations are fixed here (TIMINGS), so the expected numbers follow from the rows alone: a head of one
repetition lasts 0.8 s (stroke at 0.4), a gaze 1.6 s (ready at 0.3), an unrealized gesture 1 s (stroke at 0.5).
"""

from __future__ import annotations

import pytest

from eca.agent.bml import (
    IMPOSSIBLE_TO_SCHEDULE,
    PARSING_FAILURE,
    BehaviourTimings,
    BmlError,
    SpeechTiming,
    parse_block,
    schedule,
)

TIMINGS = BehaviourTimings(
    face_attack_s=0.2, face_hold_s=1.0, face_relax_s=0.2, head_prepare_s=0.1, head_stroke_s=0.6,
    head_retract_s=0.1, head_shift_s=0.5, gaze_ready_s=0.3, gaze_hold_s=1.0, gaze_relax_s=0.3,
    blink_closed_s=0.05, blink_s=0.25, wait_s=0.0, unrealized_s=1.0,
)
START = 100.0  # the block's start on the caller's clock: every expected time below is relative to it
NS = 'xmlns="http://www.bml-initiative.org/bml/bml-1.0"'


def bml(body: str, block_id: str = "bml1") -> str:
    return f'<bml {NS} id="{block_id}">\n{body}\n</bml>'


def speech(seconds: float, **marks: float) -> SpeechTiming:
    return SpeechTiming(seconds, marks)


HEY_PUNK = '<speech id="speech1" start="6"><text>Hey punk <sync id="syncstart1" />what do ya want?</text></speech>'
WELCOME_S1 = '<speech id="speech1"><text>Welcome <sync id="s1"/>ladies and gentlemen!</text></speech>'
BLAH = '<speech id="speech1"><text>blah blah <sync id="sync4"/> blah.</text></speech>'
BEAT_NOD = '<gesture id="beat1" lexeme="BEAT"/><head id="nod1" lexeme="NOD"/>'
GRIET = ('<speech id="welkom"><text><sync id="deicticheart1"/> Welcome! I am Griet. <sync id="beat1b1"/>Because we '
         'still need to eat, I took service with a local painter.</text></speech>')

# (name, block, speech timings, expected: {(behaviour, sync): seconds from the block's start} or an error type)
ROWS: list[tuple[str, str, dict[str, SpeechTiming], dict[tuple[str, str], float] | str]] = [
    ("testabs", bml('<head id="nod1" start="1" lexeme="NOD"/><gesture id="g1" lexeme="BEAT" start="1"/>'
                    '<speech id="speech1" start="1"><text>Yes.</text></speech>'),
     {"speech1": speech(0.5)}, {("nod1", "start"): 1, ("speech1", "start"): 1, ("speech1", "end"): 1.5}),
    ("testnod", bml('<head id="nod1" lexeme="NOD"/>'), {},
     {("nod1", "start"): 0, ("nod1", "stroke"): 0.4, ("nod1", "end"): 0.8}),
    ("testnod2x_absolute", bml('<head id="nod1" lexeme="NOD" start="1"/><head id="nod2" lexeme="NOD" start="3"/>'),
     {}, {("nod1", "start"): 1, ("nod1", "end"): 1.8, ("nod2", "start"): 3}),
    ("testnod_absolute", bml('<head id="nod1" lexeme="NOD" start="0" end="2"/>'), {},
     {("nod1", "start"): 0, ("nod1", "stroke"): 1.0, ("nod1", "end"): 2}),  # stretched 2.5 times
    ("testnod_invalidtime", bml('<head id="nod1" lexeme="NOD" start="2" end="0"/>'), {}, IMPOSSIBLE_TO_SCHEDULE),
    ("testnod_offset", bml('<head id="nod1" lexeme="NOD"/><head id="nod2" lexeme="NOD"/><constraint><synchronize>'
                           '<sync ref="nod1:start+1"/><sync ref="nod2:start-1"/></synchronize></constraint>'),
     {}, {("nod1", "start"): 0, ("nod2", "start"): 2}),
    ("testnodandbeat", bml('<head id="nod1" start="3" end="5" lexeme="NOD"/>'
                           '<gesture id="beat1" start="nod1:stroke" lexeme="BEAT" mode="RIGHT_HAND"/>'),
     {}, {("nod1", "start"): 3, ("nod1", "end"): 5}),
    ("testnods", bml('<head id="nod1" start="1" lexeme="TILT"/><head id="tilt1" start="nod1:end+1" lexeme="SHAKE"/>'),
     {}, {("nod1", "start"): 1, ("nod1", "end"): 1.8, ("tilt1", "start"): 2.8}),
    ("testoffsetchain", bml('<head id="h1" lexeme="NOD" start="h2:start-2"/><head id="h2" lexeme="NOD" '
                            'start="h3:start-2"/><head id="h3" lexeme="NOD" start="h4:start-2"/>'
                            '<head id="h4" lexeme="NOD" start="10"/>'),
     {}, {("h1", "start"): 4, ("h2", "start"): 6, ("h3", "start"): 8, ("h4", "start"): 10}),
    ("testoffsetchainreversed", bml('<head id="h4" lexeme="NOD" start="10"/><head id="h3" lexeme="NOD" '
                                    'start="h4:start-2"/><head id="h2" lexeme="NOD" start="h3:start-2"/>'
                                    '<head id="h1" lexeme="NOD" start="h2:start-2"/>'),
     {}, {("h1", "start"): 4, ("h2", "start"): 6, ("h3", "start"): 8, ("h4", "start"): 10}),
    ("testrequiredbeh", bml('<required><head id="h1" lexeme="NOD" start="h2:start-2"/><head id="h2" lexeme="NOD" '
                            'start="h3:start-2"/></required><head id="h3" lexeme="NOD" start="h4:start-2"/>'
                            '<head id="h4" lexeme="NOD" start="10"/>'),
     {}, {("h1", "start"): 4, ("h2", "start"): 6, ("h3", "start"): 8, ("h4", "start"): 10}),
    ("testoffsetchainneg", bml('<head id="h1" lexeme="NOD" start="speech1:s1"/><head id="h2" lexeme="NOD" '
                               'start="h1:end"/><head id="h3" lexeme="NOD" start="h2:end"/><head id="h4" '
                               'lexeme="NOD" start="h3:end"/>' + WELCOME_S1),
     {"speech1": speech(2.0, s1=0.6)},
     {("speech1", "start"): 0, ("h1", "start"): 0.6, ("h2", "start"): 1.4, ("h3", "start"): 2.2,
      ("h4", "start"): 3.0}),
    ("testoffsetgaze", bml('<gaze id="gaze1" start="2" influence="NECK" target="bluebox"/><speech id="speech1" '
                           'start="gaze1:ready"><text>Welcome ladies and gentlemen!</text></speech>'),
     {"speech1": speech(2.0)}, {("gaze1", "start"): 2, ("gaze1", "ready"): 2.3, ("speech1", "start"): 2.3}),
    ("testoffsetgaze2", bml('<speech id="speech1" start="gaze1:ready"><text>Welcome ladies and gentlemen!</text>'
                            '</speech><gaze id="gaze1" start="2" influence="NECK" target="bluebox"/>'),
     {"speech1": speech(2.0)}, {("gaze1", "start"): 2, ("speech1", "start"): 2.3}),
    ("testgazereadytimed", bml('<gaze id="gaze1" ready="3" end="10" influence="NECK" target="bluebox"/>'), {},
     {("gaze1", "start"): 2.7, ("gaze1", "ready"): 3, ("gaze1", "relax"): 3 + 7 * 1.0 / 1.3, ("gaze1", "end"): 10}),
    ("testgazeshift", bml('<gazeShift id="shift1" start="0" end="3" influence="EYES" target="bluebox"/>'), {},
     {("shift1", "start"): 0, ("shift1", "end"): 3}),
    ("testhead_selftimed", bml('<head id="shake1" start="0" end="shake1:start+1" lexeme="SHAKE"/>'), {},
     {("shake1", "start"): 0, ("shake1", "end"): 1}),
    ("testspeech_2linked", bml('<speech id="speech1"><text>Welcome ladies and gentlemen!</text></speech>'
                               '<speech id="speech2" start="speech1:end"><text>This is the BML speech test</text>'
                               '</speech>'),
     {"speech1": speech(1.5), "speech2": speech(2.0)},
     {("speech1", "start"): 0, ("speech2", "start"): 1.5, ("speech2", "end"): 3.5}),
    ("testspeech_endtimed", bml('<speech id="speech1" end="5"><text>Welcome ladies and gentlemen!</text></speech>'),
     {"speech1": speech(2.0)}, {("speech1", "start"): 3, ("speech1", "end"): 5}),
    ("testspeech_endtimed2", bml('<speech id="speech1" end="0.1"><text>Welcome ladies!</text></speech>'),
     {"speech1": speech(2.0)}, IMPOSSIBLE_TO_SCHEDULE),
    ("testspeech_invalidtime", bml('<speech id="speech1" start="2" end="0"><text>Hello world.</text></speech>'),
     {"speech1": speech(1.0)}, IMPOSSIBLE_TO_SCHEDULE),
    ("testspeech_invalidtimesync", bml('<speech id="speech1"><text>Hello<sync id="s1"/> world.</text></speech>'
                                       '<constraint><synchronize><sync ref="speech1:s1"/><sync ref="0.01"/>'
                                       '</synchronize></constraint>'),
     {"speech1": speech(1.0, s1=0.5)}, IMPOSSIBLE_TO_SCHEDULE),
    ("testspeech_invalidtimesync2", bml('<speech id="speech1" start="0"><text>Hello<sync id="s1"/> world.</text>'
                                        '</speech><constraint><synchronize><sync ref="speech1:s1"/><sync ref="10"/>'
                                        '</synchronize></constraint>'),
     {"speech1": speech(1.0, s1=0.5)}, IMPOSSIBLE_TO_SCHEDULE),  # a speech cannot stretch
    ("testspeech_nodtimedtosync", bml(HEY_PUNK + '<head id="nod1" lexeme="TILT" start="speech1:syncstart1" end="9"/>'),
     {"speech1": speech(2.0, syncstart1=0.4)},
     {("speech1", "start"): 6, ("speech1", "syncstart1"): 6.4, ("nod1", "start"): 6.4, ("nod1", "end"): 9}),
    ("testspeech_nodtimedtosyncinverseorder",
     bml('<head id="nod1" lexeme="NOD" start="speech1:syncstart1" end="9"/>' + HEY_PUNK),
     {"speech1": speech(2.0, syncstart1=0.4)}, {("speech1", "start"): 6, ("nod1", "start"): 6.4, ("nod1", "end"): 9}),
    ("testspeech_nodtimedtosyncoffset",
     bml(HEY_PUNK + '<head id="nod1" lexeme="TILT" start="speech1:syncstart1+1" end="9"/>'),
     {"speech1": speech(2.0, syncstart1=0.4)}, {("nod1", "start"): 7.4, ("nod1", "end"): 9}),
    ("testspeech_synctimed", bml(WELCOME_S1 + '<constraint><synchronize><sync ref="speech1:s1"/><sync ref="10"/>'
                                              '</synchronize></constraint>'),
     {"speech1": speech(2.0, s1=0.6)}, {("speech1", "s1"): 10, ("speech1", "start"): 9.4, ("speech1", "end"): 11.4}),
    ("testspeech_synctimed2x", bml(WELCOME_S1 + '<speech id="speech2"><text>Hello <sync id="s1"/>world!</text>'
                                   '</speech><constraint><synchronize><sync ref="speech1:s1"/><sync ref="10"/>'
                                   '</synchronize></constraint><constraint><synchronize><sync ref="speech2:s1"/>'
                                   '<sync ref="speech1:s1+10"/></synchronize></constraint>'),
     {"speech1": speech(2.0, s1=0.6), "speech2": speech(1.0, s1=0.3)},
     {("speech1", "s1"): 10, ("speech2", "s1"): 20, ("speech2", "start"): 19.7}),
    ("testspeech_synctimed2x_required",
     bml(WELCOME_S1 + '<speech id="speech2"><text>Hello <sync id="s1"/>world!</text></speech><constraint>'
         '<synchronize><sync ref="speech1:s1"/><sync ref="10"/></synchronize></constraint><required><constraint>'
         '<synchronize><sync ref="speech2:s1"/><sync ref="speech1:s1+10"/></synchronize></constraint></required>'),
     {"speech1": speech(2.0, s1=0.6), "speech2": speech(1.0, s1=0.3)}, {("speech1", "s1"): 10, ("speech2", "s1"): 20}),
    ("testspeech_unknownbehavior", bml('<speech id="welkom" start="unknownbeh:end"><text>Welcome!</text></speech>'),
     {"welkom": speech(1.0)}, IMPOSSIBLE_TO_SCHEDULE),
    ("testspeech_unknownsync", bml('<speech id="speech1"><text>Welcome!</text></speech>'
                                   '<head id="nod1" lexeme="NOD" start="speech1:unknown"/>'),
     {"speech1": speech(1.0)}, IMPOSSIBLE_TO_SCHEDULE),
    ("testspeechandnod_synctimed", bml(WELCOME_S1 + '<head id="nod1" lexeme="NOD" start="speech1:start"/><constraint>'
                                       '<synchronize><sync ref="speech1:s1"/><sync ref="10"/></synchronize>'
                                       '</constraint>'),
     {"speech1": speech(2.0, s1=0.6)}, {("speech1", "s1"): 10, ("speech1", "start"): 9.4, ("nod1", "start"): 9.4}),
    # transleft starts a second before the speech's first mark: the speech waits for it (OpenBMLParser's variant)
    ("testspeechgestures", bml(GRIET + '<gesture id="g1" lexeme="BEAT" mode="RIGHT_HAND" start="welkom:deicticheart1" '
                               'end="welkom:deicticheart1+2"/><gesture id="relaxleft" lexeme="BEAT" '
                               'start="g1:end+0.5" end="g1:end+2.8"/><gesture id="transleft" lexeme="BEAT" '
                               'start="g1:start-1" end="g1:start+1"/>'),
     {"welkom": speech(6.0, deicticheart1=0.0, beat1b1=3.0)},
     {("welkom", "start"): 1, ("welkom", "deicticheart1"): 1, ("welkom", "beat1b1"): 4}),
    ("testspeechgestures_tester", bml(GRIET + '<gesture id="g1" lexeme="BEAT" start="welkom:deicticheart1" '
                                      'end="welkom:deicticheart1+2"/><gesture id="transleft" lexeme="BEAT" '
                                      'start="g1:start-2" end="g1:start"/>'),
     {"welkom": speech(6.0, deicticheart1=0.0, beat1b1=3.0)}, {("welkom", "start"): 2}),
    ("testspeechrel_offsets", bml('<speech id="speech1" start="4"><text>Welcome ladies and gentlemen!</text></speech>'
                                  '<speech id="speech2" start="speech1:end+5"><text>This is the BMLT speech test.'
                                  '</text></speech><head id="nod2" repetition="20" start="speech1:start-2" '
                                  'end="speech2:end+3" lexeme="NOD"/>'),
     {"speech1": speech(1.5), "speech2": speech(2.0)},
     {("speech1", "start"): 4, ("speech2", "start"): 10.5, ("nod2", "start"): 2, ("nod2", "end"): 15.5}),
    ("testtimeshift", bml('<speech id="speech1"><text>Welcome ladies and gentlemen!</text></speech>'
                          '<head id="nod1" end="speech1:start" lexeme="NOD"/>'),
     {"speech1": speech(2.0)}, {("nod1", "start"): 0, ("nod1", "end"): 0.8, ("speech1", "start"): 0.8}),
    ("waitdoublesync", bml('<speech id="speech1"><text>Elckerlyc is a BML compliant behavior realizer.</text>'
                           '</speech><speech id="speech2" start="speech1:end"><text>It is designed for continuous '
                           'interaction.</text></speech><wait id="w1" start="speech1:start" end="speech1:end"/>'),
     {"speech1": speech(3.0), "speech2": speech(2.0)},
     {("w1", "start"): 0, ("w1", "end"): 3, ("speech2", "start"): 3}),
    # after/before: OpenBMLParser's form, the anchor in the element's ref; each <sync> after (before) it
    ("after", bml(BLAH + BEAT_NOD + '<constraint><after ref="speech1:sync4"><sync ref="beat1:stroke+2"/>'
                  '<sync ref="nod1:stroke"/></after></constraint>'),
     {"speech1": speech(2.0, sync4=1.5)}, {("speech1", "start"): 0, ("nod1", "stroke"): 1.5, ("nod1", "start"): 1.1}),
    ("after2", bml(BLAH + BEAT_NOD + '<constraint><after ref="speech1:sync4+1"><sync ref="beat1:stroke+2"/>'
                   '<sync ref="nod1:stroke"/></after></constraint>'),
     {"speech1": speech(2.0, sync4=1.5)}, {("nod1", "stroke"): 2.5}),
    ("before", bml(BLAH + BEAT_NOD + '<constraint><before ref="speech1:sync4"><sync ref="beat1:stroke+2"/>'
                   '<sync ref="nod1:stroke"/></before></constraint>'),
     {"speech1": speech(2.0, sync4=1.5)},  # beat1:stroke+2 = 2.5 must not pass sync4: the speech waits 1 s
     {("speech1", "start"): 1.0, ("speech1", "sync4"): 2.5, ("nod1", "start"): 0}),
    ("afterunify_offset", bml(BLAH + BEAT_NOD + '<constraint><after ref="speech1:sync4"><sync ref="beat1:stroke+2"/>'
                              '<sync ref="nod1:stroke"/></after></constraint><constraint><after '
                              'ref="speech1:sync4+5"><sync ref="beat1:end"/><sync ref="nod1:end+1"/></after>'
                              '</constraint>'),
     {"speech1": speech(2.0, sync4=1.5)}, {("nod1", "end"): 5.5, ("nod1", "start"): 4.7}),
    ("testgaze", bml('<gaze id="gaze1" start="1" end="10" influence="NECK" target="bluebox"/>'), {},
     {("gaze1", "start"): 1, ("gaze1", "ready"): 1 + 9 * 0.3 / 1.6, ("gaze1", "end"): 10}),
    ("testnodlong", bml('<head start="0" end="5" id="nod1" lexeme="NOD"/>'), {},
     {("nod1", "start"): 0, ("nod1", "end"): 5}),
    ("testshortbeh", bml('<head start="0" end="0.00001" id="nod1" lexeme="NOD"/>'), {},
     {("nod1", "start"): 0, ("nod1", "end"): 0.00001}),
    ("testspeechgesturesync2x", bml('<gesture lexeme="BEAT" id="beat5"/><speech id="speech1" start="beat5:stroke">'
                                    '<text>Yes.</text></speech><gesture lexeme="BEAT" id="beatstop" '
                                    'start="beat5:end+3"/><speech id="speech2" start="beatstop:end"><text>That was '
                                    'absolutely great!</text></speech>'),
     {"speech1": speech(0.5), "speech2": speech(2.0)}, {("speech1", "start"): 0.5, ("speech2", "start"): 5.0}),
    ("testface", bml('<faceLexeme id="face1" lexeme="RAISE_LEFT_BROW" amount="1"/>'), {},
     {("face1", "start"): 0, ("face1", "attackPeak"): 0.2, ("face1", "relax"): 1.2, ("face1", "end"): 1.4}),
    ("testpostureshift", bml('<postureShift id="shift1" start="0" end="3"><stance type="SITTING"/></postureShift>'
                             '<head id="nod1" lexeme="NOD" start="shift1:end"/>'), {}, {("nod1", "start"): 3}),
    # the reference forms quoted in the standard's text
    ("and1end", bml('<speech id="s1"><text>Yes <sync id="and1end"/>and no.</text></speech>'
                    '<faceLexeme id="f1" lexeme="RAISE_BROWS" start="s1:start" end="s1:and1end+0.25"/>'),
     {"s1": speech(1.0, and1end=0.3)}, {("f1", "start"): 0, ("f1", "end"): 0.55}),
    ("h2:start-2", bml('<head id="h2" lexeme="NOD" start="6"/><head id="h1" lexeme="SHAKE" start="h2:start-2"/>'), {},
     {("h1", "start"): 4, ("h2", "start"): 6}),
    ("bmlnoid", f"<bml {NS}/>", {}, PARSING_FAILURE),
    ("testinvalidxml", bml('<speech id="speech1"><text>Hello world</text></speech></speech>'
                           '<head id="nod1" repetition="2" start="0" lexeme="NOD"/>'), {}, PARSING_FAILURE),
    ("testinvalidxml2", bml('<speech start="nod1:relax:2" id="speech1"><text>Hello world</text></speech>'
                            '<head id="nod1" repetition="2" start="0" lexeme="NOD"/>'), {}, PARSING_FAILURE),
]


@pytest.mark.parametrize(("name", "xml", "timings", "expected"), ROWS, ids=[row[0] for row in ROWS])
def test_spec_example(name: str, xml: str, timings: dict[str, SpeechTiming],
                      expected: dict[tuple[str, str], float] | str) -> None:
    if isinstance(expected, str):
        with pytest.raises(BmlError) as caught:
            schedule(parse_block(xml, name), START, timings, timings=TIMINGS)
        assert caught.value.warning_type == expected, str(caught.value)
        assert caught.value.line > 0, "an error names the line it is about"
        return
    timeline = schedule(parse_block(xml, name), START, timings, timings=TIMINGS)
    for (behaviour, sync), seconds in expected.items():
        assert timeline.times[(behaviour, sync)] == pytest.approx(START + seconds, abs=1e-6), (behaviour, sync)
    for behaviour in {b for b, _ in timeline.times}:
        points = [t for (b, _), t in timeline.times.items() if b == behaviour]
        assert points == sorted(points), f"{behaviour}'s sync points are out of order"
        assert points[0] >= START - 1e-9, f"{behaviour} starts before its block"
