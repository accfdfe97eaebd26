"""Several web workers (`eca up --web --per-visitor --web-workers N`): each a process of its own on its own port,
serving the conversations it made; HAProxy in front spreads the visitors; a worker that dies is restarted and removes
what its previous run left, while the other worker's visitors go on.
"""

from __future__ import annotations

import asyncio
import json
import os
import re
import signal
import subprocess
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from eca.protocol.endpoints import BusConfig
from eca.services.processes.avatar.loader import DEFAULT_HEAD
from eca.services.processes.runtime import wait_until
from eca.services.processes.web.conversations import Conversations
from eca.services.processes.web.options import (
    MAX_WORKERS,
    WebOptions,
    WebOptionsError,
    options_from_table,
    worker_of,
)
from tests.support.browser import browser_available, canvas_pixels, chromium, head_box, wait_for
from tests.support.bus import eca_command, private_bus_config, running
from tests.support.haproxy import balancer, free_ports
from tests.support.web_client import ConversationPage
from tests.test_web_conversations import live_agents

# --- the options ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize(("options", "says"), [
    ({"workers": 2}, "--per-visitor"),
    ({"workers": 0, "per_visitor": True}, "whole number in 1..16"),
    ({"workers": MAX_WORKERS + 1, "per_visitor": True}, "whole number in 1..16"),
    ({"workers": True, "per_visitor": True}, "whole number"),
    ({"workers": 2.0, "per_visitor": True}, "whole number"),
    ({"workers": 2, "worker": 3, "per_visitor": True}, "worker must lie in 1..workers"),
    ({"workers": 3, "per_visitor": True, "port": 65534}, "past 65535"),
])
def test_bad_worker_settings_are_refused_naming_them(options: dict[str, Any], says: str) -> None:
    with pytest.raises(WebOptionsError, match=re.escape(says)):
        WebOptions(**options).check()


def test_each_worker_has_its_name_and_port() -> None:
    options = WebOptions(workers=3, per_visitor=True, port=8080)
    ports = [WebOptions(**{**options.__dict__, "worker": i}).check().listen_port for i in (1, 2, 3)]
    assert ports == [8080, 8081, 8082]
    assert WebOptions(workers=3, worker=3, per_visitor=True, port=0).check().listen_port == 0  # any free port each
    assert [worker_of(n) for n in ("web", "web-2", "web-16")] == [1, 2, 16]
    assert [worker_of(n) for n in ("web-1", "web-17", "web-02", "web-", "webx", "gaze")] == [None] * 6
    with pytest.raises(WebOptionsError, match="unknown key 'worker'"):  # `eca up` says which; a config cannot
        options_from_table({"worker": 2})


def test_a_worker_names_its_conversations_and_finds_what_a_previous_run_left() -> None:
    mine, other = Conversations(15.0, "v2-"), Conversations(15.0, "v-")
    loop = asyncio.new_event_loop()
    try:
        mine.listed(set(), 0, 4)
        held = mine.begin(0, loop).agent
    finally:
        loop.close()
    assert re.fullmatch(r"v2-[0-9a-f]{10}", held), held
    created = [held, "v2-0123456789", "v-0123456789", "v12-0123456789", "v2-notahexid", "pipecat-bot"]
    assert mine.left_behind(created) == ["v2-0123456789"]
    assert other.left_behind(created) == ["v-0123456789"]


@pytest.mark.parametrize("argv", [
    ["up", "--web", "--web-workers", "2", "--seconds", "5"],
    ["web", "--per-visitor", "--web-workers", "2"],
])
def test_the_command_line_refuses_workers_it_cannot_start(argv: list[str]) -> None:
    with private_bus_config() as config:
        done = subprocess.run(eca_command(*argv, "--config", str(config.config_path), "--instance", config.instance),
                              capture_output=True, text=True, timeout=60)
    assert done.returncode == 2, done.stdout + done.stderr
    assert "web workers" in done.stderr, done.stderr
    assert "ready" not in done.stdout


# --- real workers ----------------------------------------------------------------------------------------------

def health(url: str) -> dict[str, Any]:
    with urllib.request.urlopen(url + "health", timeout=5) as answer:
        body: dict[str, Any] = json.loads(answer.read())
        return body


@pytest.fixture(scope="module")
def workers() -> Iterator[tuple[BusConfig, list[str], Any]]:
    """`eca up --web --per-visitor --web-workers 2` with faces the pages draw: the two workers' URLs."""
    with private_bus_config(services=["dialogue", "gaze", "audio"]) as config:
        port = free_ports(2)
        argv = eca_command("up", "--config", str(config.config_path), "--instance", config.instance, "--quiet",
                           "--web", "--web-port", str(port), "--per-visitor", "--web-workers", "2", "--face", "head",
                           "--web-draw", "browser", "--silent-audio")
        with running(argv) as (_proc, reader):
            reader.wait_for("[up] ready in", 90.0)
            urls = []
            for name in ("web", "web-2"):
                line = reader.lines[reader.wait_for(f"[{name}] INFO serving http://", 10.0)]
                match = re.search(r"(http://\S+/)", line)
                assert match
                urls.append(match.group(1))
            yield config, urls, reader


@pytest.mark.slow
@pytest.mark.skipif(not DEFAULT_HEAD.exists(), reason="the default head is not baked")
def test_each_worker_serves_its_own_visitors_and_haproxy_spreads_them(
        workers: tuple[BusConfig, list[str], Any]) -> None:
    config, urls, _reader = workers
    ports = [int(u.rstrip("/").rsplit(":", 1)[1]) for u in urls]
    assert ports[1] == ports[0] + 1, urls  # worker i on --web-port + i - 1
    assert [health(u)["instance"] for u in urls] == [u.removeprefix("http://").rstrip("/") for u in urls]

    async def direct() -> tuple[list[str], int, int, int]:
        first, _, _ = await ConversationPage.arrive(urls[0])
        second, _, _ = await ConversationPage.arrive(urls[1])
        assert first is not None and second is not None
        await first.wait_for_frames(first.agents[0], 5, 20.0)
        await second.wait_for_frames(second.agents[0], 5, 20.0)
        ok, _ = await second.command(type="set_emotion", name="happy", intensity=0.5, transition_s=0.1)
        # the first worker does not hold the second's conversation: its key opens nothing there
        elsewhere = ConversationPage(urls[0], second.agents)
        elsewhere.key = second.key
        refused, _ = await elsewhere.command(type="set_emotion", name="angry", intensity=1.0, transition_s=0.1)
        await elsewhere.pc.close()
        busy_viewers = health(urls[1])["viewers"]
        for page in (first, second):
            await page.pc.close()
        return [first.agents[0], second.agents[0]], ok, refused, busy_viewers

    agents, ok, refused, viewers_on_second = asyncio.run(direct())
    assert re.fullmatch(r"v-[0-9a-f]{10}", agents[0]) and re.fullmatch(r"v2-[0-9a-f]{10}", agents[1]), agents
    assert (ok, refused, viewers_on_second) == (202, 403, 1)
    assert wait_until(lambda: not set(agents) & set(live_agents(config)), 20.0), live_agents(config)

    # behind HAProxy (the shipped config): new visitors go to the workers in turn, each stays on its own
    servers = [(f"w{i}", u.removeprefix("http://").rstrip("/")) for i, u in enumerate(urls, 1)]
    with balancer(servers, check_inter_ms=300) as lb:
        async def through() -> list[str]:
            pages = [await ConversationPage.arrive(lb.url) for _ in range(2)]
            made = []
            for page, status, answer in pages:
                assert page is not None, (status, answer)
                await page.wait_for_frames(page.agents[0], 5, 20.0)
                made.append(page.agents[0])
            for page, _, _ in pages:
                assert page is not None
                await page.pc.close()
            return made

        spread = asyncio.run(through())
    assert sorted(a.split("-")[0] for a in spread) == ["v", "v2"], spread  # one on each worker


@pytest.mark.slow
@pytest.mark.skipif(not DEFAULT_HEAD.exists(), reason="the default head is not baked")
@pytest.mark.skipif(browser_available() is not None, reason=str(browser_available()))
def test_two_browsers_through_haproxy_draw_their_faces_each_from_its_own_worker(
        workers: tuple[BusConfig, list[str], Any], tmp_path: Path) -> None:
    config, urls, _reader = workers
    assert wait_until(lambda: not [a for a in live_agents(config) if a.startswith("v")], 30.0), live_agents(config)
    servers = [(f"w{i}", u.removeprefix("http://").rstrip("/")) for i, u in enumerate(urls, 1)]
    with balancer(servers, check_inter_ms=300) as lb, chromium() as first, chromium() as second:
        agents = []
        for driver in (first, second):
            driver.get(lb.url + "?mic=0")  # the page's own fetches carry HAProxy's cookie back
            driver.find_element("id", "connect").click()
            wait_for(driver, "return window.eca.state", 30.0, "the page connecting", lambda s: s == "connected")
            wait_for(driver, "const f = Object.values(window.eca.drawn)[0]; return f ? f.stats.received : 0", 30.0,
                     "the page drawing its agent", lambda n: n >= 5)
            agents.append(driver.execute_script("return window.eca.agents[0]"))
        pictures = [canvas_pixels(d) for d in (first, second)]
        for name, driver in (("first", first), ("second", second)):
            driver.save_screenshot(str(tmp_path / f"{name}.png"))  # what a person saw, kept for a failure's reader
        viewers = [health(u)["viewers"] for u in urls]
    assert sorted(a.split("-")[0] for a in agents) == ["v", "v2"], agents  # one conversation on each worker
    assert viewers == [1, 1], viewers
    for picture in pictures:
        top, bottom, left, right = head_box(picture)
        assert bottom - top > 0.5 * picture.shape[0]  # each page drew its head
    assert wait_until(lambda: not set(agents) & set(live_agents(config)), 20.0)  # the pages left: removed


@pytest.mark.slow
@pytest.mark.skipif(not DEFAULT_HEAD.exists(), reason="the default head is not baked")
def test_a_killed_worker_comes_back_and_removes_what_it_left_while_the_other_serves_on(
        workers: tuple[BusConfig, list[str], Any]) -> None:
    config, urls, reader = workers
    assert wait_until(lambda: not [a for a in live_agents(config) if a.startswith("v")], 30.0), live_agents(config)

    async def scenario() -> tuple[str, str, int, int]:
        stays, _, _ = await ConversationPage.arrive(urls[0])
        orphaned, _, _ = await ConversationPage.arrive(urls[1])
        assert stays is not None and orphaned is not None
        await orphaned.wait_for_frames(orphaned.agents[0], 3, 20.0)
        await stays.wait_for_frames(stays.agents[0], 3, 20.0)
        mark = len(reader.lines)
        os.kill(ready_pid(reader, "web-2"), signal.SIGKILL)
        before = len(stays.frames_of(stays.agents[0]))
        # the supervisor restarts it; meanwhile the first worker's visitor keeps its frames
        await asyncio.to_thread(reader.wait_for, "[web-2] INFO ready (pid", 60.0, mark)
        after = len(stays.frames_of(stays.agents[0]))
        await orphaned.pc.close()
        await stays.pc.close()
        return stays.agents[0], orphaned.agents[0], before, after

    kept, orphan, before, after = asyncio.run(scenario())
    assert after > before + 5, (before, after)  # frames went on while web-2 was down and starting again
    assert wait_until(lambda: orphan not in live_agents(config), 20.0), live_agents(config)
    assert any("removing 1 conversation(s) a previous run of this service left" in x and orphan in x
               for x in reader.lines), [x for x in reader.lines if "[web-2]" in x][-10:]
    assert wait_until(lambda: kept not in live_agents(config), 20.0)  # its page left: removed as ever
    assert health(urls[1])["ready"] is True


def ready_pid(reader: Any, name: str) -> int:
    """The pid the service's latest "ready" line gives."""
    line = [x for x in reader.lines if f"[{name}] INFO ready (pid" in x][-1]
    match = re.search(r"ready \(pid (\d+)\)", line)
    assert match
    return int(match.group(1))
