"""When each sync point of a block happens: its references and constraints solved into absolute times.

Every behaviour has its kind's sync points at default offsets (configs/bml.toml [timings]; a speech's from its
text-to-speech timing). A sync attribute or a <synchronize> pins a point; a behaviour with one pinned point
moves whole, with two or more it stretches between them, piecewise linearly over its default offsets (a speech
cannot stretch: its points must fit its audio). Behaviours are laid out one at a time in dependency order, a
behaviour whose references are all resolved first (one with something pinning it before a free one; a free one
at the block start); a <synchronize> pins the rest of its points as soon as one of them is laid out. A cycle of
references is refused.

A group of behaviours tied only to each other (no absolute time, no other block) then moves as a whole so its
earliest start is the block start: `<head end="speech1:start">` delays the speech instead of starting the nod
before the block (BMLRealizerTester testtimeshift.xml, testspeechgestures.xml). A group with an absolute time
that would start before the block is refused. Last, <before>/<after>: a violated one delays the free group on
its late side until it holds, and is refused when that side is anchored or tied to the other.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from itertools import accumulate

from eca.agent.bml.errors import IMPOSSIBLE_TO_SCHEDULE, BmlError
from eca.agent.bml.mapping import BehaviourTimings
from eca.agent.bml.model import (
    Behaviour,
    BlinkParams,
    Block,
    EmotionParams,
    HeadParams,
    SpeechParams,
    SpeechTiming,
    SyncRef,
    Timeline,
    UnrealizedBehaviour,
    WaitParams,
    sync_points,
)

EPS = 1e-6  # seconds: two times this close are one time


@dataclass
class _Unit:
    id: str
    kind: str
    line: int
    names: tuple[str, ...]
    offsets: tuple[float, ...]  # default seconds from start, in the order of names (never decreasing)
    rigid: bool  # speech: its points are its audio's
    sync: Mapping[str, SyncRef]
    links: list[tuple[str, tuple[str, str], float]] = field(default_factory=list)  # (sync, (other, its sync), s)
    self_links: dict[str, tuple[str, float]] = field(default_factory=dict)  # sync -> (own sync, offset)


@dataclass(frozen=True)
class _Term:
    """One reference resolved: point None = an absolute time `base`; else the point's time + `base`."""

    point: tuple[str, str] | None
    base: float
    text: str


def schedule(block: Block, start_s: float, speech: Mapping[str, SpeechTiming],
             known: Mapping[tuple[str, str, str], float] = {}, *,  # noqa: B006 (read only)
             timings: BehaviourTimings | None = None) -> Timeline:
    """Absolute times (start_s + seconds into the block) of every sync point of the block's behaviours.

    speech: each speech behaviour's duration and mark times (from its TTS). known: (block, behaviour, sync) ->
    absolute seconds of blocks scheduled before, for cross-block references (Timeline.as_known gives them, with
    each block's own start and end under behaviour "bml"). BmlError (IMPOSSIBLE_TO_SCHEDULE) when the references
    and constraints cannot all hold.
    """
    if not math.isfinite(start_s):
        raise BmlError(f"block start {start_s!r} is not a finite time", name=block.name, block=block.id,
                       warning_type=IMPOSSIBLE_TO_SCHEDULE)
    return _Scheduler(block, float(start_s), speech, known, timings or BehaviourTimings.from_config()).run()


def _phases(item: Behaviour, t: BehaviourTimings) -> tuple[float, ...]:
    """Seconds between a behaviour's successive default sync points (all but speech and head)."""
    params, kind = item.params, item.kind
    if isinstance(params, WaitParams):
        return (t.wait_s if params.max_wait_s is None else params.max_wait_s,)
    if isinstance(params, EmotionParams):
        return (params.transition_s,)
    if isinstance(params, BlinkParams):  # closing, closed (no time), opening
        return (t.blink_closed_s, 0.0, max(0.0, t.blink_s - t.blink_closed_s))
    if kind == "gaze":
        return (t.gaze_ready_s, t.gaze_hold_s, t.gaze_relax_s)
    if kind in ("faceLexeme", "faceFacs"):
        return (t.face_attack_s, t.face_hold_s, t.face_relax_s)
    return ({"gazeShift": t.gaze_ready_s, "faceShift": t.face_attack_s, "headDirectionShift": t.head_shift_s}
            .get(kind, 0.0),)  # role: at once


class _Scheduler:
    def __init__(self, block: Block, start_s: float, speech: Mapping[str, SpeechTiming],
                 known: Mapping[tuple[str, str, str], float], timings: BehaviourTimings) -> None:
        self.block, self.start_s, self.known = block, start_s, known
        items: list[Behaviour | UnrealizedBehaviour] = [*block.behaviours, *block.unrealized]
        self.units = {item.id: self._unit(item, timings, speech) for item in sorted(items, key=lambda b: b.line)}
        self.pins: dict[str, dict[str, tuple[float, str]]] = {uid: {} for uid in self.units}
        self.laid: dict[str, dict[str, float]] = {}
        self.anchored: set[str] = set()
        self.parent = {uid: uid for uid in self.units}
        self.groups: list[list[_Term]] = []

    def fail(self, message: str, behaviour: str = "", line: int = 0) -> BmlError:
        return BmlError(message, name=self.block.name, line=line, block=self.block.id, behaviour=behaviour,
                        warning_type=IMPOSSIBLE_TO_SCHEDULE)

    def rel(self, t: float) -> str:
        return f"{t - self.start_s:.3f} s"

    # -- the behaviours' default sync points --

    def _unit(self, item: Behaviour | UnrealizedBehaviour, timings: BehaviourTimings,
              speech: Mapping[str, SpeechTiming]) -> _Unit:
        rigid = isinstance(item, Behaviour) and isinstance(item.params, SpeechParams)
        if isinstance(item, UnrealizedBehaviour):
            names = sync_points(item.kind)
            step = timings.unrealized_s / max(1, len(names) - 1)
            return _Unit(item.id, item.kind, item.line, names, tuple(i * step for i in range(len(names))), False,
                         item.sync)
        names, offsets = self._defaults(item, timings, speech)
        return _Unit(item.id, item.kind, item.line, names, offsets, rigid, item.sync)

    def _defaults(self, item: Behaviour, t: BehaviourTimings,
                  speech: Mapping[str, SpeechTiming]) -> tuple[tuple[str, ...], tuple[float, ...]]:
        params = item.params
        if isinstance(params, SpeechParams):
            return self._speech_points(item, params, speech.get(item.id))
        if isinstance(params, HeadParams):
            n, prepare, stroke = params.repetitions, t.head_prepare_s, t.head_stroke_s
            strokes = [prepare + (k - 0.5) * stroke for k in range(1, n + 1)]
            names = ("start", "ready", "strokeStart", "stroke", *(f"stroke:{k}" for k in range(2, n + 1)),
                     "strokeEnd", "relax", "end")
            done = prepare + n * stroke
            return names, (0.0, prepare, prepare, *strokes, done, done, done + t.head_retract_s)
        return sync_points(item.kind), tuple(accumulate(_phases(item, t), initial=0.0))

    def _speech_points(self, item: Behaviour, params: SpeechParams,
                       timing: SpeechTiming | None) -> tuple[tuple[str, ...], tuple[float, ...]]:
        if timing is None:
            raise self.fail("no speech timing was given for this speech", item.id, item.line)
        duration = timing.duration_s
        if not (math.isfinite(duration) and duration >= 0):
            raise self.fail(f"speech duration {duration!r} is not a finite time >= 0", item.id, item.line)
        marks = []
        for order, mark in enumerate(params.marks):
            at = timing.marks.get(mark)
            if at is None or not math.isfinite(at):
                raise self.fail(f"the speech timing gives no time for mark '{mark}'", item.id, item.line)
            marks.append((min(max(at, 0.0), duration), order, mark))  # a TTS may round past the end
        marks.sort()
        return ("start", *(m for _, _, m in marks), "end"), (0.0, *(t for t, _, _ in marks), duration)

    # -- references --

    def _term(self, ref: SyncRef, line: int, who: str) -> _Term:
        if ref.block is not None:
            key = (ref.block, ref.behaviour or "bml", ref.sync or "start")
            at = self.known.get(key)
            if at is None or not math.isfinite(at):
                raise self.fail(f"'{ref.text}': no time is known for {key[1]}:{key[2]} of block '{ref.block}' "
                                "(not scheduled before this one)", who, line)
            return _Term(None, at + ref.offset_s, ref.text)
        if ref.behaviour is None or ref.sync is None:
            return _Term(None, self.start_s + ref.offset_s, ref.text)
        unit = self.units.get(ref.behaviour)
        if unit is None:
            raise self.fail(f"'{ref.text}': there is no behaviour '{ref.behaviour}' in this block", who, line)
        if ref.sync not in unit.names:
            raise self.fail(f"'{ref.text}': {unit.kind} '{unit.id}' has no sync point '{ref.sync}' (it has "
                            f"{', '.join(unit.names)})", who, line)
        return _Term((ref.behaviour, ref.sync), ref.offset_s, ref.text)

    def _find(self, uid: str) -> str:
        while self.parent[uid] != uid:
            self.parent[uid] = self.parent[self.parent[uid]]
            uid = self.parent[uid]
        return uid

    def _join(self, a: str, b: str) -> None:
        self.parent[self._find(a)] = self._find(b)

    def _pin(self, uid: str, sync: str, at: float, source: str) -> None:
        unit = self.units[uid]
        if uid in self.laid:
            if abs(self.laid[uid][sync] - at) > EPS:
                raise self.fail(f"'{uid}:{sync}' is at {self.rel(self.laid[uid][sync])}, and '{source}' asks for "
                                f"{self.rel(at)}", uid, unit.line)
            return
        earlier = self.pins[uid].get(sync)
        if earlier is not None and abs(earlier[0] - at) > EPS:
            raise self.fail(f"'{uid}:{sync}' is asked to be at {self.rel(earlier[0])} by '{earlier[1]}' and at "
                            f"{self.rel(at)} by '{source}'", uid, unit.line)
        self.pins[uid][sync] = (at, source)

    # -- solving --

    def run(self) -> Timeline:
        for unit in self.units.values():
            for sync, ref in unit.sync.items():
                term = self._term(ref, unit.line, unit.id)
                if term.point is None:
                    self._pin(unit.id, sync, term.base, ref.text)
                    self.anchored.add(unit.id)
                elif term.point[0] == unit.id:
                    unit.self_links[sync] = (term.point[1], term.base)
                else:
                    unit.links.append((sync, term.point, term.base))
                    self._join(unit.id, term.point[0])
        inequalities: list[tuple[_Term, _Term, int]] = []  # (early, late, line): late's value >= early's
        for constraint in self.block.constraints:
            terms = [self._term(ref, constraint.line, "") for ref in constraint.refs]
            if constraint.kind == "synchronize":
                self._synchronize(terms, constraint.line)
            else:
                anchor, others = terms[0], terms[1:]
                inequalities += [((anchor, other, constraint.line) if constraint.kind == "after"
                                  else (other, anchor, constraint.line)) for other in others]
        self._lay_out_all()
        self._start_free_groups()
        self._hold_inequalities(inequalities)
        for uid, times in self.laid.items():
            if times["start"] < self.start_s - EPS:
                raise self.fail(f"it would start at {self.rel(times['start'])}, before its block", uid,
                                self.units[uid].line)
        return self._timeline()

    def _synchronize(self, terms: list[_Term], line: int) -> None:
        absolute = [term for term in terms if term.point is None]
        for term in absolute[1:]:
            if abs(term.base - absolute[0].base) > EPS:
                raise self.fail(f"<synchronize> asks for both {self.rel(absolute[0].base)} ('{absolute[0].text}') "
                                f"and {self.rel(term.base)} ('{term.text}')", line=line)
        points = [term for term in terms if term.point is not None]
        if absolute:
            for term in points:
                assert term.point is not None
                self._pin(term.point[0], term.point[1], absolute[0].base - term.base, absolute[0].text)
                self.anchored.add(term.point[0])
            return
        for term in points[1:]:
            assert term.point is not None and points[0].point is not None
            self._join(term.point[0], points[0].point[0])
        self.groups.append(points)

    def _lay_out_all(self) -> None:
        remaining = list(self.units)
        deps = {uid: {link[1][0] for link in unit.links} for uid, unit in self.units.items()}
        while remaining:
            ready = [uid for uid in remaining if deps[uid] <= self.laid.keys()]
            if not ready:
                raise self._cycle(remaining, deps)
            pinned = [uid for uid in ready if self.pins[uid] or self.units[uid].links]
            uid = (pinned or ready)[0]
            unit = self.units[uid]
            for sync, (other, other_sync), offset in unit.links:
                self._pin(uid, sync, self.laid[other][other_sync] + offset, unit.sync[sync].text)
            self.laid[uid] = self._layout(unit, {s: at for s, (at, _) in self.pins[uid].items()})
            remaining.remove(uid)
            for group in [g for g in self.groups if any(term.point and term.point[0] == uid for term in g)]:
                self.groups.remove(group)
                first = next(term for term in group if term.point and term.point[0] == uid)
                assert first.point is not None
                value = self.laid[uid][first.point[1]] + first.base
                for term in group:
                    assert term.point is not None
                    self._pin(term.point[0], term.point[1], value - term.base, first.text)

    def _cycle(self, remaining: list[str], deps: Mapping[str, set[str]]) -> BmlError:
        path = [remaining[0]]
        while True:
            following = sorted(deps[path[-1]] - self.laid.keys())[0]
            if following in path:
                cycle = path[path.index(following):] + [following]
                named = " -> ".join(f"'{uid}' (line {self.units[uid].line})" for uid in cycle)
                return self.fail(f"the references {named} form a cycle", cycle[0], self.units[cycle[0]].line)
            path.append(following)

    def _layout(self, unit: _Unit, pins: dict[str, float]) -> dict[str, float]:
        """The unit's times with these points pinned (and its references to its own points)."""
        pending = dict(unit.self_links)
        while pending:
            times = self._place(unit, pins)
            ready = [sync for sync, (target, _) in pending.items() if target not in pending]
            if not ready:
                raise self.fail(f"its references to its own sync points ({', '.join(pending)}) form a cycle",
                                unit.id, unit.line)
            sync = ready[0]
            target, offset = pending.pop(sync)
            pins[target] = pins.get(target, times[target])  # the point referred to stays where it lies now
            want = pins[target] + offset
            if sync in pins and abs(pins[sync] - want) > EPS:
                raise self.fail(f"'{sync}' is asked to be at {self.rel(pins[sync])} and at {self.rel(want)} "
                                f"('{unit.sync[sync].text}')", unit.id, unit.line)
            pins[sync] = want
        return self._place(unit, pins)

    def _place(self, unit: _Unit, pins: Mapping[str, float]) -> dict[str, float]:
        names, d = unit.names, unit.offsets
        index = {name: i for i, name in enumerate(names)}
        pinned = sorted((index[name], at) for name, at in pins.items())
        if not pinned:
            return {name: self.start_s + d[i] for i, name in enumerate(names)}
        for (i, ti), (j, tj) in zip(pinned, pinned[1:], strict=False):
            if tj < ti - EPS:
                raise self.fail(f"'{names[j]}' ({self.rel(tj)}) would come before '{names[i]}' ({self.rel(ti)})",
                                unit.id, unit.line)
            if unit.rigid and abs((tj - ti) - (d[j] - d[i])) > EPS:
                raise self.fail(f"a speech cannot be stretched: its audio has {d[j] - d[i]:.3f} s from '{names[i]}' "
                                f"to '{names[j]}', the references ask for {tj - ti:.3f} s", unit.id, unit.line)
        times: list[float] = []
        for k in range(len(names)):
            before = [(i, t) for i, t in pinned if i <= k]
            after = [(i, t) for i, t in pinned if i >= k]
            if not before:
                i, t = after[0]
                at = t - (d[i] - d[k])
            elif not after:
                i, t = before[-1]
                at = t + (d[k] - d[i])
            else:
                (i, ti), (j, tj) = before[-1], after[0]
                if i == j:
                    at = ti
                elif d[j] - d[i] > EPS:
                    at = ti + (d[k] - d[i]) * (tj - ti) / (d[j] - d[i])
                else:  # the defaults put both at one time: share the span out evenly
                    at = ti + (tj - ti) * (k - i) / (j - i)
            times.append(max(at, times[-1]) if times else at)  # rounding never puts a point before the last
        return dict(zip(names, times, strict=True))

    def _groups(self) -> dict[str, list[str]]:
        groups: dict[str, list[str]] = {}
        for uid in self.units:
            groups.setdefault(self._find(uid), []).append(uid)
        return groups

    def _shift(self, members: list[str], by: float) -> None:
        for uid in members:
            self.laid[uid] = {sync: at + by for sync, at in self.laid[uid].items()}

    def _start_free_groups(self) -> None:
        for members in self._groups().values():
            if not self.anchored.intersection(members):
                earliest = min(self.laid[uid]["start"] for uid in members)
                self._shift(members, self.start_s - earliest)

    def _hold_inequalities(self, inequalities: list[tuple[_Term, _Term, int]]) -> None:
        groups = self._groups()
        rounds = len(inequalities) * (len(groups) + 1) + 1
        for _ in range(rounds):
            moved = False
            for early, late, line in inequalities:
                gap = self._value(early) - self._value(late)
                if gap <= EPS:
                    continue
                late_group = self._find(late.point[0]) if late.point else None
                early_group = self._find(early.point[0]) if early.point else None
                if late_group is None or late_group == early_group or self.anchored.intersection(groups[late_group]):
                    raise self.fail(f"'{late.text}' ({self.rel(self._value(late))}) must not come before "
                                    f"'{early.text}' ({self.rel(self._value(early))}), and neither can move",
                                    line=line)
                self._shift(groups[late_group], gap)
                moved = True
            if not moved:
                return
        raise self.fail("the <before>/<after> constraints cannot all hold at once")

    def _value(self, term: _Term) -> float:
        return term.base if term.point is None else self.laid[term.point[0]][term.point[1]] + term.base

    def _timeline(self) -> Timeline:
        times = {(b.id, sync): at for b in self.block.behaviours for sync, at in self.laid[b.id].items()}
        ends = [self.laid[b.id]["end"] for b in self.block.behaviours]
        return Timeline(self.block.id, self.start_s, max([self.start_s, *ends]), times)
