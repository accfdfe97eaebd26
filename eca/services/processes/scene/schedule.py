"""When each frame is drawn, on an injected clock: fixed slots that keep real time.

Slot k is due at t0 + k / fps and composed for that time plus a display lead (a window shows a frame
some time after it is drawn). A slot the loop could not reach in time is skipped rather than delaying
every later frame, so the face stays on time when drawing falls behind; skipped slots are counted in
`dropped`. An optional total number of slots ends the schedule (the length of a video). A drawer that
must show a change at once may draw the next slot early (`early_due_ns`).
"""

from __future__ import annotations

from collections.abc import Callable

from eca.agent.clock import NS_PER_S, Clock


class FrameSchedule:
    """Frame slots at `fps` from the clock's time at construction, or from `t0_ns` (the first slot then
    the first at or after the clock's time: t0_ns=0 puts the slots on a grid of the clock itself).

    `on_advance(n)` is told each time the schedule moves on by n slots (drawn and skipped together),
    for a progress bar."""

    def __init__(self, clock: Clock, fps: float, *, lead_s: float = 0.0, total: int | None = None,
                 on_advance: Callable[[int], None] | None = None, t0_ns: int | None = None) -> None:
        self.clock = clock
        self.total = total
        self.on_advance = on_advance
        now = clock.now_ns()
        self.t0_ns = now if t0_ns is None else t0_ns
        self.lead_ns = round(lead_s * 1e9)
        # Slot times in integer milli-frames per second: exact at fractional rates (29.97), no drift.
        self._mfps = round(fps * 1000)
        self.slot = max(0, -(-(now - self.t0_ns) * self._mfps // (NS_PER_S * 1000)))  # the next slot to draw
        self.dropped = 0  # slots skipped because drawing fell behind

    def slot_ns(self, k: int) -> int:
        """When slot k is due."""
        return self.t0_ns + (k * NS_PER_S * 1000) // self._mfps

    @property
    def period_ns(self) -> int:
        """One frame period (rounded to the ns)."""
        return (NS_PER_S * 1000) // self._mfps

    @property
    def due_ns(self) -> int:
        """When the next slot is due."""
        return self.slot_ns(self.slot)

    @property
    def display_ns(self) -> int:
        """The display time the next slot's frame is composed for."""
        return self.due_ns + self.lead_ns

    def early_due_ns(self, last_frame_ns: int, min_gap: float) -> int:
        """When the next slot may be drawn ahead of its time, to show a change at once: once the slot
        before it is due, `min_gap` of a period after the last frame drawn (`last_frame_ns`), and never
        later than the slot itself. The slot drawn early is that slot (`advance` moves on to the next
        one), so however often this is used, no more than one frame comes per period."""
        earliest = max(self.slot_ns(self.slot - 1), last_frame_ns + round(min_gap * self.period_ns))
        return min(self.due_ns, earliest)

    @property
    def finished(self) -> bool:
        return self.total is not None and self.slot >= self.total

    def advance(self) -> int:
        """Move on from the slot just drawn to the next one that can still be reached in time; returns
        how many slots were skipped on the way."""
        nxt = self.slot + 1
        latest = (self.clock.now_ns() - self.t0_ns) * self._mfps // (NS_PER_S * 1000)
        skipped = 0
        if latest > nxt:  # drawing fell behind by more than a frame: skip to the current slot
            skipped = latest - nxt
            nxt = latest
        if self.total is not None:
            nxt = min(nxt, self.total)
        if self.on_advance is not None:
            self.on_advance(nxt - self.slot)
        self.slot = nxt
        self.dropped += skipped
        return skipped
