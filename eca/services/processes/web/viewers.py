"""The browsers watching: one WebRTC peer connection each, with its face and voice tracks and, when the
page sends one, its microphone.

A viewer's tracks take from the service's shared feeds: the face is drawn once per frame, and encoded
once for all the viewers who asked the same size and rate (services/processes/web/encoding.py), whatever
their number; each viewer's own encoder encodes the voice. A viewer that leaves, fails, does not
connect within `connect_timeout_s`, or stops answering (no receiver report nor anything else for `silent_timeout_s`:
a browser that vanished mid-call, which ICE itself notices only after about 30 s) is closed and
forgotten: its peer connection, its encoders, its microphone and its place in what the service draws.
"""

from __future__ import annotations

import asyncio
import itertools
import logging
from dataclasses import dataclass, field
from datetime import datetime
from typing import Protocol

from aiortc import MediaStreamTrack, RTCDataChannel, RTCPeerConnection, RTCRtpSender, RTCSessionDescription
from aiortc.mediastreams import MediaStreamError
from aiortc.rtcpeerconnection import or_direction

from eca.agent.clock import Clock
from eca.protocol.messages import Message, UserAudio, UserSpeech
from eca.services.processes.web.browser_face import ntp_ms, pack_voice_clock
from eca.services.processes.web.calibration import click_track, flash_track
from eca.services.processes.web.encoding import EncodedStreams
from eca.services.processes.web.face_frames import next_due_ns
from eca.services.processes.web.feeds import FrameFeed, VoiceFeed
from eca.services.processes.web.ice import IceSettings
from eca.services.processes.web.ice_gathering import configuration, gathering
from eca.services.processes.web.mic_decoding import DecodeOnLoop, decode_on_loop
from eca.services.processes.web.microphone import MicBlock, Microphone
from eca.services.processes.web.options import VadSettings
from eca.services.processes.web.tracks import FaceTrack, VoiceTiming, VoiceTrack

log = logging.getLogger("web")

FACE_CHANNEL = "eca-face"  # the data channel a page opens for the frames of the faces it draws
MAX_REFUSED_CHANNELS = 16  # a page that opens more channels than this, besides its face channel, is closed
MAX_PAGE_MESSAGES = 64  # messages a page sends on its face channel (it has nothing to say) before it is closed
MAX_BUFFERED_BYTES = 64 * 1024  # a face channel holding more unsent than this skips frames until it drains
VOICE_CLOCK_EVERY_S = 0.25
MIC_IDLE_CHECK_S = 0.1  # how often a microphone that sends nothing (discontinuous transmission) is looked at
FIRST_PICTURE_WAIT_S = 60.0  # the longest a viewer's silence is not counted while its first picture is drawn


@dataclass(frozen=True)
class ViewRequest:
    """What one page asked for, already checked against the limits (services/processes/web/server.py)."""

    agents: tuple[str, ...]
    width: int
    height: int
    fps: float
    streams: tuple[tuple[str, str, str], ...]  # (mid, agent, "video" | "audio") for each media section it receives
    mic_mid: str | None  # the section its microphone comes in, if it sends one
    calibration: bool = False  # the agents with flashes and clicks on them (web/calibration.py)
    drawn_here: tuple[str, ...] = ()  # the agents the page draws itself (face frames on its data channel)


class Backend(Protocol):
    """What the viewers need of the service (called from the event loop; thread-safe)."""

    clock: Clock
    encoded: EncodedStreams
    frames: FrameFeed

    def voice(self, agent: str) -> VoiceFeed: ...

    def face_slot(self, agent: str) -> int: ...

    def expect_viewer(self) -> None: ...

    def watch(self, viewer: int, request: ViewRequest) -> None: ...

    def unwatch(self, viewer: int) -> None: ...

    def submit(self, msg: Message) -> None: ...


@dataclass
class Viewer:
    number: int
    pc: RTCPeerConnection
    request: ViewRequest
    tracks: list[MediaStreamTrack] = field(default_factory=list)
    mic_task: asyncio.Task[None] | None = None
    mic_decoding: DecodeOnLoop | None = None  # its microphone decoded on the event loop (web/mic_decoding.py)
    watchdog: asyncio.Future[None] | None = None
    closed: bool = False
    channel: RTCDataChannel | None = None  # its face channel, once the page opened it
    refused_channels: int = 0
    page_messages: int = 0
    frames_sent: int = 0
    frames_skipped: int = 0  # face frames not sent while its channel was full
    voice_senders: dict[str, RTCRtpSender] = field(default_factory=dict)  # of the agents the page draws
    clock_task: asyncio.Task[None] | None = None
    next_frame_ns: int = -(1 << 62)  # when the page's next face frame is due, at the rate it asked


class Viewers:
    def __init__(self, backend: Backend, max_viewers: int, vad: VadSettings, connect_timeout_s: float = 15.0,
                 silent_timeout_s: float = 10.0, ice: IceSettings | None = None) -> None:
        self.backend = backend
        self.ice = ice or IceSettings()  # STUN/TURN servers and the interfaces offered (web/ice.py)
        self.max_viewers = max_viewers
        self.vad = vad
        self.connect_timeout_s = connect_timeout_s
        self.silent_timeout_s = silent_timeout_s
        self.open: dict[int, Viewer] = {}
        self._numbers = itertools.count(1)
        self.voice_timing = VoiceTiming()  # every viewer's voice: how late its frames leave (GET /health)

    @property
    def full(self) -> bool:
        return len(self.open) >= self.max_viewers

    async def answer(self, offer_sdp: str, request: ViewRequest) -> str:
        """Open a viewer for an offer; its answer's SDP. ValueError (with a sentence for the page) when the
        offer cannot be answered; nothing is left open then."""
        number = next(self._numbers)
        viewer = Viewer(number, RTCPeerConnection(configuration(self.ice)), request)
        self.open[number] = viewer
        try:
            _offer_vp8_only(viewer.pc, sum(kind == "video" for _, _, kind in request.streams))
            await viewer.pc.setRemoteDescription(RTCSessionDescription(sdp=offer_sdp, type="offer"))
            self._attach(viewer)
            with gathering(self.ice):  # the answer's candidates are gathered here
                await viewer.pc.setLocalDescription(await viewer.pc.createAnswer())
        except Exception as exc:  # aiortc's SDP parser raises many types on a malformed offer
            await self.close(viewer)
            raise ValueError(f"the offer could not be answered: {_plain(exc)}") from None
        self.backend.watch(number, request)
        viewer.pc.on("connectionstatechange", lambda: self._on_state(viewer))
        viewer.pc.on("datachannel", lambda channel: self._on_channel(viewer, channel))
        asyncio.get_running_loop().call_later(self.connect_timeout_s, self._check_connected, viewer)
        log.info("viewer %d: %s at %dx%d, %g fps%s%s", number, ", ".join(request.agents), request.width,
                 request.height, request.fps, ", with a microphone" if request.mic_mid else "",
                 ", with calibration flashes and clicks" if request.calibration else "")
        answer = viewer.pc.localDescription.sdp
        return ask_dtx(answer, request.mic_mid) if request.mic_mid is not None else answer

    def _attach(self, viewer: Viewer) -> None:
        request, backend = viewer.request, self.backend
        by_mid = {t.mid: t for t in viewer.pc.getTransceivers()}
        for mid, agent, kind in request.streams:
            transceiver = by_mid.get(mid)
            if transceiver is None or transceiver.kind != kind:
                raise ValueError(f"the offer has no {kind} section with mid {mid!r}")
            track: MediaStreamTrack
            if kind == "video":
                track = (flash_track(backend.clock, backend.frames, agent, request.width, request.height, request.fps)
                         if request.calibration else self._face_track(agent, request))
                _forward_keyframe_requests(transceiver.sender, track)
            else:
                voice = backend.voice(agent)
                # a page drawing this agent's face follows the voice's clock, not a continuous stream: its voice
                # pauses in silence
                track = (click_track(backend.clock, voice) if request.calibration
                         else VoiceTrack(voice, backend.clock, pause_in_silence=agent in request.drawn_here,
                                         timing=self.voice_timing))
            transceiver.sender.replaceTrack(track)
            if kind == "audio" and agent in request.drawn_here:
                viewer.voice_senders[agent] = transceiver.sender
            transceiver.direction = or_direction(transceiver.direction, "sendonly")
            # one media stream per agent (its msid): the browser lines up the voice with the face it
            # belongs to, not with another agent's
            transceiver.sender._stream_id = f"eca-{agent}"
            viewer.tracks.append(track)
        if request.mic_mid is not None:
            transceiver = by_mid.get(request.mic_mid)
            if transceiver is None or transceiver.kind != "audio":
                raise ValueError(f"the offer has no audio section with mid {request.mic_mid!r} for the microphone")
            viewer.mic_decoding = decode_on_loop(transceiver.receiver)
            viewer.mic_task = asyncio.ensure_future(self._listen(viewer, transceiver.receiver.track))

    def _face_track(self, agent: str, request: ViewRequest) -> FaceTrack:
        """A track of the agent's face stream at the asked size and rate, shared with the other viewers
        who asked the same; the stream goes when the last of its tracks stops."""
        encoded = self.backend.encoded
        stream = encoded.use(agent, request.width, request.height, request.fps)
        return FaceTrack(stream, on_stop=lambda: encoded.release(stream))

    async def _listen(self, viewer: Viewer, track: MediaStreamTrack) -> None:
        """The viewer's microphone: blocks and turns onto the bus, for the agents it watches."""
        agents = viewer.request.agents
        source = f"viewer-{viewer.number}"
        submit, clock = self.backend.submit, self.backend.clock

        def on_block(block: MicBlock) -> None:
            submit(UserAudio(agent=agents[0], first_sample=block.first_sample, capture_time_ns=block.capture_ns,
                             pcm=block.pcm, speaking=block.speaking, source_id=source))

        def on_turn(speaking: bool) -> None:
            log.info("viewer %d: the user %s speaking", viewer.number, "started" if speaking else "stopped")
            for agent in agents:
                submit(UserSpeech(agent=agent, speaking=speaking))

        mic = Microphone(on_block, on_turn, self.vad)

        async def idle() -> None:
            while not viewer.closed:
                await asyncio.sleep(MIC_IDLE_CHECK_S)  # a periodic look: a silent browser sends nothing
                mic.idle(clock.now_ns())

        idler = asyncio.ensure_future(idle())
        try:
            while not viewer.closed:
                frame = await track.recv()
                mic.push(frame, clock.now_ns())
        except MediaStreamError:
            pass  # the browser stopped sending
        finally:
            idler.cancel()
            if mic.speaking:
                on_turn(False)  # a viewer who leaves mid-sentence has stopped speaking

    def _on_channel(self, viewer: Viewer, channel: RTCDataChannel) -> None:
        """A data channel the page opened: its face channel is kept (when it draws a face), any other closed;
        a page that keeps opening them is closed."""
        if channel.label == FACE_CHANNEL and viewer.channel is None and viewer.request.drawn_here:
            viewer.channel = channel
            channel.on("message", lambda message: self._on_page_message(viewer, message))
            viewer.clock_task = asyncio.ensure_future(self._send_voice_clocks(viewer, channel))
            return
        channel.close()
        viewer.refused_channels += 1
        if viewer.refused_channels == 1:
            log.info("viewer %d: refused a data channel %r (only one %r channel, for a face the page draws)",
                     viewer.number, str(channel.label)[:40], FACE_CHANNEL)
        if viewer.refused_channels > MAX_REFUSED_CHANNELS:
            log.info("viewer %d: opened %d data channels; closing it", viewer.number, viewer.refused_channels)
            asyncio.ensure_future(self.close(viewer))

    async def _send_voice_clocks(self, viewer: Viewer, channel: RTCDataChannel) -> None:
        """What each voice sender's RTCP sender reports say (an RTP timestamp and when it left), on the face
        channel a few times a second: a page cannot read the reports its browser receives, and lines the frames
        up with the voice it plays by them (browser_face.py)."""
        slots = {agent: self.backend.face_slot(agent) for agent in viewer.voice_senders}
        sent: dict[str, int] = {}
        while not viewer.closed:
            if channel.readyState == "open" and viewer.pc.connectionState == "connected":
                for agent, sender in viewer.voice_senders.items():
                    rtp, ntp = _last_sent(sender)
                    if ntp and ntp != sent.get(agent):
                        channel.send(pack_voice_clock(slots[agent], rtp, ntp_ms(ntp)))
                        sent[agent] = ntp
            await asyncio.sleep(VOICE_CLOCK_EVERY_S)  # a periodic report, not synchronisation

    def _on_page_message(self, viewer: Viewer, message: object) -> None:
        """The face channel carries frames to the page only: what a page sends on it is dropped (counted), and a
        page that keeps sending is closed."""
        viewer.page_messages += 1
        if viewer.page_messages == 1:
            size = len(message) if isinstance(message, str | bytes) else 0
            log.info("viewer %d: dropped a message of %d bytes on its face channel (it takes none)", viewer.number,
                     size)
        if viewer.page_messages > MAX_PAGE_MESSAGES and not viewer.closed:
            log.info("viewer %d: sent %d messages on its face channel; closing it", viewer.number,
                     viewer.page_messages)
            asyncio.ensure_future(self.close(viewer))

    def send_face_frames(self, frames: dict[str, bytes], frame_ns: int, early: bool = False) -> None:
        """One frame slot's face frames to every page that draws those agents (on the event loop's thread), at
        the rate each asked (the slots come at the fastest asked; a frame drawn early for a commanded change
        goes to all). A channel that has not drained (a slow page, a congested link) skips frames instead of
        queueing them: each frame is whole in itself."""
        for viewer in list(self.open.values()):
            channel = viewer.channel
            # a connection going away: aiortc would queue the frame and fail sending it in a task of its own
            if channel is None or channel.readyState != "open" or viewer.pc.connectionState != "connected":
                continue
            if not early:
                due_ns = next_due_ns(viewer.next_frame_ns, frame_ns, viewer.request.fps)
                if due_ns is None:
                    continue
                viewer.next_frame_ns = due_ns
            for agent in viewer.request.drawn_here:
                data = frames.get(agent)
                if data is None:
                    continue
                if channel.bufferedAmount > MAX_BUFFERED_BYTES:
                    viewer.frames_skipped += 1
                    continue
                channel.send(data)
                viewer.frames_sent += 1

    def _on_state(self, viewer: Viewer) -> None:
        state = viewer.pc.connectionState
        if state in ("failed", "closed"):
            asyncio.ensure_future(self.close(viewer))
        elif state == "connected" and viewer.watchdog is None:
            viewer.watchdog = asyncio.ensure_future(self._watch_answers(viewer))

    async def _watch_answers(self, viewer: Viewer) -> None:
        """Close the viewer when it stops answering: no receiver report on any stream it receives and nothing
        else from it on the connection (its microphone, the acknowledgements of its face frames). Every stream
        counts: Chromium reports on video every 0.2-1 s but on audio only every 2.5-7.5 s (libwebrtc's 5 s +-
        50 %), so watching one audio stream alone closed healthy pages; and a voice that pauses in silence (to a
        page that draws the face) gets no reports while it pauses, but its page acknowledges the frames."""
        loop = asyncio.get_running_loop()
        # A face drawn here starts once drawing is ready, which the first page of an instance at rest waits for
        # (a GL context and the faces' first frames, a second or more): the silence is counted from its first
        # picture, not from before it could come (at most FIRST_PICTURE_WAIT_S).
        faces = [t for t in viewer.tracks if isinstance(t, FaceTrack)]
        started = loop.time()
        while faces and not any(t.sent for t in faces) and loop.time() - started < FIRST_PICTURE_WAIT_S:
            if viewer.closed:
                return
            await asyncio.sleep(0.1)  # a look at the tracks' counters, not synchronisation
        last = loop.time()
        seen: dict[int, datetime] = {}
        received: dict[str, int] = {}  # per transport, the datagrams it has received
        senders = [t.sender for t in viewer.pc.getTransceivers() if t.sender.track is not None]
        while not viewer.closed:
            await asyncio.sleep(1.0)  # a periodic look, not synchronisation
            answered = False
            for k, sender in enumerate(senders):
                stats = list((await sender.getStats()).values())
                stamps = [s.timestamp for s in stats if s.type == "remote-inbound-rtp"]
                if stamps and stamps[0] != seen.get(k):
                    seen[k] = stamps[0]
                    answered = True
                for s in stats:
                    if s.type == "transport" and s.packetsReceived != received.get(s.id):
                        received[s.id] = s.packetsReceived
                        answered = True
            if answered:
                last = loop.time()
            elif loop.time() - last > self.silent_timeout_s:
                log.info("viewer %d: no answer for %g s; closing it", viewer.number, self.silent_timeout_s)
                await self.close(viewer)

    def _check_connected(self, viewer: Viewer) -> None:
        if not viewer.closed and viewer.pc.connectionState != "connected":
            log.info("viewer %d: not connected after %g s; closing it", viewer.number, self.connect_timeout_s)
            asyncio.ensure_future(self.close(viewer))

    async def close(self, viewer: Viewer) -> None:
        if viewer.closed:
            return
        viewer.closed = True
        self.open.pop(viewer.number, None)
        self.backend.unwatch(viewer.number)
        for track in viewer.tracks:
            track.stop()
        if viewer.channel is not None:
            viewer.channel.close()
        for task in (viewer.mic_task, viewer.watchdog, viewer.clock_task):
            if task is not None and task is not asyncio.current_task():
                task.cancel()
        await viewer.pc.close()
        log.info("viewer %d left (%d watching)", viewer.number, len(self.open))

    def close_watching(self, agent: str) -> None:
        """Close every viewer that watches `agent` (its conversation ended; on the event loop)."""
        for viewer in list(self.open.values()):
            if agent in viewer.request.agents:
                asyncio.ensure_future(self.close(viewer))

    async def close_all(self) -> None:
        for viewer in list(self.open.values()):
            await self.close(viewer)


def _offer_vp8_only(pc: RTCPeerConnection, video_sections: int) -> None:
    """Make the answer send VP8 in each video section: the face streams are VP8, encoded once for every
    viewer. aiortc gives a browser's offer the transceivers that already exist (in order) before it
    makes new ones, so the video sections get these, whose codecs are set before the offer is read."""
    vp8 = [c for c in RTCRtpSender.getCapabilities("video").codecs if c.mimeType.lower() in ("video/vp8", "video/rtx")]
    for _ in range(video_sections):
        pc.addTransceiver("video", direction="sendonly").setCodecPreferences(vp8)


def _forward_keyframe_requests(sender: RTCRtpSender, track: FaceTrack) -> None:
    """A browser's request for a keyframe (PLI, FIR) reaches aiortc's sender, which would have its own
    encoder make one; the face's encoder is the shared stream's, so the request goes on to it."""
    ask_encoder = sender._send_keyframe

    def send_keyframe() -> None:
        ask_encoder()
        track.stream.request_keyframe()

    sender._send_keyframe = send_keyframe  # type: ignore[method-assign]


def _last_sent(sender: RTCRtpSender) -> tuple[int, int]:
    """(RTP timestamp, NTP time) of the last packet `sender` sent, what its next RTCP sender report carries
    (aiortc keeps them private: read by their mangled names; (0, 0) if a version renames them)."""
    rtp = getattr(sender, "_RTCRtpSender__rtp_timestamp", 0)
    ntp = getattr(sender, "_RTCRtpSender__ntp_timestamp", 0)
    return (rtp, ntp) if isinstance(rtp, int) and isinstance(ntp, int) else (0, 0)


def _plain(exc: BaseException) -> str:
    text = " ".join(str(exc).split())[:200]
    return text or type(exc).__name__


def ask_dtx(sdp: str, mid: str) -> str:
    """The answer with `usedtx=1` on the Opus format of the microphone's section (`mid`): a browser then uses
    Opus' discontinuous transmission (no packet, or one every 400 ms, while the user is silent), which the
    microphone counts as silence (microphone.py). Each section is its own list of lines; other sections and
    formats are left as they are."""
    lines = sdp.split("\r\n")
    sections: list[list[str]] = [[]]
    for line in lines:
        if line.startswith("m="):
            sections.append([])
        sections[-1].append(line)
    for section in sections[1:]:
        if f"a=mid:{mid}" not in section:
            continue
        opus = [line.split()[0][len("a=rtpmap:"):] for line in section
                if line.startswith("a=rtpmap:") and line.lower().split()[-1].startswith("opus/")]
        for pt in opus:
            fmtp = next((i for i, line in enumerate(section) if line.startswith(f"a=fmtp:{pt} ")), None)
            if fmtp is None:
                rtpmap = next(i for i, line in enumerate(section) if line.startswith(f"a=rtpmap:{pt} "))
                section.insert(rtpmap + 1, f"a=fmtp:{pt} usedtx=1")
            elif "usedtx=" not in section[fmtp]:
                section[fmtp] += ";usedtx=1"
    return "\r\n".join(line for section in sections for line in section)
