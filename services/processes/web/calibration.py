"""The web service's calibration mode: a stream whose picture and sound are in step at their source.

A page measuring how far apart a browser presents the face and the voice needs a reference that it
knows to be aligned where it leaves the server: a white flash in the video at exactly the master-clock
time of a click in the audio. An offer with `"calibration": true` gets, for each section it receives,
one of these synthetic tracks instead of the agent's face or voice:

- video: a picture for every frame slot of the master clock (slot k at k/fps s; at a whole-number rate
  every whole second is a slot): the agent's face as last drawn, with a patch in its top left corner
  (`PATCH`) that is white for the slot nearest each whole second (the one at it; of two equally near,
  the earlier) and black for the others;
- audio: silence with a click (a 10 ms burst of a 1 kHz tone, starting at phase zero) at each whole
  second.

They are the face's and the voice's own track classes (services/processes/web/tracks.py) reading synthetic
feeds, so the reference is timed, stamped, encoded and sent as the agent is: each picture is handed to
its encoder so that it leaves when its slot comes (the face's pictures are stamped with the time they
will leave, drawn and encoded), and the voice track takes 20 ms of samples when the first of them is due
at the output. Whatever the reference's offset is in the browser, the server, encoders, network and
browser made it; the face's offset beyond that is the face's own, to within what separate connections
differ by (a browser settles each one's A/V sync on its own: bench/web.py runs two references to see how
far). The service still draws the agent for such a viewer, so the reference is measured under the face's
load. A reference's video is encoded for its viewer alone.

The patch is on the moving face rather than on a flat picture because a browser treats the two unlike:
it holds the pictures of a stream whose frames are large and slow to decode longer before showing them
(its jitter estimate grows with frame size, its render delay with decode time), and its A/V sync leaves
differences under about 30 ms alone. Flat flashes were shown 20-30 ms sooner after leaving the server
than the face's pictures, which made the reference unlike what it stands beside.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable

import numpy as np

from agent.clock import NS_PER_S, Clock
from services.processes.web.encoding import EncodedStream
from services.processes.web.feeds import FrameFeed, Picture, VoiceFeed
from services.processes.web.tracks import FaceTrack, VoiceTrack

CLICK_S = 0.010
CLICK_HZ = 1_000.0
CLICK_LEVEL = 0.5  # of full scale: loud, never clipped by Opus
# video range (BT.601) luma and neutral chroma: what a browser shows as full white and full black
WHITE_LUMA, BLACK_LUMA, NEUTRAL_CHROMA = 235, 16, 128
PATCH = (0.0, 0.0, 0.25, 0.25)  # x0, y0, x1, y1 of the picture: the flashing patch, over the background


def solid_yuv(width: int, height: int, luma: int) -> np.ndarray:
    """A grey picture as yuv420p planes stacked the way av.VideoFrame.from_ndarray takes them."""
    yuv = np.full((height * 3 // 2, width), NEUTRAL_CHROMA, dtype=np.uint8)
    yuv[:height] = luma
    return yuv


def with_patch(picture: Picture, luma: int) -> np.ndarray:
    """A copy of the picture's yuv420p planes with the `PATCH` part grey at `luma` (even pixel bounds,
    so the patch covers whole chroma samples)."""
    width, height = picture.width, picture.height
    x0, y0, x1, y1 = (2 * round(f * n / 2) for f, n in zip(PATCH, (width, height, width, height), strict=True))
    yuv = picture.yuv.copy()
    flat = yuv.reshape(-1)
    flat[:width * height].reshape(height, width)[y0:y1, x0:x1] = luma
    chroma = (width // 2) * (height // 2)
    for first in (width * height, width * height + chroma):  # the U plane, then the V plane
        flat[first:first + chroma].reshape(height // 2, width // 2)[y0 // 2:y1 // 2, x0 // 2:x1 // 2] = NEUTRAL_CHROMA
    return yuv


class FlashFeed(FrameFeed):
    """A picture per frame slot of the master clock, its patch white at the whole seconds, black otherwise.

    The picture under the patch is `backdrop()`'s (the agent's face as last drawn), or black while there
    is none. Slot k is at k·1000/(1000·fps) s of the clock, in integer milli-frames per second as the
    service's own frame schedule counts them (services/processes/renderer/schedule.py), so at a
    whole-number rate every whole second is exactly a slot."""

    def __init__(self, clock: Clock, width: int, height: int, fps: float,
                 backdrop: Callable[[], Picture | None] = lambda: None) -> None:
        super().__init__()
        self.clock = clock
        self.width, self.height = width, height
        self.backdrop = backdrop
        self._mfps = round(fps * 1000)
        self._black = Picture(0, solid_yuv(width, height, BLACK_LUMA), width, height)
        self.lead_ns: Callable[[], int] = lambda: 0  # how long before its slot a picture is given out

    def slot_ns(self, k: int) -> int:
        return k * NS_PER_S * 1000 // self._mfps

    def slot_at_or_before(self, t_ns: int) -> int:
        """The last slot k with slot_ns(k) <= t_ns."""
        return ((t_ns + 1) * self._mfps - 1) // (NS_PER_S * 1000)

    def is_flash(self, k: int) -> bool:
        """Whether slot k is the one for a whole second S: the slot in [S - half a period, S + half a
        period), exactly one a second (in integer arithmetic on the exact slot times, k / fps s)."""
        slot = k * NS_PER_S * 1000  # the slot's exact time, times the milli-frame rate
        per_second = NS_PER_S * self._mfps
        half_period = NS_PER_S * 1000 // 2
        second = (slot + half_period) // per_second
        return slot - second * per_second < half_period

    def picture(self, k: int) -> Picture:
        """Slot k's picture, at the backdrop's size (the encoder scales it to the stream's)."""
        under = self.backdrop() or self._black
        luma = WHITE_LUMA if self.is_flash(k) else BLACK_LUMA
        return Picture(self.slot_ns(k), with_patch(under, luma), under.width, under.height)

    async def next_after(self, agent: str, frame_ns: int, early_after_ns: int | None = None) -> Picture:
        """The newest slot's picture once its time has come (less the lead), like a face drawn for that
        slot: the current slot if it is after `frame_ns` (a stream that fell behind skips to it), else
        the next slot after `frame_ns`, when it is due."""
        lead = self.lead_ns()
        now = self.clock.now_ns()
        k = max(self.slot_at_or_before(now + lead), self.slot_at_or_before(frame_ns) + 1)
        wait_ns = self.slot_ns(k) - lead - now
        if wait_ns > 0:
            await asyncio.sleep(wait_ns / 1e9)  # pacing to the master clock, not synchronisation
        return self.picture(k)

    def put(self, agent: str, picture: Picture) -> None:
        raise TypeError("a flash feed makes its own pictures")


class ClickFeed(VoiceFeed):
    """Silence with a click at each whole second of the master clock, for any span a track takes."""

    def __init__(self, sample_rate: int = 48_000) -> None:
        super().__init__(sample_rate)
        t = np.arange(round(CLICK_S * sample_rate)) / sample_rate
        self.click = np.round(CLICK_LEVEL * 32767 * np.sin(2 * np.pi * CLICK_HZ * t)).astype(np.int16)

    def add(self, dac_time_ns: int, samples: np.ndarray, sample_rate: int) -> None:
        raise TypeError("a click feed makes its own samples")

    def take(self, start_ns: int, count: int) -> np.ndarray:
        out = np.zeros(count, dtype=np.int16)
        rate = self.sample_rate
        end_ns = start_ns + count * NS_PER_S // rate
        first_second = -(-(start_ns - len(self.click) * NS_PER_S // rate) // NS_PER_S)  # clicks that reach the span
        for second in range(first_second, end_ns // NS_PER_S + 1):
            # positions in samples from start_ns, rounded to the nearest sample as the voice's are
            offset = round((second * NS_PER_S - start_ns) * rate / 1e9)
            lo, hi = max(0, offset), min(count, offset + len(self.click))
            if lo < hi:
                out[lo:hi] = self.click[lo - offset:hi - offset]
        return out


def flash_track(clock: Clock, width: int, height: int, fps: float,
                backdrop: Callable[[], Picture | None] = lambda: None) -> FaceTrack:
    """The reference's video: the flashing patch over `backdrop()` (the agent's face as last drawn),
    encoded for this viewer alone."""
    feed = FlashFeed(clock, width, height, fps, backdrop)
    stream = EncodedStream(feed.next_after, "calibration", width, height, fps, clock)
    feed.lead_ns = lambda: stream.encode_ns  # a picture leaves when its slot comes, as the face's do
    stream.start()
    return FaceTrack(stream, on_stop=stream.stop)


def click_track(clock: Clock) -> VoiceTrack:
    """The reference's audio: a voice track reading clicks instead of the agent's voice."""
    return VoiceTrack(ClickFeed(), clock)
