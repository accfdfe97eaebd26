"""A conversation per visitor (`eca up --web --per-visitor`), through real processes: each page gets an agent of its
own, created over the bus; two pages' agents do not see each other's commands; a page that leaves frees its agent;
over the limit a page is told "busy, try again"; a page cannot watch or command another's agent.
"""

from __future__ import annotations

import asyncio
import re
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import pytest
import zmq

from eca.protocol.bus import Subscriber
from eca.protocol.endpoints import BusConfig
from eca.protocol.messages import AgentsState, EmotionState
from eca.services.processes.avatar.loader import DEFAULT_HEAD
from eca.services.processes.runtime import wait_until
from tests.support.browser import band_change, browser_available, canvas_pixels, chromium, head_box, wait_for
from tests.support.bus import eca_command, private_bus_config, running
from tests.support.web_client import ConversationPage as Visitor
from tests.support.web_client import FaceClient, post

pytestmark = [pytest.mark.slow, pytest.mark.skipif(not DEFAULT_HEAD.exists(), reason="the default head is not baked")]
MAX = 2


@pytest.fixture(scope="module")
def instance() -> Iterator[tuple[BusConfig, str]]:
    """`eca up --web --per-visitor` with faces the pages draw (no GL on the server), at most MAX conversations."""
    with private_bus_config(services=["dialogue", "gaze", "audio"]) as config:
        text, found = re.subn(r"^(\[conversations\][^\[]*?^max = )\d+", rf"\g<1>{MAX}", config.config_path.read_text(),
                              count=1, flags=re.MULTILINE | re.DOTALL)
        assert found, "the config has a [conversations] max to lower"
        config.config_path.write_text(text)
        argv = eca_command("up", "--config", str(config.config_path), "--instance", config.instance, "--quiet",
                           "--web", "--web-port", "0", "--per-visitor", "--face", "head", "--web-draw", "browser",
                           "--silent-audio")
        with running(argv) as (_proc, reader):
            reader.wait_for("[up] ready in", 90.0)
            line = reader.lines[reader.wait_for("[web] INFO serving http://", 10.0)]
            match = re.search(r"(http://\S+/)", line)
            assert match
            yield config, match.group(1)


@contextmanager
def subscriber(config: BusConfig, prefixes: list[str]) -> Iterator[Subscriber]:
    ctx: zmq.Context[zmq.Socket[bytes]] = zmq.Context()
    sub = Subscriber(ctx, config, prefixes)
    try:
        yield sub
    finally:
        sub.socket.close(0)
        ctx.term()


def live_agents(config: BusConfig) -> list[str]:
    """The agents list as the broker's last-value cache holds it now."""
    with subscriber(config, ["state.*.agents"]) as sub:
        for got in sub.wait_ready(10.0):
            if isinstance(got.message, AgentsState):
                return list(got.message.agents)
    return []


def test_each_visitor_gets_an_agent_of_its_own_and_frees_it_on_leaving(instance: tuple[BusConfig, str]) -> None:
    config, url = instance

    async def main() -> tuple[str, str, int, Any, int, Any]:
        a, _, _ = await Visitor.arrive(url)
        b, _, _ = await Visitor.arrive(url)
        assert a is not None and b is not None
        await a.wait_for_frames(a.agents[0], 5, 20.0)
        await b.wait_for_frames(b.agents[0], 5, 20.0)
        over, status, busy = await Visitor.arrive(url)  # a third, over the limit
        assert over is None
        # a's page commands its own agent; b's page may not command a's, nor watch it
        ok, _ = await a.command(type="set_emotion", name="surprised", intensity=1.0, transition_s=0.1)
        stolen, refused = await post(url + "command", {"key": b.key, "command": {
            "agent": a.agents[0], "type": "set_emotion", "name": "angry", "intensity": 1.0, "transition_s": 0.1}})
        spy = FaceClient(url, [a.agents[0]])
        spy_status, spy_answer = await post(url + "offer", {**await spy.offer_body(), "key": b.key})
        await spy.pc.close()
        assert ok == 202 and stolen == 403 and spy_status == 403, (ok, stolen, refused, spy_answer)
        await a.pc.close()
        await b.pc.close()
        return a.agents[0], b.agents[0], status, busy, stolen, refused

    with subscriber(config, ["state."]) as states:
        states.wait_ready(10.0)
        first, second, status, busy, _stolen, refused = asyncio.run(main())
        emotions: list[EmotionState] = []
        deadline = time.monotonic() + 10.0  # what the dialogue service published reaches us in its time
        while not any(m.agent == first and m.name == "surprised" for m in emotions) and time.monotonic() < deadline:
            got = states.recv(0.2)
            if got is not None and isinstance(got.message, EmotionState):
                emotions.append(got.message)
        emotions += [m.message for m in states.drain() if isinstance(m.message, EmotionState)]
    assert first != second and first.startswith("v-") and second.startswith("v-")
    assert status == 503 and busy["retry"] is True and "busy" in busy["error"], busy
    assert "conversation of its own" in refused["error"]
    assert any(m.agent == first and m.name == "surprised" for m in emotions)
    assert not any(m.agent == second and m.name != "natural" for m in emotions)  # nothing reached b's agent
    assert not any(m.name == "angry" for m in emotions)
    # the pages left: their agents are removed, and room is back for new visitors
    assert wait_until(lambda: not {first, second} & set(live_agents(config)), 20.0), live_agents(config)

    async def again() -> tuple[int, Any]:
        # The web service counts the instance's conversations from the agents list as its own bus loop reads it,
        # which may be a moment after this test's subscriber did: a visitor told busy with `retry` tries again.
        deadline = time.monotonic() + 10.0
        while True:
            visitor, status, answer = await Visitor.arrive(url)
            if visitor is not None:
                await visitor.pc.close()
            if status != 503 or not answer.get("retry") or time.monotonic() > deadline:
                return status, answer
            await asyncio.sleep(0.1)  # polling, as a visitor told to retry would: not synchronisation

    status, answer = asyncio.run(again())
    assert status == 201, (status, answer)


@pytest.mark.skipif(browser_available() is not None, reason=str(browser_available()))
def test_two_browsers_get_two_agents_that_do_not_see_each_others_commands(instance: tuple[BusConfig, str]) -> None:
    config, url = instance
    # the other test's visitors have left: their conversations end as the server sees their pages go
    assert wait_until(lambda: not [a for a in live_agents(config) if a.startswith("v-")], 30.0), live_agents(config)
    with chromium() as first, chromium() as second:
        agents = []
        for driver in (first, second):
            driver.get(url + "?mic=0")
            driver.find_element("id", "connect").click()
            wait_for(driver, "return window.eca.state", 30.0, "the page connecting", lambda s: s == "connected")
            wait_for(driver, "const f = Object.values(window.eca.drawn)[0]; return f ? f.stats.received : 0", 30.0,
                     "the page drawing its agent", lambda n: n >= 5)
            agents.append(driver.execute_script("return window.eca.agents[0]"))
        time.sleep(1.0)  # past the faces' first transitions (the behaviour under test is what changes after)
        before = [canvas_pixels(d) for d in (first, second)]
        box = head_box(before[1])
        # the first page's developer panel: "surprised" for its agent
        first.execute_script("[...document.querySelectorAll('#emotions button')]"
                             ".find((b) => b.textContent === 'surprised').click()")
        wait_for(first, "return document.getElementById('panel-status').textContent", 10.0, "the command sent",
                 lambda t: t.startswith("sent set_emotion"))
        time.sleep(1.5)  # the transition's time
        after = [canvas_pixels(d) for d in (first, second)]
        first.find_element("id", "connect").click()  # the first visitor leaves
        assert wait_until(lambda: agents[0] not in live_agents(config), 20.0)
        still = agents[1] in live_agents(config)
    assert agents[0] != agents[1] and all(a.startswith("v-") for a in agents), agents
    changed = band_change(before[0], after[0], head_box(before[0]), 0.22, 0.40)
    untouched = band_change(before[1], after[1], box, 0.22, 0.40)
    assert changed > 2.0, changed  # the first agent's brows went up
    assert untouched < 0.5 * changed, (changed, untouched)  # the second's did not
    assert still  # the second visitor's agent stays while its page does
