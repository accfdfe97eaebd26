"""Many eca hosts behind a real HAProxy (Debian's haproxy 2.6, the shipped eca/configs/haproxy.cfg rendered by
tests/support/haproxy.py): each host's `GET /health`; new visitors go to hosts with room and stay on theirs (the
SERVERID cookie); a full host is drained (no new visitors, its own still served); a visitor sent to a full host is
told busy by eca and HAProxy replays only that request (`POST /conversation`) on another host; a host killed takes
only its own conversations and new visitors are served by the others at once.

The first tests run HAProxy over small aiohttp hosts that answer /health with the real handler
(eca/services/processes/web/health.py): the balancer's rules, in seconds. The slow ones run three real
`eca up --web --per-visitor` hosts behind it, each a network namespace of its own with its address (as root;
ports of 127.0.0.1 otherwise), each with its private bus and a token for its pages, with WebRTC visitors (aiortc,
tests/support/web_client.py) whose signalling goes through HAProxy and whose media goes to their host.
"""

from __future__ import annotations

import asyncio
import json
import secrets
import time
from collections.abc import Iterator
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import aiohttp
import pytest
from aiohttp import web
from yarl import URL

from eca.services.processes.avatar.loader import DEFAULT_HEAD
from eca.services.processes.runtime import wait_until
from eca.services.processes.web.conversations import Conversations
from eca.services.processes.web.event_loop import EventLoopThread
from eca.services.processes.web.health import FREE_HEADER, READY_HEADER, health_handler, health_of
from eca.services.processes.web.tracks import VoiceTiming
from tests.support.haproxy import (
    Balancer,
    ConfigError,
    EcaHost,
    balancer,
    eca_hosts,
    free_port,
    haproxy_available,
    render_config,
)
from tests.support.netns import hosts, netns_available
from tests.support.web_client import FaceClient

needs_haproxy = pytest.mark.skipif(haproxy_available() is not None, reason=str(haproxy_available()))
CHECK_MS = 300  # the checks' interval in these tests (the shipped sample's comment suggests 1 s)


# --- /health on its own --------------------------------------------------------------------------------------


def viewer_places(max_viewers: int, watching: int, timing: VoiceTiming | None = None) -> SimpleNamespace:
    return SimpleNamespace(max_viewers=max_viewers, open=dict.fromkeys(range(watching)),
                           voice_timing=timing or VoiceTiming())


def test_health_counts_room_as_post_conversation_would() -> None:
    conversations = Conversations(15.0)
    places = viewer_places(16, 0)
    not_ready = health_of(places, conversations)
    assert (not_ready.ready, not_ready.free_conversations, not_ready.status) == (False, 0, 503)
    conversations.listed(set(), 0, 3)  # the dialogue service's first list: 0 of 3 made
    assert health_of(places, conversations) == type(not_ready)(True, 3, 3, 0)
    loop = asyncio.new_event_loop()
    conversations.begin(0, loop)  # one being made counts already, as begin counts it
    loop.close()
    conversations.listed(set(), 1, 3)  # and one made by someone else on the bus
    assert health_of(places, conversations).free_conversations == 1
    conversations.listed(set(), 2, 3)
    assert health_of(viewer_places(16, 0), conversations).status == 503  # made + being made = max: full
    assert health_of(viewer_places(2, 2), Conversations(15.0)).status == 503  # not ready, whatever the places
    roomy = Conversations(15.0)
    roomy.listed(set(), 0, 60)
    assert health_of(viewer_places(16, 15), roomy).free_conversations == 1  # the viewers' limit is the smaller
    assert health_of(viewer_places(16, 16), roomy).status == 503
    shared = health_of(viewer_places(4, 1), None)  # no conversation per visitor: a viewer's place is the room
    assert (shared.ready, shared.free_conversations, shared.max_conversations, shared.status) == (True, 3, 4, 200)


def test_health_endpoint_answers_json_and_headers_and_ignores_input() -> None:
    conversations = Conversations(15.0)
    timing = VoiceTiming()
    for late_ms in (1, 5, 25, 70, 3):  # five voice frames: two later than 20 ms, one of them later than 60
        timing.record(late_ms * 1_000_000)

    async def main() -> list[tuple[int, dict[str, Any], dict[str, str]]]:
        app = web.Application()
        app.router.add_get("/health", health_handler(viewer_places(16, 1, timing), conversations))
        runner = web.AppRunner(app)
        await runner.setup()
        port = free_port()
        await web.TCPSite(runner, "127.0.0.1", port).start()
        got = []
        try:
            async with aiohttp.ClientSession() as session:
                for step in ("starting", "ready", "full"):
                    if step == "ready":
                        conversations.listed(set(), 0, 2)
                    elif step == "full":
                        conversations.listed(set(), 2, 2)
                    url = f"http://127.0.0.1:{port}/health?token=wrong&free_conversations=99&x=%00"
                    async with session.get(url, data=b"ignored") as response:
                        got.append((response.status, await response.json(), dict(response.headers)))
        finally:
            await runner.cleanup()
        return got

    starting, ready, full = asyncio.run(main())
    assert starting[0] == 503 and starting[1]["ready"] is False and starting[2][READY_HEADER] == "no"
    assert ready[0] == 200 and ready[1] == {"ready": True, "free_conversations": 2, "max_conversations": 2,
                                            "viewers": 1, "instance": ready[1]["instance"],
                                            "voice": {"frames": 5, "late_20ms": 2, "late_60ms": 1,
                                                      "max_late_ms": 70.0}}
    assert ready[1]["instance"].startswith("127.0.0.1:") and ready[2][FREE_HEADER] == "2"
    assert ready[2][READY_HEADER] == "yes" and ready[2]["Cache-Control"] == "no-store"
    assert full[0] == 503 and full[1]["ready"] is True and full[1]["free_conversations"] == 0
    assert full[2][READY_HEADER] == "yes" and full[2][FREE_HEADER] == "0"


# --- the configuration -------------------------------------------------------------------------------------------


@pytest.mark.parametrize(("servers", "bind", "socket_path", "inter", "names"), [
    ([], "127.0.0.1:80", "/tmp/a.sock", 1000, "at least one"),
    ([("h 1", "127.0.0.1:81")], "127.0.0.1:80", "/tmp/a.sock", 1000, "server name"),
    ([("h1\n    server evil", "127.0.0.1:81")], "127.0.0.1:80", "/tmp/a.sock", 1000, "server name"),
    ([("h1", "127.0.0.1:81 backup")], "127.0.0.1:80", "/tmp/a.sock", 1000, "server h1"),
    ([("h1", "127.0.0.1:81\nserver x 1.2.3.4:5")], "127.0.0.1:80", "/tmp/a.sock", 1000, "server h1"),
    ([("h1", "127.0.0.1:0")], "127.0.0.1:80", "/tmp/a.sock", 1000, "port"),
    ([("h1", "127.0.0.1:70000")], "127.0.0.1:80", "/tmp/a.sock", 1000, "port"),
    ([("h1", "[::zz]:81")], "127.0.0.1:80", "/tmp/a.sock", 1000, "IPv6"),
    ([("h1", "127.0.0.1:81"), ("h1", "127.0.0.1:82")], "127.0.0.1:80", "/tmp/a.sock", 1000, "differ"),
    ([("h1", "127.0.0.1:81")], "8080", "/tmp/a.sock", 1000, "bind"),
    ([("h1", "127.0.0.1:81")], "127.0.0.1:80", "a.sock", 1000, "stats_socket"),
    ([("h1", "127.0.0.1:81")], "127.0.0.1:80", "/tmp/a b.sock", 1000, "stats_socket"),
    ([("h1", "127.0.0.1:81")], "127.0.0.1:80", "/tmp/a.sock", 5, "check_inter_ms"),
    ([("h1", "127.0.0.1:81")], "127.0.0.1:80", "/tmp/a.sock", True, "check_inter_ms"),
])
def test_render_config_refuses_what_cannot_go_into_it(servers: list[tuple[str, str]], bind: str, socket_path: str,
                                                       inter: int, names: str) -> None:
    with pytest.raises(ConfigError, match=names):
        render_config(servers, bind, Path(socket_path), inter)


@needs_haproxy
def test_rendered_config_is_valid_for_haproxy(tmp_path: Path) -> None:
    import subprocess

    text = render_config([("h1", "127.0.0.1:8081"), ("h2", "[::1]:8082"), ("h3", "localhost:8083")],
                         "0.0.0.0:8080", tmp_path / "api.sock", 1000)
    (tmp_path / "haproxy.cfg").write_text(text)
    checked = subprocess.run(["haproxy", "-c", "-f", str(tmp_path / "haproxy.cfg")], capture_output=True, text=True)
    assert checked.returncode == 0, checked.stdout + checked.stderr
    assert "server h2 [::1]:8082 cookie h2 track eca/h2" in text and "{{" not in text.split("global", 1)[1]


# --- HAProxy's rules over small hosts with the real /health ------------------------------------------------------


@dataclass
class StubHost:
    """A host that answers /health with the real handler over counts the test sets, and its other routes with its
    name (and busy or not, as an eca host would)."""

    name: str
    conversations: Conversations = field(default_factory=lambda: Conversations(15.0))
    seen: list[str] = field(default_factory=list)

    def room(self, made: int, most: int) -> None:
        self.conversations.listed(set(), made, most)

    def app(self) -> web.Application:
        app = web.Application()
        viewers = viewer_places(16, 0)

        async def health(request: web.Request) -> web.StreamResponse:
            return await health_handler(viewers, self.conversations)(request)  # the counts as they are now

        async def anything(request: web.Request) -> web.Response:
            await request.read()
            self.seen.append(f"{request.method} {request.path}")
            if request.path == "/conversation":
                free = self.conversations.free()
                if not free:
                    return web.json_response({"error": "busy", "retry": True, "host": self.name}, status=503)
                self.room((self.conversations.created_count or 0) + 1, self.conversations.max_created or 0)
                return web.json_response({"host": self.name}, status=201)
            if request.path == "/offer":  # viewers full here: an offer must not be replayed elsewhere
                return web.json_response({"error": "full", "host": self.name}, status=503)
            return web.json_response({"host": self.name})

        app.router.add_get("/health", health)
        app.router.add_route("*", "/{tail:.*}", anything)
        return app


async def ask(session: aiohttp.ClientSession, method: str, url: str) -> tuple[int, Any, str | None]:
    """One request with the pages' token (an eca host off loopback wants it; the stub hosts ignore it)."""
    body = json.dumps({"token": TOKEN}).encode()
    async with session.request(method, url, data=body, params={"token": TOKEN}) as response:
        text = await response.text()
        cookie = response.cookies.get("SERVERID")
        try:
            body = json.loads(text)
        except json.JSONDecodeError:
            body = text
        return response.status, body, cookie.value if cookie is not None else None


def jar_with(url: str, host: str | None) -> aiohttp.CookieJar:
    jar = aiohttp.CookieJar(unsafe=True)  # unsafe: keep cookies of an IP address host (127.0.0.1), as browsers do
    if host is not None:
        jar.update_cookies({"SERVERID": host}, URL(url))
    return jar


@needs_haproxy
def test_haproxy_drains_a_full_host_and_replays_only_a_busy_conversation() -> None:
    a, b = StubHost("a"), StubHost("b")
    a.room(0, 1)
    b.room(0, 5)

    async def main() -> None:
        runners, servers = [], []
        for host in (a, b):
            runner = web.AppRunner(host.app())
            await runner.setup()
            port = free_port()
            await web.TCPSite(runner, "127.0.0.1", port).start()
            runners.append(runner)
            servers.append((host.name, f"127.0.0.1:{port}"))
        loop = asyncio.get_running_loop()
        manager = balancer(servers, CHECK_MS)
        lb: Balancer = await loop.run_in_executor(None, manager.__enter__)
        try:
            await rules(lb, loop)
        finally:
            await loop.run_in_executor(None, manager.__exit__, None, None, None)
            for runner in runners:
                await runner.cleanup()

    async def rules(lb: Balancer, loop: asyncio.AbstractEventLoop) -> None:
        assert lb.states() == {"a": "UP", "b": "UP"}
        # a fills up: drained (NOLB) in both backends, within a check or two
        a.room(1, 1)
        await loop.run_in_executor(None, lb.wait_for_states, {"a": "NOLB"}, 3.0)
        assert lb.states("eca_new")["a"] == "NOLB"
        async with aiohttp.ClientSession(cookie_jar=jar_with(lb.url, None)) as fresh:
            landed = {(await ask(fresh, "GET", lb.url))[1]["host"] for _ in range(4)}
        assert landed == {"b"}  # new visitors: only the host with room
        async with aiohttp.ClientSession(cookie_jar=jar_with(lb.url, "a")) as returning:
            page = await ask(returning, "GET", lb.url)
            assert page[:2] == (200, {"host": "a"})  # a drained host still serves its own visitors
            offer = await ask(returning, "POST", lb.url + "offer")
            assert offer[:2] == (503, {"error": "full", "host": "a"})  # not replayed: only a new conversation is
            made = await ask(returning, "POST", lb.url + "conversation")
            assert made == (201, {"host": "b"}, "b")  # a said busy; HAProxy asked b, and moved the visitor there
            assert (await ask(returning, "POST", lb.url + "offer"))[1]["host"] == "b"
        assert a.seen.count("POST /conversation") == 1 and a.seen.count("POST /offer") == 1
        # one retry, redispatched: HAProxy logs a request once it has answered it, so the line may come a moment later
        assert await loop.run_in_executor(None, wait_until, lambda: any(
            "eca_new/b" in line and "/+1 " in line for line in lb.log.lines), 5.0), lb.log.lines[-5:]
        # b stops being ready (a restart): DOWN after two failed checks; no host in rotation then
        b.conversations = Conversations(15.0)
        await loop.run_in_executor(None, lb.wait_for_states, {"a": "NOLB", "b": "DOWN"}, 5.0)
        async with aiohttp.ClientSession(cookie_jar=jar_with(lb.url, None)) as late:
            busy = await ask(late, "POST", lb.url + "conversation")
            assert busy[0] == 503 and busy[1]["retry"] is True and "busy" in busy[1]["error"]  # eca's words, as JSON
            page = await ask(late, "GET", lb.url)
            assert page[0] == 503 and "full" in page[1]
        async with aiohttp.ClientSession(cookie_jar=jar_with(lb.url, "a")) as returning:
            assert (await ask(returning, "GET", lb.url))[1] == {"host": "a"}
        b.room(0, 5)  # back: in rotation again after two good checks
        await loop.run_in_executor(None, lb.wait_for_states, {"b": "UP"}, 5.0)

    asyncio.run(main())


# --- real eca hosts -------------------------------------------------------------------------------------------


TOKEN = secrets.token_hex(16)  # the pages' token: hosts off loopback (in namespaces) want one
MAXIMA = {"h1": 1, "h2": 4, "h3": 4}  # h1 holds one conversation: the full host; the others keep room after a kill


class Visitor(FaceClient):
    """A page behind the balancer: its own cookie jar (the SERVERID cookie, as a browser keeps it), its
    conversation, and its WebRTC connection (the face frames on its data channel, the voice)."""

    session: aiohttp.ClientSession
    key: str = ""

    @classmethod
    async def arrive(cls, url: str, pinned: str | None = None) -> tuple[Visitor | None, int, Any]:
        """The page, `POST /conversation` and the offer, all through `url`. `pinned`: a cookie for that host
        already (a visitor who was there before)."""
        session = aiohttp.ClientSession(cookie_jar=jar_with(url, pinned))
        async with session.get(url, params={"token": TOKEN}) as page:
            assert page.status == 200, await page.text()
        status, made, _ = await ask_json(session, url + "conversation", {})
        if status != 201:
            await session.close()
            return None, status, made
        visitor = cls(url, [made["agent"]])
        visitor.session, visitor.key = session, made["key"]
        status, answer, _ = await ask_json(session, url + "offer", {**await visitor.offer_body(), "key": visitor.key})
        if status != 200:
            await visitor.leave()
            return None, status, answer
        await visitor.accept(answer)
        return visitor, 201, made

    @property
    def host(self) -> str:
        return next((c.value for c in self.session.cookie_jar if c.key == "SERVERID"), "")

    async def command(self, base: str | None = None) -> tuple[int, Any]:
        body = {"key": self.key, "command": {"type": "set_emotion", "agent": self.agents[0], "name": "happy",
                                             "intensity": 0.5, "transition_s": 0.2}}
        status, answer, _ = await ask_json(self.session, (base or self.base) + "command", body)
        return status, answer

    async def leave(self) -> None:
        await self.pc.close()
        await self.session.close()


async def ask_json(session: aiohttp.ClientSession, url: str, body: Any) -> tuple[int, Any, str | None]:
    async with session.post(url, json={**body, "token": TOKEN}) as response:
        text = await response.text()
        cookie = response.cookies.get("SERVERID")
        try:
            return response.status, json.loads(text), cookie.value if cookie is not None else None
        except json.JSONDecodeError:
            return response.status, text, cookie.value if cookie is not None else None


async def health(host: EcaHost) -> tuple[int, dict[str, Any]]:
    async with aiohttp.ClientSession() as session, session.get(host.url + "health") as response:
        return response.status, await response.json()


@dataclass
class Farm:
    hosts: dict[str, EcaHost]
    lb: Balancer
    loop: EventLoopThread
    visitors: list[Visitor] = field(default_factory=list)

    def run(self, coro: Any, timeout_s: float = 60.0) -> Any:
        return self.loop.call(coro, timeout_s)

    def on(self, name: str) -> list[Visitor]:
        return [v for v in self.visitors if v.host == name]

    def arrive(self, pinned: str | None = None) -> tuple[Visitor | None, int, Any]:
        visitor, status, answer = self.run(Visitor.arrive(self.lb.url, pinned))
        if visitor is not None:
            self.visitors.append(visitor)
        return visitor, status, answer

    def frames(self, visitor: Visitor, count: int, timeout_s: float = 30.0) -> int:
        """How many face frames `visitor` has had once `count` more arrived (or the time ran out)."""
        before = len(visitor.frames_of(visitor.agents[0]))
        got = self.run(visitor.wait_for_frames(visitor.agents[0], before + count, timeout_s), timeout_s + 10)
        return len(got) - before


@pytest.fixture(scope="module")
def farm() -> Iterator[Farm]:
    if not DEFAULT_HEAD.exists():
        pytest.skip("the default head is not baked")
    if haproxy_available() is not None:
        pytest.skip(str(haproxy_available()))
    loop = EventLoopThread("visitors").start()
    try:
        with ExitStack() as stack:
            # each eca host a network namespace of its own when this machine can make them (as root), else a port
            # of 127.0.0.1; HAProxy and the visitors on the test's own side
            network = None if netns_available() else stack.enter_context(hosts(*MAXIMA))
            started = stack.enter_context(eca_hosts(list(MAXIMA.values()), token=TOKEN,
                                                    network=[network[n] for n in MAXIMA] if network else None))
            by_name = dict(zip(MAXIMA, started, strict=True))
            with balancer([(name, host.address) for name, host in by_name.items()], CHECK_MS) as lb:
                farm = Farm(by_name, lb, loop)
                try:
                    yield farm
                finally:
                    for visitor in farm.visitors:
                        loop.call(visitor.leave(), 10.0)
    finally:
        loop.stop()


@pytest.mark.slow
@pytest.mark.timeout(400)
def test_visitors_are_spread_over_hosts_with_room_and_stay_on_theirs(farm: Farm) -> None:
    assert farm.lb.states() == {"h1": "UP", "h2": "UP", "h3": "UP"}
    for name, host in farm.hosts.items():
        status, said = farm.run(health(host))
        assert status == 200 and said["ready"] is True and said["free_conversations"] == MAXIMA[name], (name, said)
        assert said["instance"] == host.address
    # a visitor whose page came from h1 before (its cookie): h1 makes its conversation, and h1 is full then
    first, status, made = farm.arrive(pinned="h1")
    assert first is not None and first.host == "h1", (status, made)
    assert farm.frames(first, 5) >= 5  # a whole WebRTC connection whose signalling went through HAProxy
    farm.lb.wait_for_states({"h1": "NOLB"}, 3.0)
    # new visitors (no cookie): in turn over the hosts with room, never the full one
    second, _, _ = farm.arrive()
    third, _, _ = farm.arrive()
    assert second is not None and third is not None
    assert {second.host, third.host} == {"h2", "h3"}
    # sticky: each visitor's further requests reach its host, where alone its key is good
    for visitor in (first, second, third):
        assert farm.frames(visitor, 3) >= 3
        assert farm.run(visitor.command())[0] == 202
        for _ in range(3):
            async def page(v: Visitor = visitor) -> str | None:
                async with v.session.get(v.base + "config", params={"token": TOKEN}) as response:
                    assert response.status == 200
                return v.host
            assert farm.run(page()) == visitor.host
        for name, host in farm.hosts.items():  # the key straight at each host: only its own takes it
            status, _ = farm.run(visitor.command(host.url))
            assert status == (202 if name == visitor.host else 403), (name, visitor.host, status)
    counts = {name: farm.run(health(host))[1]["viewers"] for name, host in farm.hosts.items()}
    assert counts == {name: len(farm.on(name)) for name in farm.hosts} == {"h1": 1, "h2": 1, "h3": 1}


@pytest.mark.slow
@pytest.mark.timeout(400)
def test_a_visitor_sent_to_a_full_host_is_served_by_another(farm: Farm) -> None:
    if not farm.on("h1"):  # run alone: fill h1 first
        assert farm.arrive(pinned="h1")[0] is not None
    farm.lb.wait_for_states({"h1": "NOLB"}, 3.0)
    status, said = farm.run(health(farm.hosts["h1"]))
    assert status == 503 and said["ready"] is True and said["free_conversations"] == 0
    # a visitor HAProxy sends to h1 (its cookie says h1, as after the race of a check and an arrival): h1 answers
    # busy and creates nothing; HAProxy replays that one request on another host and moves the visitor there
    before = len(farm.hosts["h1"].log.lines)
    visitor, status, made = farm.arrive(pinned="h1")
    assert visitor is not None and visitor.host in ("h2", "h3"), (status, made)
    assert farm.frames(visitor, 3) >= 3
    assert wait_until(lambda: any("eca_new/" + visitor.host in line and "/+1 " in line for line in farm.lb.log.lines),
                      5.0), farm.lb.log.lines[-5:]  # HAProxy logs a request once it has answered it
    assert farm.run(health(farm.hosts["h1"]))[1]["viewers"] == 1  # h1 kept its own visitor, and no more
    assert not any("conversation v-" in line for line in farm.hosts["h1"].log.lines[before:])


@pytest.mark.slow
@pytest.mark.timeout(400)
def test_a_killed_host_takes_only_its_own_conversations(farm: Farm) -> None:
    for name in ("h2", "h3"):  # run alone: a visitor on each host with room
        if not farm.on(name):
            assert farm.arrive(pinned=name)[0] is not None
    # the host to kill: in rotation (it has room), with visitors of its own
    dead = max(("h2", "h3"), key=lambda n: MAXIMA[n] - len(farm.on(n)))
    alive = "h3" if dead == "h2" else "h2"
    victims, survivors = farm.on(dead), [v for v in farm.visitors if v.host != dead]
    assert victims and survivors and MAXIMA[alive] - len(farm.on(alive)) >= 1
    assert farm.lb.states()[dead] == "UP"
    farm.hosts[dead].kill()
    killed = time.monotonic()
    # new visitors at once: HAProxy has not seen the death yet (its turn comes up for every other new visitor), but
    # a refused connection is redispatched to a live host

    async def pages() -> list[tuple[int, str | None]]:
        got = []
        for _ in range(4):
            async with aiohttp.ClientSession(cookie_jar=jar_with(farm.lb.url, None)) as fresh:
                status, _, cookie = await ask(fresh, "GET", farm.lb.url)
                got.append((status, cookie))
        return got

    landed = farm.run(pages())
    assert all(status == 200 and cookie not in (dead, None) for status, cookie in landed), landed
    newcomer, status, made = farm.arrive()
    served_s = time.monotonic() - killed
    assert newcomer is not None and newcomer.host != dead, (status, made)
    assert farm.frames(newcomer, 3) >= 3
    farm.lb.wait_for_states({dead: "DOWN"}, 5.0)
    down_s = time.monotonic() - killed
    # the dead host's visitors: their requests fail (another host does not know their key), nothing hangs
    for visitor in victims:
        status, answer = farm.run(visitor.command())
        assert status == 403 and "conversation of its own" in answer["error"], (status, answer)
    # everyone else: still served, face frames still arriving
    for visitor in survivors:
        assert farm.frames(visitor, 5) >= 5
        assert farm.run(visitor.command())[0] == 202
    assert all(farm.hosts[n].process.poll() is None for n in farm.hosts if n != dead)
    print(f"after the kill: a new visitor served in {served_s:.2f} s; HAProxy marked the host DOWN in {down_s:.2f} s "
          f"(checks every {CHECK_MS} ms, fall 2)")
