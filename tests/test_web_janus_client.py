"""The web service's client of Janus's HTTP API (eca/services/processes/web/janus.py) against a server that answers as
Janus's HTTP transport does (chunked, libmicrohttpd) over a slow link: an answer's chunks, and the chunk that ends
it, come apart."""

from __future__ import annotations

import asyncio
import json
from collections.abc import AsyncIterator, Awaitable, Callable
from contextlib import asynccontextmanager

import pytest
from aiohttp import web

from eca.services.processes.web.janus import MAX_ANSWER_BYTES, JanusClient, JanusError

LINK_S = 0.2  # how long the slow link holds an answer's rest: the client has read what came first by then

Answer = Callable[[web.Request, web.StreamResponse], Awaitable[None]]


@asynccontextmanager
async def janus_like(answer: Answer) -> AsyncIterator[tuple[str, list[object]]]:
    """A server at a URL of its own answering every POST through `answer`; also yields the list of the connections
    (transports) its requests came on."""
    connections: list[object] = []

    async def handle(request: web.Request) -> web.StreamResponse:
        connections.append(request.transport)
        response = web.StreamResponse(headers={"Content-Type": "application/json"})
        response.enable_chunked_encoding()
        await response.prepare(request)
        await answer(request, response)
        return response

    app = web.Application()
    app.router.add_post("/janus", handle)
    app.router.add_post("/janus/{rest:.*}", handle)
    runner = web.AppRunner(app)
    await runner.setup()
    site = web.TCPSite(runner, "127.0.0.1", 0)
    await site.start()
    port = runner.addresses[0][1]
    try:
        yield f"http://127.0.0.1:{port}/janus", connections
    finally:
        await runner.cleanup()


async def in_pieces(request: web.Request, response: web.StreamResponse) -> None:
    """Janus's answer to `create` in two chunks, the second and the end of the body after the slow link's delay."""
    body = json.dumps({"janus": "success", "transaction": (await request.json())["transaction"],
                       "data": {"id": 4242}}).encode()
    await response.write(body[:10])
    await asyncio.sleep(LINK_S)  # a slow link: the rest of the answer comes later (not synchronisation)
    await response.write(body[10:])
    await response.write_eof()


async def ended_apart(request: web.Request, response: web.StreamResponse) -> None:
    """The whole answer in one chunk, and the chunk that ends the body after the slow link's delay."""
    body = json.dumps({"janus": "success", "transaction": (await request.json())["transaction"],
                       "data": {"id": 7}}).encode()
    await response.write(body)
    await asyncio.sleep(LINK_S)
    await response.write_eof()


async def too_large(request: web.Request, response: web.StreamResponse) -> None:
    chunk = b" " * 65_536
    for _ in range(MAX_ANSWER_BYTES // len(chunk) + 2):
        await response.write(chunk)
    await response.write_eof()


def test_an_answer_in_chunks_that_come_apart_is_read_whole() -> None:
    """Read as it came (one read), the first chunk alone is not JSON: the publisher took that for a Janus that lost its
    mountpoints and made them again under its viewers."""
    async def run() -> int:
        async with janus_like(in_pieces) as (url, _):
            client = JanusClient(url)
            try:
                await client.open()
                return client.session_id
            finally:
                await client.close()

    assert asyncio.run(run()) == 4242


def test_an_answer_whose_end_comes_apart_keeps_the_connection_for_the_next_request() -> None:
    """Read to the end of its body, the connection goes back to the client's pool: the next request goes on it instead
    of a new connection, whose handshake took another round trip and doubled the way to Janus the page is told of."""
    async def run() -> list[object]:
        async with janus_like(ended_apart) as (url, connections):
            client = JanusClient(url)
            try:
                await client.open()  # create, then attach
                await client.keepalive()
            finally:
                await client.close()
            return connections

    connections = asyncio.run(run())
    assert len(connections) == 4  # create, attach, keepalive, destroy
    assert len({id(c) for c in connections}) == 1, connections


def test_an_answer_larger_than_janus_gives_is_refused_with_a_sentence() -> None:
    async def run() -> None:
        async with janus_like(too_large) as (url, _):
            client = JanusClient(url, timeout_s=20.0)
            try:
                await client.open()
            finally:
                await client.close()

    with pytest.raises(JanusError, match=f"more than {MAX_ANSWER_BYTES} bytes"):
        asyncio.run(run())
