"""The web service's calibration mode: the agent with markers whose picture and sound are in step at their source.

A page measuring how far apart a browser presents the face and the voice needs a reference that it
knows to be aligned where it leaves the server: a white flash in the video at exactly the master-clock
time of a click in the audio. An offer with `"calibration": true` gets the agent's face and voice with
these markers on them, for each section it receives:

- video: each of the agent's pictures as drawn for every viewer (the same times, the same content), with
  a patch in its top left corner (`PATCH`) that is white on the picture for a whole second of the master
  clock and black on the others. The service draws its frames at k / fps of the master clock, so at a
  whole-number rate every whole second has one (unless it was skipped, or drawn early to show a
  command: that second has no flash);
- audio: the agent's voice with a click (a 10 ms burst of a 1 kHz tone, starting at phase zero) added at
  each whole second.

They are the face's and the voice's own track classes (services/processes/web/tracks.py) reading these
feeds, so the markers are timed, stamped, encoded and sent as the agent is. Whatever the markers' offset
is in the browser, the server, encoders, network and browser made it; the face's offset beyond that, on
the same connection, is the face's own: its lip-sync and how its pictures are composed.

Both on one connection, because a browser settles each connection's A/V sync on its own and leaves
differences under about 30 ms alone (libwebrtc's stream synchronization): two connections of identical
streams were seen to settle up to 33 ms apart, so a reference on a connection of its own says little
about the face's. On one connection the face and the markers share the browser's jitter buffers, decoder
and sync. The markers are on the face's own pictures, not on flat ones of their own, because a browser
also holds the pictures of a stream whose frames are large and slow to decode longer before showing them:
flat flashes were shown 20-30 ms sooner after leaving the server than the face's pictures.

The pictures with the patch are encoded for their viewer alone.
"""

from __future__ import annotations

import numpy as np

from eca.agent.clock import NS_PER_S, Clock
from eca.services.processes.web.encoding import EncodedStream
from eca.services.processes.web.feeds import FrameFeed, Picture, VoiceFeed
from eca.services.processes.web.tracks import FaceTrack, VoiceTrack

CLICK_S = 0.010
CLICK_HZ = 1_000.0
CLICK_LEVEL = 0.5  # of full scale: loud, never clipped by Opus
# video range (BT.601) luma and neutral chroma: what a browser shows as full white and full black
WHITE_LUMA, BLACK_LUMA, NEUTRAL_CHROMA = 235, 16, 128
PATCH = (0.0, 0.0, 0.25, 0.25)  # x0, y0, x1, y1 of the picture: the flashing patch, over the background


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


class FlashFeed:
    """The agent's pictures from `faces`, each with the patch: white on the one for a whole second of the
    master clock, black on the others."""

    def __init__(self, faces: FrameFeed) -> None:
        self.faces = faces

    async def next_after(self, agent: str, frame_ns: int, early_after_ns: int | None = None) -> Picture:
        """The agent's next picture, as the face's own stream would take it, with the patch on."""
        face = await self.faces.next_after(agent, frame_ns, early_after_ns)
        luma = WHITE_LUMA if face.frame_ns % NS_PER_S == 0 else BLACK_LUMA
        return Picture(face.frame_ns, with_patch(face, luma), face.width, face.height, face.early)


class ClickFeed:
    """The voice of `under` (silence without one) with a click added at each whole second of the master
    clock, for any span a track takes; where both are loud the sum is clipped to the sample range."""

    def __init__(self, under: VoiceFeed | None = None, sample_rate: int = 48_000) -> None:
        if under is not None and under.sample_rate != sample_rate:
            raise ValueError(f"clicks at {sample_rate} Hz over a voice at {under.sample_rate} Hz")
        self.under = under
        self.sample_rate = sample_rate
        t = np.arange(round(CLICK_S * sample_rate)) / sample_rate
        self.click = np.round(CLICK_LEVEL * 32767 * np.sin(2 * np.pi * CLICK_HZ * t)).astype(np.int16)

    def take(self, start_ns: int, count: int) -> np.ndarray:
        out = self._clicks_in(start_ns, count)
        if self.under is None:
            return out
        mixed = self.under.take(start_ns, count).astype(np.int32) + out
        return np.clip(mixed, -32768, 32767).astype(np.int16)

    def _clicks_in(self, start_ns: int, count: int) -> np.ndarray:
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


def flash_track(clock: Clock, faces: FrameFeed, agent: str, width: int, height: int, fps: float) -> FaceTrack:
    """The agent's face with the flashing patch, encoded for this viewer alone."""
    stream = EncodedStream(FlashFeed(faces).next_after, agent, width, height, fps, clock)
    stream.start()
    return FaceTrack(stream, on_stop=stream.stop)


def click_track(clock: Clock, voice: VoiceFeed) -> VoiceTrack:
    """The agent's voice with the clicks."""
    return VoiceTrack(ClickFeed(voice, voice.sample_rate), clock)
