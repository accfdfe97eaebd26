"""The web service's settings: where it listens, who may connect, and the limits of what a page may ask.

From the config's [web] table, overridden on the command line (`eca up --web --web-host ...`, `eca web
...`). Listening anywhere but loopback needs a token (or a token file): the page and its offers must
present it.
"""

from __future__ import annotations

import argparse
import math
import re
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

from eca.protocol.endpoints import is_loopback
from eca.services.processes.web.ice import IceSettings, IceSettingsError, ice_from_table

MAX_TOKEN_CHARS = 256
MAX_SFU_URL_CHARS = 2000
DRAW_MODES = ("auto", "browser", "server")
# One web process uses at most one core (about 24 % of one plus 4 % per conversation measured on a 2-core machine,
# bench/conversations.py); 16 workers are a 16-core server's worth.
MAX_WORKERS = 16


@dataclass(frozen=True)
class VadSettings:
    # 0 (most speech kept) .. 3 (most noise refused): webrtcvad's modes. Below 3 it calls a microphone's
    # hiss speech: at 2, 37-82 % of the frames of white noise at -64..-44 dBFS are "voiced" (measured),
    # enough to barge in on the agent; 3 refuses them all and still hears speech.
    aggressiveness: int = 3
    window: int = 10  # frames (200 ms) over which voiced frames are counted
    start_frames: int = 6  # voiced frames in the window that make the user speaking (120 ms of speech)
    stop_s: float = 0.6  # without a voiced frame this long, the user has stopped

    def check(self) -> VadSettings:
        if self.aggressiveness not in (0, 1, 2, 3):
            raise ValueError(f"vad aggressiveness must be 0, 1, 2 or 3, got {self.aggressiveness}")
        if not 1 <= self.start_frames <= self.window <= 100:
            raise ValueError(f"vad start_frames must lie in 1..window and window in 1..100, got "
                             f"{self.start_frames} of {self.window}")
        if not 0.02 <= self.stop_s <= 10:
            raise ValueError(f"vad stop_s must lie in [0.02, 10] s, got {self.stop_s}")
        return self


class WebOptionsError(ValueError):
    """A setting that cannot be: the message names it."""


@dataclass(frozen=True)
class WebOptions:
    host: str = "127.0.0.1"
    port: int = 8080
    token: str | None = None
    agents: tuple[str, ...] = ()  # empty: every agent of the instance
    width: int = 640  # what a page gets when it asks for nothing
    height: int = 480
    fps: float = 30.0
    max_width: int = 1280  # what a page may ask for at most
    max_height: int = 720
    max_fps: float = 30.0
    max_viewers: int = 16
    connect_timeout_s: float = 15.0  # a viewer that does not connect within this is closed
    silent_timeout_s: float = 10.0  # a connected viewer that sends no receiver report for this long is closed
    vad: VadSettings = field(default_factory=VadSettings)
    face: str | None = None  # every agent's face (None: the config's [faces], else flexor; renderer/faces.py)
    # who draws a face: "auto" (a page with WebGL draws a 3D face itself from face frames; the server draws the
    # 2D face, and for a page without WebGL, as video), "browser" (pages draw every face: no GL on the server)
    # or "server" (always video)
    draw: str = "auto"
    # a conversation per visitor: each page gets an agent of its own, created for it over the bus and removed when
    # it leaves (web/conversations.py); the instance's [conversations] max bounds how many at once
    per_visitor: bool = False
    # Janus's HTTP API (e.g. "http://sfu:8088/janus"): each agent's face published once into a Streaming mountpoint
    # there (web/sfu.py), which pages then watch through Janus; None: every page peers with this service
    sfu: str | None = None
    # web worker processes serving the visitors' conversations (per_visitor only): worker i listens on port + i - 1
    # and `eca up` starts them all; a load balancer in front spreads the visitors (docs/web.md, "Web workers")
    workers: int = 1
    worker: int = 1  # which worker this process is (1: the service "web"; i > 1: "web-i"), set by `eca up`
    # how this service's WebRTC peers and its pages find a way to each other: STUN/TURN servers, the interfaces
    # offered ([web.ice], web/ice.py); none by default: host addresses only, no outside server asked
    ice: IceSettings = field(default_factory=IceSettings)

    def check(self) -> WebOptions:
        if not 0 <= self.port < 65536:
            raise WebOptionsError(f"web port must lie in 0..65535 (0: any free port), got {self.port}")
        if not is_loopback(self.host) and not self.token:
            raise WebOptionsError(f"listening on {self.host!r} (not loopback) needs a token: give --web-token or "
                                  "--web-token-file, and open the page with ?token=...")
        if self.token is not None and not (8 <= len(self.token) <= MAX_TOKEN_CHARS and self.token.isprintable()):
            raise WebOptionsError(f"the web token must be 8-{MAX_TOKEN_CHARS} printable characters")
        for name in ("width", "height", "max_width", "max_height"):
            if not 16 <= getattr(self, name) <= 4096 or getattr(self, name) % 2:
                raise WebOptionsError(f"web {name} must be an even number in 16..4096, got {getattr(self, name)}")
        for name in ("fps", "max_fps"):
            if not (math.isfinite(getattr(self, name)) and 1 <= getattr(self, name) <= 60):
                raise WebOptionsError(f"web {name} must lie in [1, 60], got {getattr(self, name)}")
        if self.width > self.max_width or self.height > self.max_height or self.fps > self.max_fps:
            raise WebOptionsError("the web defaults (width, height, fps) must lie within the maxima")
        if not 1 <= self.max_viewers <= 256:
            raise WebOptionsError(f"web max_viewers must lie in 1..256, got {self.max_viewers}")
        if not 1 <= self.connect_timeout_s <= 120:
            raise WebOptionsError(f"web connect_timeout_s must lie in [1, 120], got {self.connect_timeout_s}")
        if not 2 <= self.silent_timeout_s <= 120:
            raise WebOptionsError(f"web silent_timeout_s must lie in [2, 120], got {self.silent_timeout_s}")
        if not isinstance(self.per_visitor, bool):
            raise WebOptionsError(f"web per_visitor must be true or false, got {self.per_visitor!r}")
        self._check_workers()
        if self.draw not in DRAW_MODES:
            raise WebOptionsError(f"web draw must be one of {', '.join(DRAW_MODES)}, got {self.draw!r}")
        if self.sfu is not None:
            self._check_sfu()
        self.vad.check()
        if not isinstance(self.ice, IceSettings):
            raise WebOptionsError(f"web ice must be a table of ICE settings, got {self.ice!r}")
        try:
            self.ice.check("web ice")
        except IceSettingsError as exc:
            raise WebOptionsError(str(exc)) from None
        return self

    def _check_workers(self) -> None:
        if isinstance(self.workers, bool) or not isinstance(self.workers, int) or not 1 <= self.workers <= MAX_WORKERS:
            raise WebOptionsError(f"web workers must be a whole number in 1..{MAX_WORKERS}, got {self.workers!r}")
        if isinstance(self.worker, bool) or not isinstance(self.worker, int) or not 1 <= self.worker <= self.workers:
            raise WebOptionsError(f"web worker must lie in 1..workers ({self.workers}), got {self.worker!r}")
        if self.workers > 1 and not self.per_visitor:
            raise WebOptionsError(f"{self.workers} web workers split the visitors' conversations among them: give "
                                  "--per-visitor (or [web] per_visitor = true), or one worker")
        if self.port and self.port + self.workers - 1 > 65535:
            last = self.port + self.workers - 1
            raise WebOptionsError(f"{self.workers} web workers listen on ports {self.port}..{last}, past 65535: give a "
                                  "lower --web-port")

    @property
    def service_name(self) -> str:
        """This worker's service name: "web" for the first, "web-2", "web-3" ... for the others."""
        return worker_service_name(self.worker)

    @property
    def conversation_prefix(self) -> str:
        """How this worker's conversations' agent ids begin: "v-" for the first, "v2-", "v3-" ... for the others."""
        return "v-" if self.worker == 1 else f"v{self.worker}-"

    @property
    def listen_port(self) -> int:
        """The port this worker listens on: `port` + worker - 1 (0, any free port, for every worker)."""
        return self.port + self.worker - 1 if self.port else 0

    def _check_sfu(self) -> None:
        url = self.sfu
        if not isinstance(url, str) or not 0 < len(url) <= MAX_SFU_URL_CHARS or not url.isprintable() or " " in url:
            raise WebOptionsError(f"web sfu must be a URL of 1-{MAX_SFU_URL_CHARS} printable characters without "
                                  "spaces (Janus's HTTP API, e.g. http://sfu.example:8088/janus)")
        try:
            parts = urlsplit(url)
            parts.port  # noqa: B018 (a port out of range raises here)
        except ValueError as exc:
            raise WebOptionsError(f"web sfu {url!r} is not a URL: {exc}") from None
        if parts.scheme not in ("http", "https") or not parts.hostname:
            raise WebOptionsError(f"web sfu must be an http:// or https:// URL with a host (Janus's HTTP API, e.g. "
                                  f"http://sfu.example:8088/janus), got {url!r}")
        if parts.query or parts.fragment or parts.username or parts.password:
            raise WebOptionsError(f"web sfu must be Janus's API's base URL, without a query, fragment or user, got "
                                  f"{url!r}")
        if self.per_visitor:
            raise WebOptionsError("web sfu publishes the instance's agents once for every viewer; a conversation per "
                                  "visitor (per_visitor) has one viewer each: use one or the other")

    def url(self, port: int | None = None) -> str:
        """The page's address (with the token): on `port` when given (the one bound for port 0)."""
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"http://{host}:{port or self.port}/" + (f"?token={self.token}" if self.token else "")


def worker_service_name(worker: int) -> str:
    return "web" if worker == 1 else f"web-{worker}"


def worker_of(service_name: str) -> int | None:
    """The worker number a service name stands for ("web" 1, "web-2" 2 ...), or None when it names no web worker."""
    if service_name == "web":
        return 1
    match = re.fullmatch(r"web-([1-9][0-9]?)", service_name)
    return int(match.group(1)) if match and 2 <= int(match.group(1)) <= MAX_WORKERS else None


def options_from_table(table: dict[str, Any], where: str = "[web]") -> WebOptions:
    """Options from a config's [web] table; unknown keys and wrong types are errors naming them."""
    known = {f.name: f for f in fields(WebOptions) if f.name != "worker"} | {"token_file": None}
    values: dict[str, Any] = {}
    for key, value in table.items():
        if key not in known:
            raise WebOptionsError(f"{where}: unknown key {key!r}; known: {', '.join(sorted(known))}")
        if key == "vad":
            if not isinstance(value, dict):
                raise WebOptionsError(f"{where}: 'vad' must be a table")
            values["vad"] = _vad_from(value, f"{where}.vad")
        elif key == "ice":
            try:
                values["ice"] = ice_from_table(value, f"{where}.ice")
            except IceSettingsError as exc:
                raise WebOptionsError(str(exc)) from None
        elif key == "agents":
            values["agents"] = tuple(str(a) for a in value)
        elif key == "token_file":
            values["token"] = read_token_file(Path(value)) if value else None
        else:
            values[key] = value
    try:
        return WebOptions(**values)
    except TypeError as exc:
        raise WebOptionsError(f"{where}: {exc}") from None


def _vad_from(table: dict[str, Any], where: str) -> VadSettings:
    names = {f.name for f in fields(VadSettings)}
    unknown = set(table) - names
    if unknown:
        raise WebOptionsError(f"{where}: unknown keys {sorted(unknown)}; known: {', '.join(sorted(names))}")
    return VadSettings(**table)


def read_token_file(path: Path) -> str:
    try:
        text = path.read_text(encoding="utf-8").strip()
    except OSError as exc:
        raise WebOptionsError(f"cannot read the web token file {path}: {exc.strerror}") from None
    except UnicodeDecodeError:
        raise WebOptionsError(f"the web token file {path} is not UTF-8 text") from None
    if not text:
        raise WebOptionsError(f"the web token file {path} is empty")
    return text


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--web-host", default=None, help="address to listen on (default 127.0.0.1)")
    parser.add_argument("--web-port", type=int, default=None, help="port to listen on (default 8080)")
    token = parser.add_mutually_exclusive_group()
    token.add_argument("--web-token", default=None, help="a token the page must present (needed off loopback)")
    token.add_argument("--web-token-file", default=None, help="read the token from this file")
    parser.add_argument("--web-face", default=None, metavar="FACE",
                        help="the agents' face in the page: flexor, head or a .glb/.gltf/.vrm file "
                             "(default: the config's [faces], else flexor)")
    parser.add_argument("--per-visitor", action="store_true", default=None,
                        help="a conversation per visitor: each page gets an agent of its own, created for it and "
                             "removed when it leaves (at most the config's [conversations] max at once)")
    parser.add_argument("--web-draw", default=None, choices=DRAW_MODES,
                        help="who draws the faces: auto (a page with WebGL draws 3D faces itself, default), browser "
                             "(pages draw every face; the server needs no GL) or server (video)")
    parser.add_argument("--web-workers", type=int, default=None, metavar="N",
                        help=f"web worker processes for the visitors' conversations (with --per-visitor; "
                             f"1..{MAX_WORKERS}, default 1): worker i listens on --web-port + i - 1; put a load "
                             "balancer in front (docs/web.md)")
    parser.add_argument("--web-sfu", "--sfu", dest="web_sfu", default=None, metavar="URL",
                        help="publish each face once into Janus (its HTTP API, e.g. http://sfu:8088/janus; the "
                             "Streaming plugin) and let pages watch through it (default: pages peer with this service)")


def options_from(table: dict[str, Any], args: argparse.Namespace) -> WebOptions:
    """The config's [web] table overridden by the command line; checked."""
    options = options_from_table(table)
    changes: dict[str, Any] = {}
    if args.web_host is not None:
        changes["host"] = args.web_host
    if args.web_port is not None:
        changes["port"] = args.web_port
    if args.web_token is not None:
        changes["token"] = args.web_token
    if args.web_token_file is not None:
        changes["token"] = read_token_file(Path(args.web_token_file))
    if args.per_visitor:
        changes["per_visitor"] = True
    if args.web_draw is not None:
        changes["draw"] = args.web_draw
    if args.web_workers is not None:
        changes["workers"] = args.web_workers
    if getattr(args, "web_worker", None) is not None:  # only the web service's own command line has it
        changes["worker"] = args.web_worker
    if getattr(args, "web_sfu", None) is not None:
        changes["sfu"] = args.web_sfu
    if args.web_face is not None:
        from eca.services.processes.renderer import check_face  # GL libraries load only here

        try:
            changes["face"] = check_face(args.web_face, "--web-face")
        except ValueError as exc:
            raise WebOptionsError(str(exc)) from None
    return replace(options, **changes).check()

