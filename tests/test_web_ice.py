"""How the web service's WebRTC peers and its pages find a path ([web.ice], web/ice.py): a page that may only use a
TURN relay (a real coturn on a host of its own, time-limited credentials minted from its secret) gets its face
frames and voice through it, and eca's own peer allocates a relay with the credentials it mints; the host
candidates eca offers can be held to named interfaces; and settings that cannot be are refused naming what."""

from __future__ import annotations

import asyncio
import re
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import aiohttp
import pytest
import zmq
from aiortc import RTCConfiguration, RTCIceServer, RTCIceTransportPolicy, RTCPeerConnection

from eca.protocol.bus import Publisher
from eca.protocol.endpoints import BusConfig
from eca.services.processes.avatar.loader import DEFAULT_HEAD
from eca.services.processes.web.ice import IceSettings, IceSettingsError, ice_from_table, turn_rest_credential
from eca.services.processes.web.ice_gathering import configuration
from eca.services.processes.web.options import WebOptions, WebOptionsError, options_from_table
from eca.services.processes.web.service import WebService
from tests.support.browser import browser_available, chromium, wait_for
from tests.support.bus import BrokerThread, ServiceThread, private_bus_config
from tests.support.netns import Network, hosts, netns_available
from tests.support.turn import TurnServer, turn_available, turn_server
from tests.support.web_client import FaceClient, speak_tone

ROOT = Path(__file__).resolve().parents[1]
SECRET = "a-shared-secret-of-the-turn-server"
needs_network = pytest.mark.skipif(netns_available() is not None, reason=str(netns_available()))
needs_turn = pytest.mark.skipif(turn_available() is not None, reason=str(turn_available()))
needs_head = pytest.mark.skipif(not DEFAULT_HEAD.exists(), reason="the default head is not baked")


def candidates(sdp: str) -> list[tuple[str, str]]:
    """(address, type) of each candidate line of an SDP."""
    return [(m[1], m[2]) for m in re.finditer(r"a=candidate:\S+ \d+ \w+ \d+ (\S+) \d+ typ (\w+)", sdp)]


@pytest.fixture
def network() -> Iterator[Network]:
    with hosts("turn") as net:
        yield net


@pytest.fixture
def turn(network: Network) -> Iterator[TurnServer]:
    with turn_server(network["turn"], SECRET) as server:
        yield server


@pytest.fixture
def relayed_web(network: Network, turn: TurnServer, tmp_path: Path) -> Iterator[tuple[BusConfig, WebService]]:
    secret = tmp_path / "turn-secret"
    secret.write_text(SECRET + "\n")
    # the service offers its address on the test network only: the TURN host has no route to the machine's others
    # (coturn's relay socket that fails to send to one spoils the allocation's next channel bindings: 438, then 400)
    ice = ice_from_table({"servers": [turn.url], "secret_file": str(secret), "credential_ttl_s": 3600.0,
                          "interfaces": [network.root_address]})
    with private_bus_config() as config, BrokerThread(config):
        service = WebService(config, WebOptions(port=0, fps=15.0, face="head", draw="browser", ice=ice))
        with ServiceThread(service):
            yield config, service


def relay_only(servers: list[dict[str, Any]]) -> RTCConfiguration:
    return RTCConfiguration(iceServers=[RTCIceServer(urls=s["urls"], username=s.get("username"),
                                                     credential=s.get("credential")) for s in servers],
                            iceTransportPolicy=RTCIceTransportPolicy.RELAY)


@needs_network
@needs_turn
@needs_head
def test_a_page_that_may_only_use_a_relay_gets_its_face_and_voice_through_the_turn_server(
        relayed_web: tuple[BusConfig, WebService], turn: TurnServer) -> None:
    config, service = relayed_web
    url = f"http://127.0.0.1:{service.port}/"
    ctx = zmq.Context()
    pub = Publisher(ctx, config, "audio")
    pub.wait_ready()

    async def main() -> tuple[dict[str, Any], FaceClient, str, str, int, int]:
        async with aiohttp.ClientSession() as session, session.get(url + "config") as response:
            page_config = await response.json()
        # a page told to use the TURN server only, with the servers and credentials /config gave it
        client = FaceClient(url, ["ada"], fps=15.0, configuration=relay_only(page_config["ice_servers"]))
        answer = await client.connect()
        offer_sdp = client.pc.localDescription.sdp
        await client.wait_for_frames("ada", 10, 20.0)
        speak_tone(pub, 1.5)
        sounds = await client.frames("ada", "audio", 3.0)
        loud = sum(1 for f in sounds if abs(f.to_ndarray()).max() > 1000)
        await client.pc.close()
        return page_config, client, offer_sdp, answer["sdp"], len(sounds), loud

    try:
        page_config, client, offer_sdp, answer_sdp, sounds, loud = asyncio.run(main())
    finally:
        pub.close()
        ctx.term()
    [server] = page_config["ice_servers"]
    expiry, name = server["username"].split(":")
    assert server["urls"] == turn.url and name == "eca"
    assert abs(int(expiry) - (time.time() + 3600)) < 60, server  # valid for credential_ttl_s from now
    assert server["credential"] == turn_rest_credential(SECRET.encode(), int(expiry))[1]
    offered = candidates(offer_sdp)
    assert offered and {kind for _, kind in offered} == {"relay"}, offered  # the page's only way: the relay
    assert {address for address, _ in offered} == {turn.address}
    # eca's own peer allocated a relay too, with a credential it minted, beside its host addresses
    answered = candidates(answer_sdp)
    assert (turn.address, "relay") in answered and any(kind == "host" for _, kind in answered), answered
    assert len(client.frames_of("ada")) >= 10, turn.log()  # the face frames came through the relay...
    # ...and the voice: its 1.5 s tone (75 frames of 20 ms; the voice to a page that draws pauses in silence)
    assert loud >= 50, (sounds, loud, turn.log())
    assert sum("ALLOCATE processed, success" in line for line in turn.lines) >= 2, turn.log()


LOCAL_CANDIDATES = """
    const done = arguments[0];
    window.eca.pc.getStats().then((stats) => { const found = [];
      stats.forEach((r) => { if (r.type === "local-candidate") found.push([r.address, r.candidateType]); });
      done(found); });"""


@needs_network
@needs_turn
@needs_head
@pytest.mark.skipif(browser_available() is not None, reason=str(browser_available()))
def test_the_page_in_a_real_browser_takes_the_servers_and_gets_a_relay_with_its_minted_credential(
        relayed_web: tuple[BusConfig, WebService], turn: TurnServer) -> None:
    _config, service = relayed_web
    with chromium() as driver:
        driver.get(service.url + "?mic=0")
        driver.find_element("id", "connect").click()
        wait_for(driver, "return window.eca.drawn.ada ? window.eca.drawn.ada.stats.received : 0", 30.0,
                 "the page drawing ada from face frames", lambda n: n >= 5)
        servers = driver.execute_script("return window.eca.pc.getConfiguration().iceServers")
        gathered = driver.execute_async_script(LOCAL_CANDIDATES)
    [server] = servers
    assert server["urls"] == [turn.url] or server["urls"] == turn.url, server
    assert server["username"].endswith(":eca"), server
    assert [turn.address, "relay"] in gathered, (gathered, turn.log())  # coturn took the page's credential


@needs_network
@needs_turn
def test_a_credential_minted_from_another_secret_gets_no_relay(turn: TurnServer) -> None:
    """The control: the TURN server checks what eca mints (a wrong secret allocates nothing)."""
    async def relay_candidates(secret: str) -> list[tuple[str, str]]:
        username, credential = turn_rest_credential(secret.encode(), int(time.time()) + 600)
        pc = RTCPeerConnection(relay_only([{"urls": turn.url, "username": username, "credential": credential}]))
        pc.addTransceiver("audio", direction="recvonly")
        await pc.setLocalDescription(await pc.createOffer())
        found = candidates(pc.localDescription.sdp)
        await pc.close()
        return found

    assert asyncio.run(relay_candidates("not-the-secret")) == []
    assert asyncio.run(relay_candidates(SECRET)) == [(turn.address, "relay")]


@pytest.fixture
def two_webs(network: Network) -> Iterator[tuple[WebService, WebService]]:
    held = IceSettings(interfaces=(network.root_address,))
    with private_bus_config() as config, BrokerThread(config):
        free = WebService(config, WebOptions(port=0, face="head", draw="browser"))
        kept = WebService(config, WebOptions(port=0, face="head", draw="browser", ice=held))
        with ServiceThread(free), ServiceThread(kept):
            yield free, kept


@needs_network
@needs_head
def test_the_host_candidates_offered_can_be_held_to_named_interfaces(
        network: Network, two_webs: tuple[WebService, WebService]) -> None:
    async def answered(service: WebService) -> list[tuple[str, str]]:
        client = FaceClient(f"http://127.0.0.1:{service.port}/", ["ada"])
        answer = await client.connect()
        await client.pc.close()
        return candidates(answer["sdp"])

    async def both() -> tuple[list[tuple[str, str]], list[tuple[str, str]]]:
        free, kept = two_webs
        got = await asyncio.gather(answered(free), answered(kept))  # at once: each keeps its own settings
        return got[0], got[1]

    free, kept = asyncio.run(both())
    assert {address for address, _ in kept} == {network.root_address}, kept  # the bridge's address only
    assert network.root_address in {address for address, _ in free} and len({a for a, _ in free}) > 1, free


def test_the_default_peer_asks_no_outside_server() -> None:
    """aiortc given no configuration asks Google's public STUN server; eca's peers get an empty list."""
    assert configuration(IceSettings()).iceServers == []
    assert options_from_table({}).ice == IceSettings()
    chosen = IceSettings(servers=ice_from_table({"servers": ["stun:a.example", "stun:b.example:3479",
                                                             "turns:t.example", "turn:u.example"],
                                                 "username": "u", "credential": "p"}).servers,
                         username="u", credential="p").for_peer()
    assert chosen == [("stun:a.example", None, None), ("turns:t.example", "u", "p")]


@pytest.mark.parametrize(("table", "said"), [
    ({"servers": "stun:a.example"}, "servers must be a list"),
    ({"servers": ["http://a.example"]}, "is not a STUN or TURN server's URL"),
    ({"servers": ["stun:a.example:70000"]}, "the port must lie in 1..65535"),
    ({"servers": ["stun:a.example?transport=udp"]}, "a STUN server's URL has no transport"),
    ({"servers": ["turns:a.example?transport=udp"]}, "TURN over TLS runs over TCP"),
    ({"servers": ["stun:" + "a" * 600]}, "a server is a URL of 1-512 characters"),
    ({"servers": ["stun:a.example"] * 9}, "at most 8"),
    ({"servers": ["turn:a.example"]}, "a TURN server needs credentials"),
    ({"servers": ["stun:a.example"], "username": "u", "credential": "p"}, "no TURN server"),
    ({"servers": ["turn:a.example"], "username": "u", "credential": "p\n"}, "credential must be 1-512 printable"),
    ({"servers": ["turn:a.example"], "username": "u", "credential": "p", "credential_ttl_s": 5}, "credential_ttl_s"),
    ({"transport_policy": "relay"}, "name one in servers"),
    ({"transport_policy": "none"}, "transport_policy must be one of all, relay"),
    ({"interfaces": ["eth0; rm -rf /"]}, "names of network interfaces"),
    ({"interfaces": ["127.0.0.1"]}, "loopback"),
    ({"interfaces": "eth0"}, "interfaces must be a list"),
    ({"stun": ["stun:a.example"]}, "unknown key 'stun'"),
    ({"servers": ["turn:a.example"], "secret_file": "/nonexistent/eca-secret"}, "cannot read /nonexistent/eca-secret"),
])
def test_ice_settings_that_cannot_be_are_refused_naming_what(table: dict[str, Any], said: str) -> None:
    with pytest.raises(IceSettingsError, match=re.escape(said)) as refused:
        ice_from_table(table)
    assert "[web.ice]" in str(refused.value)
    with pytest.raises(WebOptionsError, match=re.escape(said)):  # through the [web] table, as a config gives it
        options_from_table({"ice": table})


def test_secrets_come_from_files_read_whole_and_bounded(tmp_path: Path) -> None:
    secret = tmp_path / "secret"
    secret.write_text(SECRET + "\n")
    ice = ice_from_table({"servers": ["turn:a.example"], "secret_file": str(secret)})
    assert ice.secret == SECRET.encode()
    username, credential = ice.credentials()
    assert username is not None and credential == turn_rest_credential(SECRET.encode(), int(username.split(":")[0]))[1]
    (tmp_path / "big").write_bytes(b"x" * 10_000)
    (tmp_path / "binary").write_bytes(b"\xff\xfe\x00secret")
    for name, said in (("big", "must hold 1-512 bytes"), ("binary", "printable UTF-8")):
        with pytest.raises(IceSettingsError, match=re.escape(said)):
            ice_from_table({"servers": ["turn:a.example"], "secret_file": str(tmp_path / name)})
    with pytest.raises(IceSettingsError, match="not both"):
        ice_from_table({"servers": ["turn:a.example"], "username": "u", "credential": "p",
                        "credential_file": str(secret)})


def test_eca_web_with_interfaces_this_host_lacks_stops_with_one_line() -> None:
    with private_bus_config(agents=["ada"], extra='[web.ice]\ninterfaces = ["nothere0", "192.0.2.254"]\n') as config:
        done = subprocess.run([sys.executable, "-m", "eca.services.tools.cli", "web", "--config",
                               str(config.config_path), "--web-port", "0", "--web-face", "head", "--web-draw",
                               "browser"],
                              capture_output=True, text=True, cwd=ROOT, timeout=60)
    assert done.returncode == 2, (done.returncode, done.stderr[-2000:])
    lines = [line for line in done.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and "none of nothere0, 192.0.2.254 is on this host" in lines[0], done.stderr[-2000:]
