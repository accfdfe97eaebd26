"""A private Janus (Debian's `janus`, its Streaming plugin) for the tests and benches, and a viewer of its mountpoints
written with aiortc.

`janus_server(host)` renders a configuration into a fresh folder (the HTTP transport bound to the host's address on a
free port, no admin API, only the Streaming plugin and the HTTP transport loaded, ICE on the host's interface only,
RTP ports from a private range), starts `janus -F <folder> -C <folder>/janus.jcfg` in the foreground in that network
namespace, waits until its HTTP API answers `info` (polled) and stops it on exit. A namespace, not loopback: libnice
(Janus) and aioice (aiortc) both skip 127.0.0.1 candidates, so WebRTC through Janus needs a real address.

`JanusViewer` watches one mountpoint as a page does (session, attach, watch, answer the offer with `start`), from
whatever namespace the process runs in; `python -m tests.support.janus watch URL ID SECONDS` runs viewers in a
process of their own (put it in a viewer namespace with `Host.popen`) and prints what they received as JSON.
"""

from __future__ import annotations

import argparse
import asyncio
import base64
import json
import os
import re
import secrets
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import aiohttp

JANUS = "/usr/bin/janus"
# what Janus logs for every message, request or SDP line at debug level 5: left out of a failure's message, so that the
# sessions, ICE pairs and states stay in its last lines
LOG_NOISE = re.compile(r"SCTP data to send|Using open channel|Message sent on channel|Got a Janus API request|"
                       r"Transport task pool|returning up to|Got a keep-alive|There's a message for|"
                       r"Sending event to transport|Pushing event|^\s*[a-z]=|^\s*$")
RUNNING: list[Janus] = []  # the private Janus instances running in this process, newest last (their logs for failures)
LIBS = "/usr/lib/x86_64-linux-gnu/janus"
START_TIMEOUT_S = 20.0


def janus_available() -> str | None:
    """None when Janus can run here; otherwise why not (a skip reason)."""
    path = shutil.which("janus") or (JANUS if os.path.exists(JANUS) else None)
    if path is None:
        return "janus is not installed (Debian: apt-get install janus; .ci/setup installs it)"
    if not Path(LIBS, "plugins", "libjanus_streaming.so").exists():
        return f"Janus's Streaming plugin is missing under {LIBS}/plugins"
    return None


def free_port(address: str = "") -> int:
    with socket.socket() as s:
        s.bind((address, 0))
        return int(s.getsockname()[1])


@dataclass
class Janus:
    """A running private Janus: its HTTP API's URL, where its config lives, and how to restart it."""

    url: str
    folder: Path
    argv: list[str]
    host: Any  # tests.support.netns.Host, or None for the root namespace
    proc: subprocess.Popen[bytes] | None = None
    log_path: Path = field(default_factory=Path)

    def start(self) -> None:
        log = open(self.log_path, "ab")  # noqa: SIM115 (the child holds it; closed with the process)
        self.proc = (self.host.popen(self.argv, stdout=log, stderr=subprocess.STDOUT) if self.host is not None
                     else subprocess.Popen(self.argv, stdout=log, stderr=subprocess.STDOUT))
        log.close()
        deadline = time.monotonic() + START_TIMEOUT_S
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"janus exited with {self.proc.returncode}: {self.log_tail()}")
            if janus_info(self.url) is not None:
                return
            time.sleep(0.05)  # polling its HTTP API: Janus says nothing else when it is ready
        self.stop()
        raise RuntimeError(f"janus did not answer info at {self.url} within {START_TIMEOUT_S} s: {self.log_tail()}")

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)
        self.proc = None

    def restart(self) -> None:
        """Stop and start again: every session and mountpoint is lost (what a crashed or redeployed Janus does)."""
        self.stop()
        self.start()

    def recent_log(self, last: int = 60) -> str:
        """The last `last` lines of Janus's log (sessions, ICE pairs and states, DTLS, media: debug level 5), colour
        codes taken out and each run of a repeated line said once with its count: what a failure's message shows."""
        try:
            text = self.log_path.read_text(errors="replace")
        except OSError:
            return ""
        runs: list[list[Any]] = []  # [line, times]
        for line in text.splitlines():
            line = re.sub(r"\x1b\[[0-9;]*m", "", line)
            if LOG_NOISE.search(line):
                continue
            if runs and runs[-1][0] == line:
                runs[-1][1] += 1
            else:
                runs.append([line, 1])
        return "\n".join(line if times == 1 else f"{line} (x{times})" for line, times in runs[-last:])

    def log_tail(self, chars: int = 2000) -> str:
        try:
            return self.log_path.read_text(errors="replace")[-chars:]
        except OSError:
            return ""


def running_logs(last: int = 150) -> str:
    """The recent log of every private Janus running in this process (Janus.recent_log), for a failure's message."""
    return "\n".join(f"--- Janus at {j.url}:\n{j.recent_log(last)}" for j in RUNNING) or "(no Janus running)"


def janus_info(url: str, timeout_s: float = 1.0) -> dict[str, Any] | None:
    """Janus's `info` answer, or None when it does not answer (yet)."""
    import urllib.error
    import urllib.request

    try:
        with urllib.request.urlopen(url.rstrip("/") + "/info", timeout=timeout_s) as response:
            body = json.loads(response.read())
    except (OSError, urllib.error.URLError, ValueError):
        return None
    return body if isinstance(body, dict) and body.get("janus") == "server_info" else None


def render_config(folder: Path, address: str, http_port: int, rtp_range: tuple[int, int],
                  interface: str | None) -> None:
    """Janus's configuration files for one private instance, written into `folder`."""
    plugins = sorted(p.name for p in Path(LIBS, "plugins").glob("libjanus_*.so")
                     if p.name != "libjanus_streaming.so")
    transports = sorted(p.name for p in Path(LIBS, "transports").glob("libjanus_*.so") if p.name != "libjanus_http.so")
    enforce = f'ice_enforce_list = "{interface}"' if interface else f'ice_enforce_list = "{address}"'
    (folder / "janus.jcfg").write_text(f"""general: {{
	configs_folder = "{folder}"
	plugins_folder = "{LIBS}/plugins"
	transports_folder = "{LIBS}/transports"
	events_folder = "{LIBS}/events"
	loggers_folder = "{LIBS}/loggers"
	debug_level = 5
	session_timeout = 60
	hide_dependencies = true
	protected_folders = ["/bin", "/boot", "/dev", "/etc", "/lib", "/proc", "/sbin", "/sys", "/usr", "/var"]
}}
media: {{
	rtp_port_range = "{rtp_range[0]}-{rtp_range[1]}"
	ipv6 = false
}}
nat: {{
	{enforce}
	ice_ignore_list = "lo"
}}
plugins: {{
	disable = "{','.join(plugins)}"
}}
transports: {{
	disable = "{','.join(transports)}"
}}
loggers: {{
	disable = "libjanus_jsonlog.so"
}}
events: {{
	broadcast = false
}}
""")
    (folder / "janus.transport.http.jcfg").write_text(f"""general: {{
	json = "plain"
	base_path = "/janus"
	http = true
	port = {http_port}
	ip = "{address}"
	https = false
}}
admin: {{
	admin_http = false
	admin_https = false
}}
cors: {{
	allow_origin = "*"
}}
""")
    # no mountpoints of its own (eca creates its mountpoints through the API); the ports a mountpoint made with port 0
    # gets come from the plugin's own range (its default is 10000-60000), kept next to the ICE range
    (folder / "janus.plugin.streaming.jcfg").write_text(
        f'general: {{\n\trtp_port_range = "{rtp_range[1] + 1}-{rtp_range[1] + 1000}"\n}}\n')


def _interface_of(host: Any) -> str | None:
    """The namespace's own (veth) interface name: ICE is kept to it (loopback is skipped anyway)."""
    if host is None:
        return None
    done = host.run(["ip", "-o", "-4", "addr", "show"], capture_output=True, text=True)
    for line in done.stdout.splitlines():
        parts = line.split()
        if len(parts) > 3 and parts[3].split("/")[0] == host.address:
            return str(parts[1])
    return None


@contextmanager
def janus_server(host: Any = None, address: str | None = None) -> Iterator[Janus]:
    """A private Janus in `host` (a tests.support.netns Host; None: this namespace on `address`), stopped on exit."""
    why = janus_available()
    if why is not None:
        raise RuntimeError(why)
    bind = host.address if host is not None else (address or "127.0.0.1")
    folder = Path(tempfile.mkdtemp(prefix="eca-janus-"))
    try:
        # ports: the namespace is fresh, so any port is free there; in this namespace ask the system
        http_port = free_port(bind) if host is None else 8088
        base = 20000 + (os.getpid() * 37) % 30000
        render_config(folder, bind, http_port, (base, base + 999), _interface_of(host))
        janus = Janus(f"http://{bind}:{http_port}/janus", folder,
                      [shutil.which("janus") or JANUS, "-F", str(folder), "-C", str(folder / "janus.jcfg")], host,
                      log_path=folder / "janus.log")
        janus.start()
        RUNNING.append(janus)
        try:
            yield janus
        finally:
            RUNNING.remove(janus)
            janus.stop()
    finally:
        shutil.rmtree(folder, ignore_errors=True)


# --- a viewer of a Streaming mountpoint (aiortc) ------------------------------------------------------------------


class JanusViewer:
    """One viewer of a mountpoint through Janus's HTTP API: a session, the Streaming plugin, `watch`, Janus's offer
    answered with `start` (aiortc gathers its candidates before answering: no trickle needed)."""

    def __init__(self, url: str, mountpoint: int) -> None:
        from aiortc import RTCPeerConnection

        self.url, self.mountpoint = url.rstrip("/"), mountpoint
        self.pc = RTCPeerConnection()
        self.tracks: dict[str, Any] = {}
        self.offer_sdp = ""
        self.messages: list[tuple[float, bytes | str]] = []  # what came on Janus's data channel, with arrival times
        self.pc.on("datachannel", self._on_channel)
        self._http: aiohttp.ClientSession | None = None
        self._session = self._handle = 0
        self._poll: asyncio.Task[None] | None = None
        self._events: asyncio.Queue[dict[str, Any]] = asyncio.Queue()

    def _on_channel(self, channel: Any) -> None:
        channel.on("message", lambda message: self.messages.append((time.time(), message)))

    async def _post(self, path: str, body: dict[str, Any]) -> dict[str, Any]:
        assert self._http is not None
        async with self._http.post(self.url + path, json={**body, "transaction": secrets.token_hex(6)}) as r:
            answer: dict[str, Any] = await r.json(content_type=None)
        if answer.get("janus") == "error":
            raise RuntimeError(f"janus: {answer.get('error')}")
        return answer

    async def _long_poll(self) -> None:
        assert self._http is not None
        while True:
            try:
                async with self._http.get(f"{self.url}/{self._session}?maxev=5") as r:
                    got = await r.json(content_type=None)
            except (aiohttp.ClientError, TimeoutError, ValueError):
                await asyncio.sleep(0.5)
                continue
            for event in got if isinstance(got, list) else [got]:
                if isinstance(event, dict) and event.get("janus") != "keepalive":
                    await self._events.put(event)

    async def _event_with(self, key: str, timeout_s: float) -> dict[str, Any]:
        deadline = time.monotonic() + timeout_s
        while True:
            event = await asyncio.wait_for(self._events.get(), max(0.01, deadline - time.monotonic()))
            data = event.get("plugindata", {}).get("data", {})
            if "error" in data:
                raise RuntimeError(f"janus streaming: {data['error']}")
            if key in event or key in data.get("result", {}):
                return event

    async def connect(self, timeout_s: float = 20.0) -> None:
        from aiortc import RTCSessionDescription

        self._http = aiohttp.ClientSession(timeout=aiohttp.ClientTimeout(total=40))
        self._session = (await self._post("", {"janus": "create"}))["data"]["id"]
        self._handle = (await self._post(f"/{self._session}", {"janus": "attach",
                                                               "plugin": "janus.plugin.streaming"}))["data"]["id"]
        self._poll = asyncio.ensure_future(self._long_poll())
        await self._post(f"/{self._session}/{self._handle}",
                         {"janus": "message", "body": {"request": "watch", "id": self.mountpoint}})
        offer = (await self._event_with("jsep", timeout_s))["jsep"]
        self.offer_sdp = str(offer["sdp"])
        self.pc.on("track", lambda track: self.tracks.__setitem__(track.kind, track))
        await self.pc.setRemoteDescription(RTCSessionDescription(sdp=offer["sdp"], type=offer["type"]))
        if "m=application" in self.offer_sdp:
            # Janus relays a mountpoint's data once the viewer's data channel is open: the viewer opens it (as
            # janus.js does), under the label Janus sends on when a plugin names none
            self._on_channel(self.pc.createDataChannel("JanusDataChannel"))
        await self.pc.setLocalDescription(await self.pc.createAnswer())
        await self._post(f"/{self._session}/{self._handle}",
                         {"janus": "message", "body": {"request": "start"},
                          "jsep": {"type": "answer", "sdp": self.pc.localDescription.sdp}})

    async def frames(self, kind: str, seconds: float) -> list[tuple[float, Any]]:
        """What arrives on the received track of `kind` within `seconds` (decoded frames), with their arrival times
        (time.time(): one clock for every namespace)."""
        deadline = time.monotonic() + seconds
        while kind not in self.tracks and time.monotonic() < deadline:
            await asyncio.sleep(0.05)  # the track event comes with the answer
        out = []
        track = self.tracks.get(kind)
        while track is not None and time.monotonic() < deadline:
            try:
                frame = await asyncio.wait_for(track.recv(), max(0.01, deadline - time.monotonic()))
                out.append((time.time(), frame))
            except TimeoutError:
                break
            except Exception:  # MediaStreamError: the connection ended
                break
        return out

    async def close(self) -> None:
        await self.pc.close()
        if self._poll is not None:
            self._poll.cancel()
        if self._http is not None:
            try:
                await self._post(f"/{self._session}", {"janus": "destroy"})
            except (aiohttp.ClientError, RuntimeError, TimeoutError):
                pass  # Janus may be gone already
            await self._http.close()


def picture_stats(arrived: float, frame: Any, thumbnail: bool = True) -> dict[str, Any]:
    """What the tests compare of a decoded picture: when it arrived, its spread (a face, not a blank), and a 32x24
    grey thumbnail (a change of expression shows in it)."""
    grey = frame.to_ndarray(format="gray").astype("float32")
    out: dict[str, Any] = {"t": arrived, "std": float(grey.std()), "w": frame.width, "h": frame.height}
    if thumbnail:
        h, w = grey.shape
        out["thumb"] = [round(float(v), 1) for v in
                        grey[: h - h % 24, : w - w % 32].reshape(24, h // 24, 32, w // 32).mean(axis=(1, 3)).ravel()]
    return out


async def watch(url: str, mountpoint: int, seconds: float, viewers: int = 1, decode_every: int = 1,
                thumbnails: bool = True) -> dict[str, Any]:
    """`viewers` viewers of one mountpoint for `seconds`: per viewer, the pictures (their arrival time and stats),
    the audio frames received and the data channel's messages (arrival time, base64 of a binary message)."""
    import numpy as np

    clients = [JanusViewer(url, mountpoint) for _ in range(viewers)]
    await asyncio.gather(*(c.connect() for c in clients))
    began = time.time()

    async def one(client: JanusViewer) -> dict[str, Any]:
        video, audio = await asyncio.gather(client.frames("video", seconds), client.frames("audio", seconds))
        level = 0.0
        if audio:
            level = float(np.sqrt(np.mean(np.concatenate([f.to_ndarray().astype(np.float64).reshape(-1)
                                                          for _, f in audio]) ** 2)))
        return {"pictures": len(video), "audio_frames": len(audio), "audio_rms": level,
                "stats": [picture_stats(t, f, thumbnails) for t, f in video[::decode_every]],
                "messages": [{"t": t, "binary": isinstance(m, bytes),
                              "data": base64.b64encode(m).decode() if isinstance(m, bytes) else m[:100]}
                             for t, m in client.messages]}

    try:
        results = await asyncio.gather(*(one(c) for c in clients))
    finally:
        await asyncio.gather(*(c.close() for c in clients), return_exceptions=True)
    return {"began": began, "viewers": results}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tests.support.janus")
    sub = parser.add_subparsers(dest="cmd", required=True)
    w = sub.add_parser("watch", help="watch a mountpoint and print what arrived as JSON")
    w.add_argument("url")
    w.add_argument("mountpoint", type=int)
    w.add_argument("seconds", type=float)
    w.add_argument("--viewers", type=int, default=1)
    args = parser.parse_args(argv)
    result = asyncio.run(watch(args.url, args.mountpoint, args.seconds, args.viewers))
    json.dump(result, sys.stdout)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
