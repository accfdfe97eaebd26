"""The web front-end's HTTP side (aiohttp): the page, WebRTC offers, and the page's commands.

Routes: `GET /` the page, `GET /static/<file>` its files, `POST /offer` a WebRTC offer answered with
the viewer's answer, `POST /command` one bus command from the page's developer panel. With a token
configured, every route wants it (`?token=` on the page, `token` in the JSON bodies): a request without
the right one gets 403 and nothing else happens. Every request body is bounded and checked field by
field; what is wrong comes back as `{"error": "<sentence naming the field>"}` with 400 (413 when too
large), and nothing is opened.
"""

from __future__ import annotations

import hmac
import json
import logging
import math
from pathlib import Path
from typing import Any

import msgpack
from aiohttp import web

from eca.agent.vocabulary import EYE_MODES
from eca.protocol.codec import ProtocolError, decode, describe, is_agent_id
from eca.protocol.messages import MESSAGE_TYPES, PROTOCOL_VERSION
from eca.services.processes.web.options import WebOptions
from eca.services.processes.web.viewers import Backend, Viewers, ViewRequest

log = logging.getLogger("web")

STATIC = Path(__file__).resolve().parent / "static"
PAGE_FILES = {"index.html": "text/html", "app.js": "text/javascript", "style.css": "text/css"}
MAX_BODY_BYTES = 64 * 1024  # an offer's SDP is a few kB
MAX_SDP_CHARS = 48 * 1024
MAX_STREAMS = 16


class BadRequest(ValueError):
    """What is wrong with a request, as a sentence for the page."""


def make_app(backend: Backend, viewers: Viewers, options: WebOptions, agents: tuple[str, ...]) -> web.Application:
    app = web.Application(client_max_size=MAX_BODY_BYTES, middlewares=[_errors_as_json])

    async def page(request: web.Request) -> web.StreamResponse:
        _check_token(options, request.query.get("token"))
        return web.FileResponse(STATIC / "index.html", headers={"Cache-Control": "no-store"})

    async def static(request: web.Request) -> web.StreamResponse:
        name = request.match_info["name"]
        if name not in PAGE_FILES:
            raise web.HTTPNotFound(text=json.dumps({"error": "no such file"}), content_type="application/json")
        return web.FileResponse(STATIC / name, headers={"Content-Type": PAGE_FILES[name], "Cache-Control": "no-store"})

    async def config(request: web.Request) -> web.Response:
        _check_token(options, request.query.get("token"))
        return web.json_response({"agents": list(agents), "eye_modes": list(EYE_MODES),
                                  "width": options.width, "height": options.height,
                                  "fps": options.fps, "max_width": options.max_width,
                                  "max_height": options.max_height, "max_fps": options.max_fps})

    async def offer(request: web.Request) -> web.Response:
        body = await _json_body(request)
        _check_token(options, body.get("token"))
        sdp, view = parse_offer(body, options, agents)
        if viewers.full:
            raise web.HTTPServiceUnavailable(text=json.dumps({"error": f"{viewers.max_viewers} viewers are "
                                                              "watching already; try again later"}),
                                             content_type="application/json")
        try:
            answer = await viewers.answer(sdp, view)
        except ValueError as exc:
            raise BadRequest(str(exc)) from None
        return web.json_response({"sdp": answer, "type": "answer", "width": view.width, "height": view.height,
                                  "fps": view.fps})

    async def command(request: web.Request) -> web.Response:
        body = await _json_body(request)
        _check_token(options, body.get("token"))
        backend.submit(parse_command(body.get("command"), agents))
        return web.json_response({"accepted": True}, status=202)

    app.router.add_get("/", page)
    app.router.add_get("/config", config)
    app.router.add_get("/static/{name}", static)
    app.router.add_post("/offer", offer)
    app.router.add_post("/command", command)
    return app


@web.middleware
async def _errors_as_json(request: web.Request, handler: Any) -> web.StreamResponse:
    try:
        return await handler(request)
    except BadRequest as exc:
        log.info("refused %s %s: %s", request.method, request.path, exc)
        return web.json_response({"error": str(exc)}, status=400)
    except web.HTTPRequestEntityTooLarge:
        return web.json_response({"error": f"the request is over {MAX_BODY_BYTES} bytes"}, status=413)
    except web.HTTPException:
        raise
    except Exception:  # a bug must cost one request, not the server
        log.exception("%s %s failed", request.method, request.path)
        return web.json_response({"error": "the web service failed on this request (an eca bug)"}, status=500)


def _check_token(options: WebOptions, given: Any) -> None:
    if options.token is None:
        return
    if not isinstance(given, str) or not hmac.compare_digest(given.encode(), options.token.encode()):
        raise web.HTTPForbidden(text=json.dumps({"error": "a wrong or missing token"}),
                                content_type="application/json")


async def _json_body(request: web.Request) -> dict[str, Any]:
    if request.content_length is not None and request.content_length > MAX_BODY_BYTES:
        raise web.HTTPRequestEntityTooLarge(max_size=MAX_BODY_BYTES, actual_size=request.content_length)
    raw = await request.read()  # bounded by client_max_size
    try:
        body = json.loads(raw)
    except (UnicodeDecodeError, json.JSONDecodeError):
        raise BadRequest("the body is not JSON") from None
    except RecursionError:
        raise BadRequest("the body is nested too deeply") from None
    if not isinstance(body, dict):
        raise BadRequest("the body must be a JSON object")
    return body


def parse_offer(body: dict[str, Any], options: WebOptions, agents: tuple[str, ...]) -> tuple[str, ViewRequest]:
    """The SDP and the request in an offer body, checked field by field against the limits."""
    sdp, kind = body.get("sdp"), body.get("type")
    if kind != "offer":
        raise BadRequest("'type' must be \"offer\"")
    if not isinstance(sdp, str) or not 0 < len(sdp) <= MAX_SDP_CHARS:
        raise BadRequest(f"'sdp' must be a string of 1-{MAX_SDP_CHARS} characters")
    watched = body.get("agents", [agents[0]])
    if not isinstance(watched, list) or not 1 <= len(watched) <= len(agents):
        raise BadRequest(f"'agents' must be a list of 1-{len(agents)} of: {', '.join(agents)}")
    for agent in watched:
        if agent not in agents:
            raise BadRequest(f"'agents': {describe(agent, 40)} is not an agent of this instance "
                             f"({', '.join(agents)})")
    if len(set(watched)) != len(watched):
        raise BadRequest("'agents' lists an agent twice")
    video = body.get("video", {})
    if not isinstance(video, dict):
        raise BadRequest("'video' must be an object with width, height and fps")
    width = _bounded_int(video, "width", options.width, 16, options.max_width)
    height = _bounded_int(video, "height", options.height, 16, options.max_height)
    fps = video.get("fps", options.fps)
    if isinstance(fps, bool) or not isinstance(fps, int | float) or not math.isfinite(fps) or not 1 <= fps <= 60:
        raise BadRequest("'video.fps' must be a number in [1, 60]")
    streams = body.get("streams")
    if not isinstance(streams, list) or not 0 < len(streams) <= MAX_STREAMS:
        raise BadRequest(f"'streams' must list 1-{MAX_STREAMS} received sections as {{mid, agent, kind}}")
    parsed = []
    for i, item in enumerate(streams):
        if not isinstance(item, dict) or set(item) != {"mid", "agent", "kind"}:
            raise BadRequest(f"'streams[{i}]' must be an object with mid, agent and kind")
        mid, agent, stream_kind = item["mid"], item["agent"], item["kind"]
        if not isinstance(mid, str) or not 0 < len(mid) <= 32:
            raise BadRequest(f"'streams[{i}].mid' must be a string of 1-32 characters")
        if agent not in watched:
            raise BadRequest(f"'streams[{i}].agent' must be one of the agents watched")
        if stream_kind not in ("video", "audio"):
            raise BadRequest(f"'streams[{i}].kind' must be \"video\" or \"audio\"")
        parsed.append((mid, agent, stream_kind))
    mic = body.get("mic_mid")
    if mic is not None and (not isinstance(mic, str) or not 0 < len(mic) <= 32):
        raise BadRequest("'mic_mid' must be null or a string of 1-32 characters")
    if len({p[0] for p in parsed} | ({mic} if mic else set())) != len(parsed) + (1 if mic else 0):
        raise BadRequest("'streams' and 'mic_mid' must name each section once")
    calibration = body.get("calibration", False)
    if not isinstance(calibration, bool):
        raise BadRequest("'calibration' must be true or false")
    # even sizes: the encoders work on 2x2 chroma blocks
    view = ViewRequest(tuple(watched), width - width % 2, height - height % 2, min(float(fps), options.max_fps),
                       tuple(parsed), mic, calibration)
    return sdp, view


def _bounded_int(table: dict[str, Any], key: str, default: int, lo: int, hi: int) -> int:
    value = table.get(key, default)
    if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
        raise BadRequest(f"'video.{key}' must be a whole number in {lo}..{hi}")
    return value


def parse_command(command: Any, agents: tuple[str, ...]) -> Any:
    """A bus command from the page (`{"type": ..., "agent": ..., fields}`), checked by the protocol's own
    codec: the page speaks the wire's field names and limits."""
    if not isinstance(command, dict):
        raise BadRequest("'command' must be an object with the command's type, agent and fields")
    kind = command.get("type")
    cls = MESSAGE_TYPES.get(kind) if isinstance(kind, str) else None
    if cls is None or cls.CATEGORY != "cmd":
        commands = sorted(t for t, c in MESSAGE_TYPES.items() if c.CATEGORY == "cmd")
        raise BadRequest(f"'command.type' must be one of {', '.join(commands)}")
    agent = command.get("agent")
    if not (isinstance(agent, str) and is_agent_id(agent) and agent in agents):
        raise BadRequest(f"'command.agent' must be one of {', '.join(agents)}")
    payload = {k: v for k, v in command.items() if k not in ("v", "seq", "t_ns", "source")}
    try:
        return decode(msgpack.packb({**payload, "v": PROTOCOL_VERSION, "source": "web-page"}, use_bin_type=True))
    except ProtocolError as exc:
        raise BadRequest(f"'command': {exc}") from None
    except (TypeError, ValueError, OverflowError):  # msgpack cannot pack what JSON gave (a huge integer)
        raise BadRequest("'command' holds a value the bus cannot carry") from None
