"""A page's part, in Python (aiortc): a WebRTC client of the web service, for the tests."""

from __future__ import annotations

import asyncio
import json
import subprocess
import time
from pathlib import Path
from typing import Any

import aiohttp
import numpy as np
import soundfile as sf
from aiortc import RTCConfiguration, RTCPeerConnection, RTCSessionDescription

SMALL = {"width": 160, "height": 120, "fps": 15.0}


class Client:
    """One peer connection receiving the agents' faces and voices (and sending a microphone, if given)."""

    def __init__(self, base: str, agents: list[str], mic: Any = None, token: str | None = None,
                 video: dict[str, float] | None = None, configuration: RTCConfiguration | None = None) -> None:
        self.base, self.agents, self.mic, self.token = base, agents, mic, token
        self.video = video or SMALL
        # `configuration`: the page's STUN/TURN servers and policy (none: aiortc's own default)
        self.pc = RTCPeerConnection(configuration)
        self.tracks: dict[tuple[str, str], Any] = {}

    async def offer_body(self) -> dict[str, Any]:
        # the microphone's section first, as the page does (aiortc routes a sending section that follows
        # receiving ones of the same kind wrongly)
        mic = self.pc.addTransceiver(self.mic, direction="sendonly") if self.mic is not None else None
        sections = []
        for agent in self.agents:
            for kind in ("video", "audio"):
                sections.append((self.pc.addTransceiver(kind, direction="recvonly"), agent, kind))
        await self.pc.setLocalDescription(await self.pc.createOffer())
        self.sections = sections
        return {"type": "offer", "sdp": self.pc.localDescription.sdp, "token": self.token, "agents": self.agents,
                "video": self.video, "streams": [{"mid": t.mid, "agent": a, "kind": k} for t, a, k in sections],
                "mic_mid": mic.mid if mic is not None else None}

    async def connect(self) -> dict[str, Any]:
        body = await self.offer_body()
        status, answer = await post(self.base + "offer", body)
        assert status == 200, answer
        await self.accept(answer)
        return answer

    async def accept(self, answer: dict[str, Any]) -> None:
        await self.pc.setRemoteDescription(RTCSessionDescription(sdp=answer["sdp"], type="answer"))
        self.tracks = {(a, k): t.receiver.track for t, a, k in self.sections}

    def vanish(self) -> None:
        """Stop answering at all, as a browser whose machine lost its network: the sockets go quiet and
        no goodbye is sent."""
        for transceiver in self.pc.getTransceivers():
            connection = transceiver.sender.transport.transport._connection
            for protocol in connection._protocols:
                protocol.transport.close()

    async def frames(self, agent: str, kind: str, seconds: float) -> list[Any]:
        """What arrives on one received track within `seconds`."""
        track = self.tracks[(agent, kind)]
        out = []
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            try:
                out.append(await asyncio.wait_for(track.recv(), max(0.01, deadline - time.monotonic())))
            except TimeoutError:
                break
        return out


async def post(url: str, body: Any, raw: bytes | None = None,
               session: aiohttp.ClientSession | None = None) -> tuple[int, Any]:
    """POST JSON (or raw bytes), in `session` or a new one; the status and the decoded answer (text when it is not
    JSON)."""
    if session is None:
        async with aiohttp.ClientSession() as own:
            return await post(url, body, raw, own)
    data = raw if raw is not None else json.dumps(body).encode()
    async with session.post(url, data=data, headers={"Content-Type": "application/json"}) as response:
        text = await response.text()
        try:
            return response.status, json.loads(text)
        except json.JSONDecodeError:
            return response.status, text


def user_speech_wav(path: Path, sentence: str, before_s: float, after_s: float) -> Path:
    """What a user says into the microphone: silence, a sentence spoken by espeak-ng, silence."""
    spoken = path.with_name(path.stem + "-spoken.wav")
    subprocess.run(["espeak-ng", "-w", str(spoken), sentence], check=True)
    samples, rate = sf.read(spoken, dtype="float32")
    silence = lambda seconds: np.zeros(round(seconds * rate), np.float32)  # noqa: E731
    sf.write(path, np.concatenate([silence(before_s), samples, silence(after_s)]), rate)
    return path


class FaceClient(Client):
    """A page that draws its agents itself, in Python: their voices as audio tracks and their face frames on the
    "eca-face" data channel (kept with their arrival times), and the answer's face descriptions."""

    def __init__(self, base: str, agents: list[str], token: str | None = None, fps: float = 15.0,
                 configuration: RTCConfiguration | None = None) -> None:
        super().__init__(base, agents, token=token, video={"width": 160, "height": 120, "fps": fps},
                         configuration=configuration)
        self.messages: list[tuple[float, bytes]] = []
        self.channel = self.pc.createDataChannel("eca-face", ordered=False, maxRetransmits=0)
        self.channel.on("message", lambda m: self.messages.append((time.monotonic(), m)))
        self.faces: dict[str, Any] = {}

    async def offer_body(self) -> dict[str, Any]:
        sections = [(self.pc.addTransceiver("audio", direction="recvonly"), agent, "audio") for agent in self.agents]
        await self.pc.setLocalDescription(await self.pc.createOffer())
        self.sections = sections
        return {"type": "offer", "sdp": self.pc.localDescription.sdp, "token": self.token, "agents": self.agents,
                "video": self.video, "streams": [{"mid": t.mid, "agent": a, "kind": k} for t, a, k in sections],
                "mic_mid": None, "draw_here": self.agents}

    async def accept(self, answer: dict[str, Any]) -> None:
        await super().accept(answer)
        self.faces = answer["faces"]

    def frames_of(self, agent: str, kind: int = 1) -> list[tuple[float, bytes]]:
        """The messages of one kind (1: frames, 2: voice clocks) for an agent, with their arrival times."""
        slot = self.faces[agent]["slot"]
        return [(t, m) for t, m in self.messages
                if isinstance(m, bytes) and len(m) >= 4 and int.from_bytes(m[:2], "little") == slot and m[2] == kind]

    async def wait_for_frames(self, agent: str, count: int, timeout_s: float) -> list[tuple[float, bytes]]:
        deadline = time.monotonic() + timeout_s
        while len(got := self.frames_of(agent)) < count and time.monotonic() < deadline:
            await asyncio.sleep(0.05)  # polling what has arrived: the channel's events fill the list
        return got


class ConversationPage(FaceClient):
    """A page of a per-visitor instance: it asks for its conversation, then connects to its agent with its key. Its
    two requests share a cookie jar of their own, as a browser's page does: behind a load balancer its sticky cookie
    keeps the offer on the host that made the conversation."""

    key: str = ""

    @classmethod
    async def arrive(cls, url: str) -> tuple[ConversationPage | None, int, Any]:
        async with aiohttp.ClientSession(cookie_jar=aiohttp.CookieJar(unsafe=True)) as session:
            status, made = await post(url + "conversation", {}, session=session)
            if status != 201:
                return None, status, made
            page = cls(url, [made["agent"]])
            page.key = made["key"]
            offered, answer = await post(url + "offer", await page.offer_body(), session=session)
            assert offered == 200, answer
            await page.accept(answer)
            return page, status, made

    async def offer_body(self) -> dict[str, Any]:
        return {**await super().offer_body(), "key": self.key}

    async def command(self, **command: Any) -> tuple[int, Any]:
        return await post(self.base + "command", {"key": self.key, "command": {"agent": self.agents[0], **command}})


def speak_tone(pub: Any, seconds: float, agent: str = "ada") -> int:
    """Voice blocks of a loud tone on `pub` (a bus Publisher), stamped ahead of time as the audio service stamps
    them: what a web service plays to its viewers. Returns when the tone starts (time.monotonic_ns)."""
    from eca.protocol.messages import VoiceBlock

    start = time.monotonic_ns() + 60_000_000
    t = np.arange(480) / 48_000
    for k in range(int(seconds * 100)):
        tone = (0.5 * np.sin(2 * np.pi * 440 * (t + k * 0.01)) * 32767).astype("<i2")
        pub.publish(VoiceBlock(agent=agent, sample_rate=48_000, first_sample=k * 480,
                               dac_time_ns=start + k * 10_000_000, pcm=tone.tobytes(), request_id="r"))
    return start
