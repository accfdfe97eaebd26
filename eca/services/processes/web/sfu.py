"""Faces fanned out by Janus (`eca web --sfu URL`): each agent's face and voice published ONCE, as RTP, into a Janus
Streaming mountpoint, which every viewer watches through Janus instead of peering with eca.

A face that pages draw themselves (a 3D head, `draw` "auto" or "browser") also goes in as its face frames
(web/face_frames.py, the same bytes a direct page gets on its data channel): the mountpoint has a data section, eca
sends each frame to its port as one UDP datagram, and Janus relays each to every viewer's data channel. With `draw`
"browser" the mountpoint has no video at all: eca then neither draws nor encodes, whatever the number of viewers.

Per agent, the publisher creates a mountpoint through Janus's HTTP API (web/janus.py) with an Opus and a VP8 section
on ports Janus picks, and sends it RTP over UDP: the VP8 pictures of the same shared encoder the direct viewers'
tracks send (web/encoding.py: one encode per picture at the configured size and rate, also shared with direct
viewers of that size), and the voice as the direct path's VoiceTrack paces it (20 ms frames, each sent when its
first sample reaches the output), Opus-encoded once for all; into a mountpoint without video it pauses in silence,
as to a direct page that draws the face. eca's cost is one viewer's, however many watch Janus.

Timing. Both streams' RTP timestamps come from the master clock's stamps (a picture's `frame_ns`, a voice frame's
DAC time) from one origin, and each packet leaves at its stamp, as on the direct path. Janus strips the RTCP sender
reports a source sends (janus_rtcp_filter drops SR/RR/SDES) and writes its own for each viewer, mapping the newest
RTP timestamp it forwarded to the wall-clock time it forwarded it (src/ice.c): so the browser's lip sync through
Janus rests on the packets leaving on time, as it does with aiortc's own reports on the direct path. The publisher
still sends a sender report per video stream every second to the mountpoint's RTCP port: that is how Janus learns
where to send keyframe requests (it latches the address RTCP comes from) and it sends one (PLI) when a viewer starts
watching and when a viewer's browser asks (at most one a second): each makes the shared encoder's next picture a
keyframe, so a new viewer sees the face at once rather than at the next periodic keyframe (10 s).

Faults. Janus is asked `info` on each mountpoint every `check_s`, which also keeps the session alive (Janus drops a
session after 60 s without a request). A mountpoint or session Janus lost (a restart) is made again, under the same
id when Janus allows, with back-off; meanwhile RTP goes to the old ports and is dropped, and direct viewers are not
affected. On stop the mountpoints are destroyed and the session closed.
"""

from __future__ import annotations

import asyncio
import fractions
import logging
import random
import secrets
import socket
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol, cast
from urllib.parse import urlsplit

import av
from aiortc.codecs.opus import OpusEncoder
from aiortc.codecs.vpx import Vp8Encoder as Vp8Packetizer
from aiortc.rtp import RtcpPacket, RtcpPsfbPacket, RtcpSenderInfo, RtcpSrPacket, RtpPacket

from eca.agent.clock import Clock
from eca.services.processes.web.browser_face import MAX_SPURTS, NTP_UNIX_OFFSET_MS, pack_voice_spurts
from eca.services.processes.web.encoding import VIDEO_RATE, EncodedStream, EncodedStreams
from eca.services.processes.web.face_frames import next_due_ns
from eca.services.processes.web.feeds import VoiceFeed
from eca.services.processes.web.janus import MOUNTPOINT_EXISTS, NO_SUCH_MOUNTPOINT, JanusClient, JanusError
from eca.services.processes.web.tracks import AUDIO_FRAME_S, VoiceTrack
from eca.services.processes.web.viewers import ViewRequest

log = logging.getLogger("web")

AUDIO_PT, VIDEO_PT = 111, 96  # the payload types the mountpoints are made with (Janus offers them to viewers)
# the mountpoints' media sections (a viewer may watch only some: the voice and face frames of a face it draws)
MIDS = {"audio": "a", "video": "v", "data": "d"}
AUDIO_RATE = 48_000  # Opus' RTP clock
SR_EVERY_S = 1.0
CHECK_EVERY_S = 2.0  # how often each mountpoint is looked at (also the session's keepalive: Janus waits 60 s)
RETRY_MAX_S = 10.0
PSFB_PLI, PSFB_FIR = 1, 4  # RTCP payload-specific feedback formats (RFC 4585, RFC 5104): keyframe requests
PUBLISHER_VIEWER = 0  # the numbers the publisher watches under: the video (the viewers' own numbers start at 1)
PUBLISHER_FACES = -1  # and the face frames
# Janus's Streaming plugin reads a data port's datagrams into a 1500-byte buffer (janus_streaming.c): a face whose
# frames are larger (an avatar with many morph targets) cannot go through it; the web service sends it as video
# (draw "auto") or refuses to start (draw "browser")
MAX_DATA_BYTES = 1500
VOICE_CLOCK_EVERY = 12  # voice frames (240 ms) between the voice's clock reports on a face's data section
NTP_EPOCH_S = 2_208_988_800


class SfuError(RuntimeError):
    """The publisher cannot start: the message says why, in one line."""


class PublisherBackend(Protocol):
    """What the publisher needs of the web service (called on its event loop)."""

    clock: Clock
    encoded: EncodedStreams

    def voice(self, agent: str) -> VoiceFeed: ...

    def face_slot(self, agent: str) -> int: ...

    def watch(self, viewer: int, request: ViewRequest) -> None: ...

    def unwatch(self, viewer: int) -> None: ...


class RtpStream:
    """One RTP stream's numbering (SSRC, sequence, timestamps from the master clock) and its sender reports."""

    def __init__(self, payload_type: int, rate: int, origin_ns: int) -> None:
        self.payload_type, self.rate, self.origin_ns = payload_type, rate, origin_ns
        self.ssrc = random.getrandbits(32) or 1
        self.seq = random.getrandbits(16)
        self.ts_offset = random.getrandbits(32)  # RFC 3550: a random start, so streams cannot be told apart by it
        self.packets = 0
        self.octets = 0
        self.last_ns: int | None = None  # the master-clock stamp of the newest packet sent, and its RTP timestamp
        self.last_ts = 0

    def timestamp(self, stamp_ns: int) -> int:
        return (self.ts_offset + (stamp_ns - self.origin_ns) * self.rate // 1_000_000_000) & 0xFFFFFFFF

    def packetize(self, payloads: list[bytes], stamp_ns: int) -> list[bytes]:
        ts = self.timestamp(stamp_ns)
        out = []
        for i, payload in enumerate(payloads):
            packet = RtpPacket(payload_type=self.payload_type, marker=int(i == len(payloads) - 1),
                               sequence_number=self.seq, timestamp=ts, ssrc=self.ssrc, payload=payload)
            self.seq = (self.seq + 1) & 0xFFFF
            out.append(packet.serialize())
            self.packets += 1
            self.octets += len(payload)
        self.last_ns, self.last_ts = stamp_ns, ts
        return out

    def sender_report(self, now_ns: int, wall_s: float) -> bytes | None:
        """An SR for now: the wall clock's NTP time and the RTP timestamp of this instant (the newest packet's
        timestamp carried forward on the master clock), so the two clocks' mapping is exact, not the send time's."""
        if self.last_ns is None:
            return None
        ts = (self.last_ts + (now_ns - self.last_ns) * self.rate // 1_000_000_000) & 0xFFFFFFFF
        ntp = (int((wall_s + NTP_EPOCH_S) * (1 << 32))) & 0xFFFFFFFFFFFFFFFF
        report = RtcpSrPacket(ssrc=self.ssrc, sender_info=RtcpSenderInfo(
            ntp_timestamp=ntp, rtp_timestamp=ts, packet_count=self.packets & 0xFFFFFFFF,
            octet_count=self.octets & 0xFFFFFFFF))
        return bytes(report)


class _Socket(asyncio.DatagramProtocol):
    """A UDP socket to Janus; what comes back (Janus's RTCP: keyframe requests) goes to `on_datagram`."""

    def __init__(self, on_datagram: Callable[[bytes], None] | None = None) -> None:
        self.on_datagram = on_datagram
        self.transport: asyncio.DatagramTransport | None = None
        self.errors = 0

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = cast(asyncio.DatagramTransport, transport)  # the selector's own class does not derive from it

    def datagram_received(self, data: bytes, addr: tuple[str | Any, int]) -> None:
        if self.on_datagram is not None:
            self.on_datagram(data)

    def error_received(self, exc: Exception) -> None:
        self.errors += 1  # ICMP port unreachable while Janus restarts: the packets were lost, nothing else to do

    def send(self, data: bytes, address: tuple[str, int]) -> None:
        if self.transport is not None and not self.transport.is_closing():
            self.transport.sendto(data, address)


@dataclass
class Mountpoint:
    """One agent's mountpoint in Janus and what was sent into it."""

    agent: str
    id: int = 0
    audio_port: int = 0
    video_port: int = 0
    video_rtcp_port: int = 0
    data_port: int = 0  # its face frames' (0: no data section, the server draws this face)
    viewers: int = 0  # as Janus said at the last check
    pictures: int = 0
    voice_frames: int = 0
    face_frames: int = 0
    voice_clocks: int = 0
    keyframe_requests: int = 0
    video: RtpStream | None = None
    audio: RtpStream | None = None
    # (sequence number, RTP timestamp) of the latest talk spurts' first voice packets (runs sent one after another)
    spurts: deque[tuple[int, int]] = field(default_factory=lambda: deque(maxlen=MAX_SPURTS))
    tasks: list[asyncio.Task[None]] = field(default_factory=list)


class SfuPublisher:
    """The faces of `agents`, each published once into a Janus Streaming mountpoint at one size and rate.

    `faces`: the agents whose face frames go in too (pages draw them); `video`: whether any face goes in as video
    (False with `draw` "browser": every face is in `faces`)."""

    def __init__(self, backend: PublisherBackend, url: str, agents: tuple[str, ...], width: int, height: int,
                 fps: float, check_s: float = CHECK_EVERY_S, faces: tuple[str, ...] = (), video: bool = True) -> None:
        self.backend, self.url, self.agents = backend, url.rstrip("/"), agents
        self.width, self.height, self.fps = width, height, fps
        self.faces = tuple(a for a in agents if a in faces)
        self.video = video
        if not video and len(self.faces) != len(agents):
            raise SfuError("without video every agent's face must be one pages draw (a 3D face)")
        self.check_s = check_s
        self.janus = JanusClient(self.url)
        self.host = urlsplit(self.url).hostname or ""  # RTP goes to the host of the API (mountpoints bind to all)
        self.secret = secrets.token_urlsafe(18)  # our mountpoints' secret: no one else may destroy or edit them
        self.mountpoints = {a: Mountpoint(a) for a in agents}
        self.recreated = 0  # how many times the mountpoints were made again after Janus lost them
        self._streams: dict[str, EncodedStream] = {}
        self._video_socket: dict[str, _Socket] = {}
        self._audio_socket: _Socket | None = None
        self._data_socket: _Socket | None = None
        self._next_frame_ns = 0
        self._tasks: list[asyncio.Task[None]] = []
        self._lost = False
        self._origin_ns = 0

    # --- what the page and the tests see -------------------------------------------------------------------

    def page_info(self) -> dict[str, Any]:
        """What `GET /config` tells pages: where Janus is and which mountpoint shows which agent."""
        ids = {a: m.id for a, m in self.mountpoints.items()}
        return {"url": self.url, "mountpoints": ids, "mountpoint": ids[self.agents[0]] if self.agents else None,
                "width": self.width, "height": self.height, "fps": self.fps,
                # the agents whose mountpoint carries face frames (a data section) and whether any has video
                "faces": list(self.faces), "video": self.video, "mids": MIDS}

    def stats(self) -> dict[str, Any]:
        """What was sent into Janus (per agent), independent of how many watch there."""
        return {"recreated": self.recreated, "lost": self._lost,
                "agents": {a: {"mountpoint": m.id, "viewers": m.viewers, "pictures": m.pictures,
                               "voice_frames": m.voice_frames, "keyframe_requests": m.keyframe_requests,
                               "face_frames": m.face_frames, "voice_clocks": m.voice_clocks,
                               "video_packets": m.video.packets if m.video else 0,
                               "audio_packets": m.audio.packets if m.audio else 0}
                           for a, m in self.mountpoints.items()}}

    # --- start and stop ------------------------------------------------------------------------------------

    async def start(self) -> None:
        """The mountpoints made and the media flowing; SfuError (one line) when Janus will not make them."""
        if not self.host:
            raise SfuError(f"the SFU URL {self.url} names no host")
        try:
            resolved = await asyncio.get_running_loop().getaddrinfo(self.host, None, type=socket.SOCK_DGRAM)
            self.host = str(resolved[0][4][0])  # once: every packet goes to the same address
            await self._create_all()
        except (JanusError, OSError) as exc:
            await self.janus.close()
            raise SfuError(f"cannot publish into Janus at {self.url}: {exc}") from None
        loop = asyncio.get_running_loop()
        self._origin_ns = self.backend.clock.now_ns()
        _, audio = await loop.create_datagram_endpoint(_Socket, local_addr=("0.0.0.0", 0))
        self._audio_socket = audio
        if self.faces:
            _, self._data_socket = await loop.create_datagram_endpoint(_Socket, local_addr=("0.0.0.0", 0))
            self.backend.watch(PUBLISHER_FACES, ViewRequest(self.faces, self.width, self.height, self.fps, (), None,
                                                            drawn_here=self.faces))
        if self.video:
            self.backend.watch(PUBLISHER_VIEWER, ViewRequest(self.agents, self.width, self.height, self.fps, (), None))
        for agent in self.agents:
            mp = self.mountpoints[agent]
            mp.audio = RtpStream(AUDIO_PT, AUDIO_RATE, self._origin_ns)
            self._tasks.append(asyncio.ensure_future(self._send_voice(mp, audio)))
            if not self.video:
                continue
            stream = self._streams[agent] = self.backend.encoded.use(agent, self.width, self.height, self.fps)
            _, video = await loop.create_datagram_endpoint(self._rtcp_socket(agent, stream), local_addr=("0.0.0.0", 0))
            self._video_socket[agent] = video
            mp.video = RtpStream(VIDEO_PT, VIDEO_RATE, self._origin_ns)
            self._tasks += [asyncio.ensure_future(self._send_video(mp, stream, video)),
                            asyncio.ensure_future(self._send_reports(mp, video))]
        self._tasks.append(asyncio.ensure_future(self._watch_janus()))
        log.info("publishing %s into Janus at %s (mountpoints %s) at %dx%d, %g fps%s%s", ", ".join(self.agents),
                 self.url, ", ".join(f"{a}: {m.id}" for a, m in self.mountpoints.items()), self.width, self.height,
                 self.fps, f"; face frames of {', '.join(self.faces)}" if self.faces else "",
                 "" if self.video else "; no video")

    def _rtcp_socket(self, agent: str, stream: EncodedStream) -> Callable[[], _Socket]:
        return lambda: _Socket(lambda data: self._on_rtcp(agent, stream, data))

    async def stop(self) -> None:
        for task in self._tasks:
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)
        self._tasks = []
        self.backend.unwatch(PUBLISHER_VIEWER)
        self.backend.unwatch(PUBLISHER_FACES)
        for stream in self._streams.values():
            self.backend.encoded.release(stream)
        self._streams = {}
        for sock in [*self._video_socket.values(), self._audio_socket, self._data_socket]:
            if sock is not None and sock.transport is not None:
                sock.transport.close()
        self._video_socket, self._audio_socket, self._data_socket = {}, None, None
        if not self._lost:
            for mp in self.mountpoints.values():
                if mp.id:
                    try:
                        await self.janus.request({"request": "destroy", "id": mp.id, "secret": self.secret})
                    except JanusError as exc:
                        log.info("Janus did not destroy mountpoint %d (%s): it goes with Janus", mp.id, exc)
        await self.janus.close()

    # --- the mountpoints ------------------------------------------------------------------------------------

    async def _create_all(self) -> None:
        await self.janus.open()
        for mp in self.mountpoints.values():
            await self._create(mp)

    async def _create(self, mp: Mountpoint) -> None:
        """The agent's mountpoint: under its old id when it had one (pages keep watching the same id), else
        wherever Janus puts it. Only the mountpoint's own secret lets anyone destroy it."""
        media: list[dict[str, Any]] = [{"type": "audio", "mid": MIDS["audio"], "codec": "opus", "pt": AUDIO_PT,
                                        "port": 0}]
        if self.video:
            # rtcpport: Janus sends keyframe requests (PLI) back to where our reports come from
            media.append({"type": "video", "mid": MIDS["video"], "codec": "vp8", "pt": VIDEO_PT, "port": 0,
                          "rtcpport": 0})
        if mp.agent in self.faces:
            # binary: each datagram reaches the viewers' data channels as one binary message, as eca sent it
            media.append({"type": "data", "mid": MIDS["data"], "port": 0, "datatype": "binary"})
        body: dict[str, Any] = {
            "request": "create", "type": "rtp", "permanent": False, "is_private": False,
            "name": f"eca-{mp.agent}", "description": f"eca {mp.agent} {self.width}x{self.height} {self.fps:g} fps",
            "secret": self.secret, "media": media,
        }
        if mp.id:
            body["id"] = mp.id
        try:
            created = await self.janus.request(body)
        except JanusError as exc:
            if not (mp.id and exc.code == MOUNTPOINT_EXISTS):
                raise
            # the id is still there (our session timed out, the mountpoint did not): ours, by its secret
            await self.janus.request({"request": "destroy", "id": mp.id, "secret": self.secret})
            created = await self.janus.request(body)
        stream = created["stream"]
        ports = {p.get("type"): p for p in stream.get("ports", []) if isinstance(p, dict)}
        try:
            mp.id = int(stream["id"])
            mp.audio_port = int(ports["audio"]["port"])
            if self.video:
                mp.video_port = int(ports["video"]["port"])
                mp.video_rtcp_port = int(ports["video"].get("rtcp_port") or 0)
            if mp.agent in self.faces:
                mp.data_port = int(ports["data"]["port"])
        except (KeyError, TypeError, ValueError):
            raise JanusError(f"Janus's answer to create has no ports: {stream}") from None

    async def _watch_janus(self) -> None:
        """Every `check_s`: each mountpoint still there (which keeps the session alive); those Janus lost made
        again, with back-off."""
        delay = self.check_s
        while True:
            await asyncio.sleep(delay)
            try:
                if self._lost:
                    await self._create_all()
                    self._lost = False
                    self.recreated += 1
                    for stream in self._streams.values():
                        stream.request_keyframe()  # the new mountpoint's viewers start from a keyframe
                    for mp in self.mountpoints.values():
                        mp.viewers = 0
                    log.warning("Janus at %s: mountpoints made again (%s)", self.url,
                                ", ".join(f"{a}: {m.id}" for a, m in self.mountpoints.items()))
                else:
                    for mp in self.mountpoints.values():
                        # with the secret: Janus tells the viewers' count only to the mountpoint's owner
                        asked = {"request": "info", "id": mp.id, "secret": self.secret}
                        info = (await self.janus.request(asked))["info"]
                        mp.viewers = int(info.get("viewers") or 0)
                delay = self.check_s
            except JanusError as exc:
                if not self._lost:
                    log.warning("Janus at %s lost our mountpoints or does not answer (%s): making them again; direct "
                                "viewers are not affected", self.url, exc)
                self._lost = self._lost or exc.lost or exc.code in (0, NO_SUCH_MOUNTPOINT)
                delay = min(RETRY_MAX_S, delay * 2) if self._lost else self.check_s
            except Exception:  # a bug here must not end the publishing: said, and tried again
                log.exception("watching Janus at %s failed", self.url)
                delay = RETRY_MAX_S

    # --- the media ------------------------------------------------------------------------------------------

    async def _send_video(self, mp: Mountpoint, stream: EncodedStream, sock: _Socket) -> None:
        """Each encoded picture as it comes, packetized (VP8 payload descriptors by aiortc) and sent at once; a
        picture that cannot be decoded after the last one sent (one was missed) waits for a keyframe, as a
        direct viewer's FaceTrack does."""
        assert mp.video is not None
        packetizer = Vp8Packetizer()
        sent_seq = seen = -1
        while True:
            picture = await stream.next_after(seen)
            if picture is None:
                return  # the stream stopped: the service is stopping
            seen = picture.seq
            if not (picture.keyframe or (sent_seq >= 0 and picture.seq == sent_seq + 1)):
                stream.request_keyframe()
                continue
            sent_seq = picture.seq
            packet = av.Packet(picture.data)
            packet.pts, packet.time_base = 0, fractions.Fraction(1, VIDEO_RATE)
            payloads, _ = packetizer.pack(packet)
            for datagram in mp.video.packetize(payloads, picture.frame_ns):
                sock.send(datagram, (self.host, mp.video_port))
            mp.pictures += 1

    def send_face_frames(self, frames: dict[str, bytes], frame_ns: int, early: bool = False) -> None:
        """One frame slot's face frames (on the event loop's thread), each as one datagram to its mountpoint's data
        port, at this publisher's rate (the slots come at the fastest any page asked; a frame made early for a
        commanded change goes at once). Janus relays each to every viewer's data channel."""
        sock = self._data_socket
        if sock is None:
            return
        if not early:
            due_ns = next_due_ns(self._next_frame_ns, frame_ns, self.fps)
            if due_ns is None:
                return
            self._next_frame_ns = due_ns
        for agent in self.faces:
            data = frames.get(agent)
            mp = self.mountpoints[agent]
            if data is None or not mp.data_port or len(data) > MAX_DATA_BYTES:
                continue
            sock.send(data, (self.host, mp.data_port))
            mp.face_frames += 1

    async def _send_voice(self, mp: Mountpoint, sock: _Socket) -> None:
        """The voice in 20 ms frames, each when its first sample reaches the output (the direct path's
        VoiceTrack), Opus-encoded once for every viewer of Janus. Into a mountpoint without video (every page draws
        the face) it pauses in silence, as to a direct page that draws it: Janus relays nothing then. A mountpoint
        with video keeps it continuous (a browser lines the video up with it)."""
        assert mp.audio is not None
        pause = mp.agent in self.faces and not self.video
        # one track per agent whatever the viewers: it looks at every frame's time in a pause, as the page's count
        # of Janus's packets was worked out against (sleeping through pauses saves a conversation per viewer)
        track = VoiceTrack(self.backend.voice(mp.agent), self.backend.clock, pause_in_silence=pause,
                           sleep_in_pauses=False)
        encoder = OpusEncoder()
        slot = self.backend.face_slot(mp.agent) if mp.agent in self.faces else None
        frame_ts = round(AUDIO_RATE * AUDIO_FRAME_S)
        while True:
            frame = await track.recv()
            if isinstance(frame, av.Packet):  # the paused voice's own Opus packet
                payloads = [bytes(frame)]
            else:
                payloads, _ = encoder.encode(frame)
                if not payloads:
                    continue  # the encoder's first frame: it holds samples back
            start_ns = track.frame_start_ns((frame.pts or 0) // track.samples_per_frame)
            first_seq, ts = mp.audio.seq, mp.audio.timestamp(start_ns)
            spurt = mp.audio.last_ns is None or ts != (mp.audio.last_ts + frame_ts) & 0xFFFFFFFF
            for datagram in mp.audio.packetize(payloads, start_ns):
                sock.send(datagram, (self.host, mp.audio_port))
            if spurt:
                mp.spurts.append((first_seq, ts))
            mp.voice_frames += 1
            if slot is not None and (spurt or mp.voice_frames % VOICE_CLOCK_EVERY == 0):
                self._send_voice_clock(mp, slot, start_ns)

    def _send_voice_clock(self, mp: Mountpoint, slot: int, stamp_ns: int) -> None:
        """The voice's clock on the face's data section (browser_face.py, kind 3): the RTP timestamp of the packet
        just sent and its time on the wall clock's NTP scale (the face frames' clock), the way to Janus (half the
        quickest of the latest API round trips), and the latest talk spurts' first packets. Janus renumbers each
        viewer's voice from the first packet it relays to it; the page works out which that was
        (static/face3d.js VoiceClock.rebase) from when its packets arrive, less its own way from Janus and eca's way
        to it: each leg is taken off where it is known, so a Janus far from eca, or a page far from Janus, leaves
        the page's count on the right packet."""
        assert mp.audio is not None
        if self._data_socket is None or not mp.data_port or not mp.spurts:
            return
        wall_offset_ns = time.time_ns() - self.backend.clock.now_ns()
        ntp = (stamp_ns + wall_offset_ns) / 1e6 + NTP_UNIX_OFFSET_MS
        last_seq = (mp.audio.seq - 1) & 0xFFFF
        message = pack_voice_spurts(slot, mp.audio.last_ts, ntp, self.janus.one_way_s() * 1e3, last_seq,
                                    list(mp.spurts))
        self._data_socket.send(message, (self.host, mp.data_port))
        mp.voice_clocks += 1

    async def _send_reports(self, mp: Mountpoint, sock: _Socket) -> None:
        """A sender report on the video stream every second, to the mountpoint's RTCP port (see the module's
        docstring: Janus keeps its own, but learns from ours where keyframe requests go)."""
        assert mp.video is not None
        while True:
            await asyncio.sleep(SR_EVERY_S if mp.video.last_ns is not None else 0.1)
            report = mp.video.sender_report(self.backend.clock.now_ns(), time.time())
            if report is not None and mp.video_rtcp_port:
                sock.send(report, (self.host, mp.video_rtcp_port))

    def _on_rtcp(self, agent: str, stream: EncodedStream, data: bytes) -> None:
        """Janus's RTCP on a video socket: a keyframe request (a viewer started, or its browser lost a picture)
        makes the shared encoder's next picture a keyframe."""
        try:
            packets = RtcpPacket.parse(data)
        except ValueError:
            return  # not RTCP: nothing Janus sends us otherwise
        for packet in packets:
            if isinstance(packet, RtcpPsfbPacket) and packet.fmt in (PSFB_PLI, PSFB_FIR):
                stream.request_keyframe()
                self.mountpoints[agent].keyframe_requests += 1
