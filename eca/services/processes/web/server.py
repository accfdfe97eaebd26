"""The web front-end's HTTP side (aiohttp): the page, WebRTC offers, and the page's commands.

Routes: `GET /` the page, `GET /static/<path>` its files (the page's own and the vendored three.js and
three-vrm, static/vendor/), `GET /avatars/<slot>/<file>` the avatar file of a face the page draws itself (and,
for a .gltf, the buffers and images it names; nothing else of its folder), `POST /offer` a WebRTC offer answered
with the viewer's answer, `POST /command` one bus command from the page's developer panel, `GET /health` readiness
and free conversations for a load balancer (web/health.py; no token: it tells only counts). With a token
configured, every route but the page's static files wants it (`?token=` on the page and the avatars, or an
`X-Eca-Token` header; `token` in the JSON bodies): a request without the right one gets 403 and nothing else
happens. Every request body is bounded and checked field by
field; what is wrong comes back as `{"error": "<sentence naming the field>"}` with 400 (413 when too
large), and nothing is opened.
"""

from __future__ import annotations

import hmac
import json
import logging
import math
import time
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any
from urllib.parse import quote, unquote

from aiohttp import web

from eca.agent.vocabulary import EYE_MODES
from eca.protocol.codec import ProtocolError, decode, describe, is_agent_id, packb
from eca.protocol.messages import MESSAGE_TYPES, PROTOCOL_VERSION
from eca.services.processes.web.conversations import Busy, Conversation, Conversations
from eca.services.processes.web.face_frames import FaceFrames
from eca.services.processes.web.health import health_handler
from eca.services.processes.web.options import WebOptions
from eca.services.processes.web.viewers import Backend, Viewers, ViewRequest

log = logging.getLogger("web")

STATIC = Path(__file__).resolve().parent / "static"
CONTENT_TYPES = {".html": "text/html", ".js": "text/javascript", ".css": "text/css", ".md": "text/plain",
                 ".txt": "text/plain"}
MAX_STATIC_FILES = 256
MAX_GLTF_JSON_BYTES = 16 * 1024 * 1024  # a .gltf whose JSON is larger is served alone (its resources are not)
MAX_BODY_BYTES = 64 * 1024  # an offer's SDP is a few kB
MAX_SDP_CHARS = 48 * 1024
MAX_STREAMS = 16


class BadRequest(ValueError):
    """What is wrong with a request, as a sentence for the page."""


def page_files(root: Path = STATIC) -> dict[str, Path]:
    """The page's files by their path under static/ (what `GET /static/<path>` serves; nothing else)."""
    files: dict[str, Path] = {}
    for path in sorted(root.rglob("*")):
        if path.is_file() and path.suffix in CONTENT_TYPES and not path.is_symlink():
            files[path.relative_to(root).as_posix()] = path
            if len(files) > MAX_STATIC_FILES:
                raise RuntimeError(f"more than {MAX_STATIC_FILES} files under {root}")
    return files


def avatar_files(path: Path) -> dict[str, Path]:
    """What `GET /avatars/<slot>/<name>` serves of one avatar: the file itself and, for a .gltf, the buffers and
    images its JSON names by a relative URI inside its folder (each resolved there: none reaches outside it)."""
    files = {path.name: path}
    if path.suffix.lower() != ".gltf" or path.stat().st_size > MAX_GLTF_JSON_BYTES:
        return files
    try:
        document = json.loads(path.read_bytes())
    except (ValueError, RecursionError):
        return files  # the loader refused it already, or will
    folder = path.parent.resolve()
    for key in ("buffers", "images"):
        items = document.get(key) if isinstance(document, dict) else None
        for item in items if isinstance(items, list) else []:
            uri = item.get("uri") if isinstance(item, dict) else None
            if not isinstance(uri, str) or ":" in uri or uri.startswith("/") or len(uri) > 1024:
                continue  # data: URIs and absolute ones are not files of the folder
            target = (folder / unquote(uri)).resolve()
            if target.is_relative_to(folder) and target.is_file():
                files[uri] = target
    return files


def make_app(backend: Backend, viewers: Viewers, options: WebOptions, agents: tuple[str, ...],
             face_frames: FaceFrames | None = None, conversations: Conversations | None = None,
             create_conversation: Callable[[], Awaitable[Conversation]] | None = None) -> web.Application:
    """The routes. With `conversations` (a conversation per visitor), a page asks `POST /conversation` for an agent
    of its own and watches (and commands) only that one, with its key."""
    app = web.Application(client_max_size=MAX_BODY_BYTES, middlewares=[_errors_as_json])
    static_files = page_files()
    avatars: dict[Path, int] = {}  # each avatar file served, by its number in /avatars/<n>/
    served: dict[int, dict[str, Path]] = {}

    def may_draw(agent: str) -> bool:
        return face_frames is not None and options.draw != "server" and face_frames.drawable(agent)

    def drawable() -> list[str]:
        return [a for a in agents if may_draw(a)]

    def avatar_url(agent: str) -> str:
        assert face_frames is not None
        path = face_frames.files[agent]
        if path not in avatars:
            avatars[path] = len(avatars)
            served[avatars[path]] = avatar_files(path)
        return f"avatars/{avatars[path]}/{quote(path.name)}"

    def own_agents(body: dict[str, Any], field: str) -> tuple[str, ...]:
        """The agents a request may name: the instance's, or with conversations the page's own (its key)."""
        if conversations is None:
            return agents
        asked = body.get("agents") if field == "agents" else (body.get("command") or {}).get("agent")
        agent = asked[0] if isinstance(asked, list) and len(asked) == 1 else asked
        if isinstance(agent, str) and conversations.check_key(agent, body.get("key")):
            return (agent,)
        raise web.HTTPForbidden(text=json.dumps({"error": "each page of this instance has a conversation of its "
                                                 "own: POST /conversation, then name its agent with its key"}),
                                content_type="application/json")

    async def conversation(request: web.Request) -> web.Response:
        body = await _json_body(request)
        _check_token(options, body.get("token"))
        if conversations is None or create_conversation is None:
            raise web.HTTPNotFound(text=json.dumps({"error": "this instance has no conversation per visitor "
                                                    "(--per-visitor)"}), content_type="application/json")
        if viewers.full:  # a conversation needs a viewer's place too: none is made that could not be watched
            return web.json_response({"error": f"busy: {viewers.max_viewers} viewers are watching already; try again "
                                               "later", "retry": True}, status=503)
        try:
            made = await create_conversation()
        except Busy as exc:
            return web.json_response({"error": str(exc), "retry": True}, status=503)
        return web.json_response({"agent": made.agent, "key": made.key, "drawable": may_draw(made.agent)},
                                 status=201)

    async def page(request: web.Request) -> web.StreamResponse:
        _check_token(options, request.query.get("token"))
        backend.expect_viewer()
        return web.FileResponse(STATIC / "index.html", headers={"Cache-Control": "no-store"})

    async def static(request: web.Request) -> web.StreamResponse:
        path = static_files.get(request.match_info["path"])
        if path is None:
            raise web.HTTPNotFound(text=json.dumps({"error": "no such file"}), content_type="application/json")
        # the page's own files may change with eca; the vendored libraries only with their version's folder
        cache = "max-age=86400" if request.match_info["path"].startswith("vendor/") else "no-store"
        return web.FileResponse(path, headers={"Content-Type": CONTENT_TYPES[path.suffix], "Cache-Control": cache})

    async def avatar(request: web.Request) -> web.StreamResponse:
        _check_token(options, request.query.get("token") or request.headers.get("X-Eca-Token"))
        slot_text, name = request.match_info["slot"], request.match_info["name"]
        files = served.get(int(slot_text)) if slot_text.isdigit() and len(slot_text) < 6 else None
        path = files.get(name) if files is not None else None
        if path is None:
            raise web.HTTPNotFound(text=json.dumps({"error": "no such avatar file"}), content_type="application/json")
        return web.FileResponse(path, headers={"Content-Type": "application/octet-stream",
                                               "Cache-Control": "no-store"})

    def sfu_info() -> dict[str, Any] | None:
        """Where pages watch through Janus, with what they need to draw each face whose frames go there."""
        sfu: dict[str, Any] | None = getattr(backend, "sfu_info", lambda: None)()
        if sfu is None or face_frames is None:
            return sfu
        return {**sfu, "faces": {a: face_frames.description(a, avatar_url(a)) for a in sfu.get("faces", ())}}

    async def config(request: web.Request) -> web.Response:
        _check_token(options, request.query.get("token"))
        return web.json_response({"agents": list(agents), "eye_modes": list(EYE_MODES),
                                  "width": options.width, "height": options.height,
                                  "fps": options.fps, "max_width": options.max_width,
                                  "max_height": options.max_height, "max_fps": options.max_fps,
                                  "draw": options.draw, "drawable": drawable(),
                                  "per_visitor": conversations is not None,
                                  # STUN/TURN servers for the page's peers, TURN credentials minted now (web/ice.py)
                                  "ice_servers": options.ice.for_page(),
                                  # with an SFU: where pages watch each agent through Janus (web/sfu.py)
                                  "sfu": sfu_info()})

    async def clock(request: web.Request) -> web.Response:
        """This machine's wall clock (Unix ms), for a page that watches through Janus to learn how far its own clock
        is from the one the face frames are stamped with (static/face3d.js VoiceClock: it keeps the quickest of
        several asks, as NTP does)."""
        _check_token(options, request.query.get("token"))
        return web.json_response({"unix_ms": time.time_ns() / 1e6}, headers={"Cache-Control": "no-store"})

    async def offer(request: web.Request) -> web.Response:
        body = await _json_body(request)
        _check_token(options, body.get("token"))
        allowed = own_agents(body, "agents")
        sdp, view = parse_offer(body, options, allowed, tuple(a for a in allowed if may_draw(a)))
        if viewers.full:
            raise web.HTTPServiceUnavailable(text=json.dumps({"error": f"{viewers.max_viewers} viewers are "
                                                              "watching already; try again later"}),
                                             content_type="application/json")
        try:
            answer = await viewers.answer(sdp, view)
        except ValueError as exc:
            raise BadRequest(str(exc)) from None
        faces = {}
        if face_frames is not None:
            faces = {a: face_frames.description(a, avatar_url(a)) for a in view.drawn_here}
        return web.json_response({"sdp": answer, "type": "answer", "width": view.width, "height": view.height,
                                  "fps": view.fps, "faces": faces})

    async def command(request: web.Request) -> web.Response:
        body = await _json_body(request)
        _check_token(options, body.get("token"))
        backend.submit(parse_command(body.get("command"), own_agents(body, "command")))
        return web.json_response({"accepted": True}, status=202)

    app.router.add_get("/", page)
    app.router.add_get("/config", config)
    app.router.add_get("/clock", clock)
    app.router.add_get("/static/{path:.+}", static)
    app.router.add_get("/avatars/{slot}/{name:.+}", avatar)
    app.router.add_post("/offer", offer)
    app.router.add_post("/conversation", conversation)
    app.router.add_post("/command", command)
    app.router.add_get("/health", health_handler(viewers, conversations))  # web/health.py: for a load balancer
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


def parse_offer(body: dict[str, Any], options: WebOptions, agents: tuple[str, ...],
                drawable: tuple[str, ...] = ()) -> tuple[str, ViewRequest]:
    """The SDP and the request in an offer body, checked field by field against the limits. `drawable`: the
    agents a page may draw itself (`draw_here`; its other agents come as video)."""
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
    drawn_here = _drawn_here(body.get("draw_here", []), watched, drawable, options.draw, parsed)
    # even sizes: the encoders work on 2x2 chroma blocks
    view = ViewRequest(tuple(watched), width - width % 2, height - height % 2, min(float(fps), options.max_fps),
                       tuple(parsed), mic, calibration, drawn_here)
    return sdp, view


def _drawn_here(value: Any, watched: list[str], drawable: tuple[str, ...], draw: str,
                streams: list[tuple[str, str, str]]) -> tuple[str, ...]:
    """The agents an offer draws itself, checked: each watched and drawable, with a voice section and no video
    one; under `draw = "browser"` every watched agent."""
    if not isinstance(value, list) or len(value) > len(watched):
        raise BadRequest("'draw_here' must be a list of the watched agents the page draws itself")
    for agent in value:
        if agent not in watched:
            raise BadRequest(f"'draw_here': {describe(agent, 40)} is not one of the agents watched")
        if agent not in drawable:
            why = ("this server sends every face as video (draw = \"server\")" if draw == "server"
                   else "its face is the 2D face, which only the server draws")
            raise BadRequest(f"'draw_here': {agent} cannot be drawn by the page: {why}")
    if len(set(value)) != len(value):
        raise BadRequest("'draw_here' lists an agent twice")
    if draw == "browser" and set(value) != set(watched):
        raise BadRequest("this server draws no faces (draw = \"browser\"): the page must draw every agent it "
                         "watches, which needs WebGL")
    for agent in value:
        kinds = [kind for _, a, kind in streams if a == agent]
        if "video" in kinds or "audio" not in kinds:
            raise BadRequest(f"'streams': {agent}, drawn by the page, takes an audio section and no video one")
    return tuple(value)


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
        return decode(packb({**payload, "v": PROTOCOL_VERSION, "source": "web-page"}))
    except ProtocolError as exc:
        raise BadRequest(f"'command': {exc}") from None
    except (TypeError, ValueError, OverflowError):  # msgpack cannot pack what JSON gave (a huge integer)
        raise BadRequest("'command' holds a value the bus cannot carry") from None
