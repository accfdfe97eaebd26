"""One agent's BML blocks on the master clock, on injected time: when each block starts (its composition),
which sync points have passed, and the standard's feedback, each exactly once.

The service (services/processes/bml.py) parses and schedules a block (parse.py, schedule.py), realizes its
behaviours as bus messages stamped with their times, and hands the block here with its timeline. From then
on it asks `due(now)` for the sync points that have passed, and tells this realizer what the audio did
(`speech_started`, `speech_ended`): a speech's sync points are the voice's own (its start when the first
sample is heard, each mark at its offset from there, its end when the audio says so), every other
behaviour's are its schedule's. A block ends when all its sync points have passed and its speech has ended;
an interrupted block (REPLACE, a barge-in, an interrupt) ends at once. Either way its end is reported once.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Literal

FeedbackKind = Literal["blockProgress", "syncPointProgress", "warningFeedback", "predictionFeedback"]
NS = 1_000_000_000


@dataclass(frozen=True)
class Feedback:
    """One feedback element, before it becomes a bus message and the standard's XML."""

    kind: FeedbackKind
    block: str
    behaviour: str = ""
    sync: str = ""  # start/end (blockProgress), the sync point, or the warning's type
    time_s: float = 0.0  # from the block's start
    global_ns: int = 0
    end_ns: int = 0  # predictionFeedback: the block's predicted end
    text: str = ""
    request_id: str = ""


@dataclass
class RunningBlock:
    """A block handed to the realizer: its times on the master clock and what has been reported of it."""

    block_id: str
    request_id: str
    start_ns: int
    times_ns: dict[tuple[str, str], int]  # (behaviour, sync) -> planned master-clock time
    speech: dict[str, str] = field(default_factory=dict)  # speech behaviour -> its say request id
    reported: set[tuple[str, str]] = field(default_factory=set)
    started: bool = False
    ended: bool = False
    speech_start_ns: dict[str, int] = field(default_factory=dict)  # heard start of each speech
    speech_over: set[str] = field(default_factory=set)  # speeches whose audio has ended

    @property
    def planned_end_ns(self) -> int:
        return max(self.times_ns.values(), default=self.start_ns)

    def speech_of(self, behaviour: str) -> bool:
        return behaviour in self.speech


class AgentRealizer:
    """The blocks of one agent, in the order they were handed over."""

    def __init__(self, agent: str, max_blocks: int = 64) -> None:
        self.agent = agent
        self.max_blocks = max_blocks
        self.blocks: list[RunningBlock] = []
        self.ended_ids: dict[str, None] = {}  # block ids lately ended (a later block may refer to them)
        self._ended_times: dict[tuple[str, str, str], int] = {}

    # --- before a block runs ------------------------------------------------------------------------

    def start_for(self, composition: str, now_ns: int) -> int:
        """When a new block may start: now (MERGE, REPLACE: the caller interrupts first), or when everything
        handed over before it has ended (APPEND)."""
        if composition == "APPEND":
            return max([now_ns, *(b.planned_end_ns for b in self.blocks if not b.ended)])
        return now_ns

    def known_times_s(self) -> dict[tuple[str, str, str], float]:
        """(block, behaviour, sync) -> master-clock seconds of every block handed over (running or lately
        ended): what a new block's cross-block references may name."""
        known = {key: t / NS for key, t in self._ended_times.items()}
        for b in self.blocks:
            for (behaviour, sync), t in b.times_ns.items():
                known[(b.block_id, behaviour, sync)] = t / NS
            # the block itself, as `b1:bml:start` and `b1:bml:end` name it (its end as planned, while it runs)
            known[(b.block_id, "bml", "start")] = b.start_ns / NS
            known[(b.block_id, "bml", "end")] = b.planned_end_ns / NS
        return known

    def running_ids(self) -> set[str]:
        return {b.block_id for b in self.blocks if not b.ended}

    def is_taken(self, block_id: str) -> bool:
        return block_id in self.running_ids()

    # --- running ----------------------------------------------------------------------------------

    def begin(self, block_id: str, request_id: str, start_ns: int, times_ns: Mapping[tuple[str, str], int],
              speech: Mapping[str, str]) -> list[Feedback]:
        """Hand over a scheduled block; returns its predictionFeedback."""
        if len(self.running_ids()) >= self.max_blocks:
            raise ValueError(f"agent '{self.agent}' already runs {self.max_blocks} blocks")
        running = RunningBlock(block_id, request_id, start_ns, dict(times_ns), dict(speech))
        self.blocks.append(running)
        return [Feedback("predictionFeedback", block_id, global_ns=start_ns, end_ns=running.planned_end_ns,
                         request_id=request_id)]

    def speech_started(self, say_id: str, heard_ns: int) -> None:
        for b in self.blocks:
            for behaviour, sid in b.speech.items():
                if sid == say_id and behaviour not in b.speech_start_ns:
                    b.speech_start_ns[behaviour] = heard_ns

    def speech_ended(self, say_id: str, heard_ns: int) -> None:
        """The say's audio ended (finished, interrupted or failed) at heard_ns."""
        for b in self.blocks:
            for behaviour, sid in b.speech.items():
                if sid == say_id and behaviour not in b.speech_over:
                    b.speech_over.add(behaviour)
                    b.speech_start_ns.setdefault(behaviour, heard_ns)  # a speech that never played
                    b.times_ns[(behaviour, "end")] = max(heard_ns, b.speech_start_ns[behaviour])

    def block_of_say(self, say_id: str) -> RunningBlock | None:
        for b in self.blocks:
            if not b.ended and say_id in b.speech.values():
                return b
        return None

    def due(self, now_ns: int) -> list[Feedback]:
        """The feedback of everything that has happened by now_ns, in time order, each once."""
        out: list[tuple[int, int, Feedback]] = []
        for b in self.blocks:
            if b.ended:
                continue
            if not b.started and now_ns >= b.start_ns:
                b.started = True
                out.append((b.start_ns, 0, Feedback("blockProgress", b.block_id, sync="start", global_ns=b.start_ns,
                                                     request_id=b.request_id)))
            for (behaviour, sync), t in self._times_now(b).items():
                if (behaviour, sync) not in b.reported and t <= now_ns:
                    b.reported.add((behaviour, sync))
                    out.append((t, 1, Feedback("syncPointProgress", b.block_id, behaviour, sync,
                                               (t - b.start_ns) / NS, t, request_id=b.request_id)))
            if b.started and len(b.reported) == len(b.times_ns) and set(b.speech) <= b.speech_over:
                end = max([b.start_ns, *self._times_now(b).values()])
                out.append((end, 2, self._end(b, end)))
        out.sort(key=lambda item: (item[0], item[1]))
        self._forget_ended()
        return [feedback for _, _, feedback in out]

    def interrupt(self, now_ns: int, reason: str, block_ids: Iterable[str] | None = None) -> list[Feedback]:
        """End the named running blocks (all when None) at now_ns: their end, once each, with the reason."""
        wanted = None if block_ids is None else set(block_ids)
        out = []
        for b in self.blocks:
            if b.ended or (wanted is not None and b.block_id not in wanted):
                continue
            if not b.started:
                b.started = True
                out.append(Feedback("blockProgress", b.block_id, sync="start", global_ns=now_ns,
                                    request_id=b.request_id))
            out.append(self._end(b, now_ns, reason))
        self._forget_ended()
        return out

    def _times_now(self, b: RunningBlock) -> dict[tuple[str, str], int]:
        """The block's times as known now: a speech's own points move with its heard start; a speech that has
        not started (or not ended) yet has its start (or end) held back until the audio says."""
        times = {}
        for (behaviour, sync), t in b.times_ns.items():
            if behaviour in b.speech:
                heard = b.speech_start_ns.get(behaviour)
                if heard is None:
                    continue  # not heard yet: none of its points has happened
                if sync == "end":
                    if behaviour not in b.speech_over:
                        continue
                else:
                    t = heard + (t - b.times_ns[(behaviour, "start")])
            times[(behaviour, sync)] = t
        return times

    def _end(self, b: RunningBlock, t_ns: int, reason: str = "") -> Feedback:
        b.ended = True
        for (behaviour, sync), t in b.times_ns.items():
            self._ended_times[(b.block_id, behaviour, sync)] = t
        self._ended_times[(b.block_id, "bml", "start")] = b.start_ns
        self._ended_times[(b.block_id, "bml", "end")] = t_ns
        self.ended_ids[b.block_id] = None
        return Feedback("blockProgress", b.block_id, sync="end", time_s=(t_ns - b.start_ns) / NS, global_ns=t_ns,
                        text=reason, request_id=b.request_id)

    def _forget_ended(self) -> None:
        self.blocks = [b for b in self.blocks if not b.ended]
        while len(self.ended_ids) > self.max_blocks:  # the references a later block may still make, bounded
            gone = next(iter(self.ended_ids))
            del self.ended_ids[gone]
            self._ended_times = {k: v for k, v in self._ended_times.items() if k[0] != gone}
