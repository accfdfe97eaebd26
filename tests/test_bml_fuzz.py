"""Property tests: whatever arrives (random bytes, broken blocks), parse_block and schedule raise nothing but
BmlError; and a generated valid block, when it can be scheduled, keeps every behaviour's points in order, after
the block start, and every reference and constraint it was given."""

from __future__ import annotations

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from eca.agent.bml import Block, BmlError, SpeechParams, SpeechTiming, Timeline, parse_block, schedule
from tests.test_bml_spec_examples import ROWS, TIMINGS

FAST = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
SEEDS = [row[1] for row in ROWS] + [
    '<act><participant id="a"/><bml id="s"><speech id="sp">Hi <mark name="T0"/>there</speech>'
    '<head id="h" type="NOD" repeats="2" start="sp:T0"/><face id="f" type="facs" au="1_left"/></bml></act>',
    '<bml id="e" xmlns:eca="urn:eca:bml:1.0"><eca:emotion id="e1" name="happy"/><eca:role id="r" role="talking"/>'
    '<blink id="k" start="e1:end"/><constraint><before><sync ref="k:start"/><sync ref="r:end+1"/></before>'
    '</constraint></bml>',
]
SNIPPETS = ['<', '>', '"', "'", '/>', '</bml>', 'start="', 'end="', ':', '-', '+', '1e9', 'nan', '600.5', 'id="x"',
            '<sync id="q"/>', '&amp;', '&lol;', '<!DOCTYPE a>', '\x00', 'é', '\ufeff', 'xmlns="urn:x"', 'sbm:',
            'repetition="0"', 'amount="7"', '<constraint>', '<synchronize>', '<sync ref="h:start"/>', 'self:',
            'bml:start', '<required>', '<![CDATA[<]]>', '<?pi x?>', '<!-- c -->']


def speech_timings(block: Block) -> dict[str, SpeechTiming]:
    timings = {}
    for behaviour in block.behaviours:
        if isinstance(behaviour.params, SpeechParams):
            marks = behaviour.params.marks
            timings[behaviour.id] = SpeechTiming(2.0, {m: (i + 1) / (len(marks) + 1) * 2 for i, m in enumerate(marks)})
    return timings


def parse_and_schedule(data: str | bytes) -> None:
    try:
        block = parse_block(data)
        schedule(block, 3.0, speech_timings(block), {("b0", "h", "end"): 3.5}, timings=TIMINGS)
    except BmlError as error:
        assert str(error)  # readable, whatever went wrong


@FAST
@given(st.binary(max_size=400))
def test_random_bytes_raise_only_bml_errors(data: bytes) -> None:
    parse_and_schedule(data)


@FAST
@given(st.text(max_size=200))
def test_random_text_raises_only_bml_errors(text: str) -> None:
    parse_and_schedule(text)
    parse_and_schedule(f'<bml id="b">{text}</bml>')


@FAST
@given(st.sampled_from(SEEDS), st.lists(st.tuples(st.floats(0, 1), st.integers(0, 6), st.sampled_from(SNIPPETS)),
                                         min_size=1, max_size=6))
def test_mutated_blocks_raise_only_bml_errors(seed: str, edits: list[tuple[float, int, str]]) -> None:
    text = seed
    for where, cut, snippet in edits:
        at = int(where * len(text))
        text = text[:at] + snippet + text[at + cut:]
    parse_and_schedule(text)


# -- generated valid blocks --

KINDS = {
    "head": ('<head id="{id}" lexeme="NOD" repetition="{n}"{a}/>',
             ["start", "ready", "strokeStart", "stroke", "strokeEnd", "relax", "end"]),
    "face": ('<faceLexeme id="{id}" lexeme="RAISE_BROWS"{a}/>', ["start", "attackPeak", "relax", "end"]),
    "gaze": ('<gaze id="{id}" target="user"{a}/>', ["start", "ready", "relax", "end"]),
    "shift": ('<gazeShift id="{id}" target="user"{a}/>', ["start", "end"]),
    "blink": ('<blink id="{id}"{a}/>', ["start", "attackPeak", "relax", "end"]),
    "speech": ('<speech id="{id}"{a}><text>one <sync id="m1"/>two <sync id="m2"/>three</text></speech>',
               ["start", "m1", "m2", "end"]),
}
TIME = st.integers(-20, 200).map(lambda tenths: tenths / 10)


@st.composite
def valid_blocks(draw: st.DrawFn) -> tuple[str, dict[str, SpeechTiming]]:
    parts: list[str] = []
    points: list[tuple[str, str]] = []
    timings: dict[str, SpeechTiming] = {}
    for i in range(draw(st.integers(1, 7))):
        kind = draw(st.sampled_from(sorted(KINDS)))
        template, names = KINDS[kind]
        bid = f"{kind}{i}"
        attrs = ""
        own = names if kind != "speech" else ["start", "end"]  # a speech's marks are not attributes
        absolute = 0.0  # two absolute pins come in their points' order, so that many blocks can be scheduled
        pins = st.lists(st.sampled_from(own), max_size=1 if kind == "speech" else 2, unique=True)
        for sync in sorted(draw(pins), key=own.index):
            refer = draw(st.booleans())
            if points and refer:
                other, other_sync = draw(st.sampled_from(points))
                ref = f"{other}:{other_sync}{draw(TIME):+.1f}"
            else:
                absolute += max(0.0, draw(TIME))
                ref = f"{absolute:.1f}"
            attrs += f' {sync}="{ref}"'
        parts.append(template.format(id=bid, n=draw(st.integers(1, 3)), a=attrs))
        if kind == "speech":
            first, second = sorted(draw(st.lists(st.integers(0, 30), min_size=2, max_size=2)))
            timings[bid] = SpeechTiming(3.0, {"m1": first / 10, "m2": second / 10})
        points += [(bid, name) for name in names]
    constraints = []
    for _ in range(draw(st.integers(0, 2))):
        kind = draw(st.sampled_from(["synchronize", "before", "after"]))
        refs = draw(st.lists(st.sampled_from(points), min_size=2, max_size=3, unique=True))
        syncs = "".join(f'<sync ref="{b}:{s}{draw(TIME):+.1f}"/>' for b, s in refs)
        constraints.append(f"<{kind}>{syncs}</{kind}>")
    body = "".join(parts) + (f"<constraint>{''.join(constraints)}</constraint>" if constraints else "")
    return f'<bml id="g">{body}</bml>', timings


def value(timeline: Timeline, behaviour: str | None, sync: str | None, offset: float) -> float:
    base = timeline.start_s if behaviour is None or sync is None else timeline.times[(behaviour, sync)]
    return base + offset


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(valid_blocks(), st.floats(0, 1000))
def test_valid_blocks_schedule_in_order_and_keep_every_reference(generated: tuple[str, dict[str, SpeechTiming]],
                                                                 start_s: float) -> None:
    text, timings = generated
    block = parse_block(text)  # always well formed
    try:
        timeline = schedule(block, start_s, timings, timings=TIMINGS)
    except BmlError as error:
        assert error.warning_type == "IMPOSSIBLE_TO_SCHEDULE", str(error)
        return
    tolerance = 1e-6 * (1 + start_s)
    for behaviour in block.behaviours:
        points = [t for (b, _), t in timeline.times.items() if b == behaviour.id]
        assert all(a <= b + tolerance for a, b in zip(points, points[1:], strict=False)), (behaviour.id, points)
        assert points[0] >= start_s - tolerance
        for sync, ref in behaviour.sync.items():
            assert abs(timeline.times[(behaviour.id, sync)] - value(timeline, ref.behaviour, ref.sync,
                                                                    ref.offset_s)) <= tolerance, (behaviour.id, sync)
    for constraint in block.constraints:
        values = [value(timeline, r.behaviour, r.sync, r.offset_s) for r in constraint.refs]
        if constraint.kind == "synchronize":
            assert max(values) - min(values) <= tolerance
        elif constraint.kind == "before":
            assert all(v <= values[0] + tolerance for v in values[1:])
        else:
            assert all(v >= values[0] - tolerance for v in values[1:])
    assert timeline.end_s >= start_s
