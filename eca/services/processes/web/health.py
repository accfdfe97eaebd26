"""The web service's health, for a load balancer in front of several eca hosts: `GET /health`.

The answer is JSON, `{"ready", "free_conversations", "max_conversations", "viewers", "instance", "voice"}`:
- 200 when the service is ready and has room for one more visitor;
- 503 with the same JSON when it is full or not ready (with `--per-visitor`: no agents list from the dialogue
  service yet, so `POST /conversation` would be refused too).

Room is what `POST /conversation` and `POST /offer` would grant now: with a conversation per visitor, the smaller of
the instance's free conversations (`[conversations] max` less the agents created, and those being created; counted
by web/conversations.py as `begin` counts them) and the free viewer places (`[web] max_viewers`); without, the
free viewer places alone (every page watches the instance's agents). `viewers` is the pages connected now;
`instance` the address and port the request came in on (which host of several answered); `voice` how late the
viewers' voice frames have left since the service started, against their time on the master clock (`frames`,
`late_20ms`, `late_60ms`, `max_late_ms`): a service that hands its voice over late is overloaded, whatever the
network does after (web/tracks.py VoiceTiming).

Headers say the same for checks that read no body: `X-Eca-Ready` (`yes` / `no`) and `X-Eca-Free-Conversations`.
eca/configs/haproxy.cfg tells a full host (ready, 503) from a dead or starting one by `X-Eca-Ready`: a full host is
drained (no new visitors, its own visitors still reach it), a dead one taken out.

No token is asked, even where the service wants one: the answer reveals counts only (no agent, key or address of a
visitor), and a load balancer's checks must reach it without the secret the pages carry. The request's query and
body are ignored; nothing is created or changed.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable, Sized
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

from aiohttp import web

from eca.services.processes.web.conversations import Conversations

if TYPE_CHECKING:  # the tracks' module brings av and aiortc; a health answer reads only counts
    from eca.services.processes.web.tracks import VoiceTiming

READY_HEADER = "X-Eca-Ready"
FREE_HEADER = "X-Eca-Free-Conversations"


class ViewerPlaces(Protocol):
    """What the health endpoint reads of the viewers (web/viewers.py Viewers): their number and limit, and how late
    their voices leave."""

    max_viewers: int
    voice_timing: VoiceTiming

    @property
    def open(self) -> Sized: ...


@dataclass(frozen=True)
class Health:
    ready: bool
    free_conversations: int
    max_conversations: int
    viewers: int

    @property
    def status(self) -> int:
        return 200 if self.ready and self.free_conversations > 0 else 503


def health_of(viewers: ViewerPlaces, conversations: Conversations | None) -> Health:
    """The service's health now (on the event loop, where the viewers are kept)."""
    watching = len(viewers.open)
    places = max(0, viewers.max_viewers - watching)
    if conversations is None:  # every page watches the instance's own agents: a viewer's place is all it takes
        return Health(True, places, viewers.max_viewers, watching)
    free = conversations.free()
    if free is None or conversations.max_created is None:
        return Health(False, 0, viewers.max_viewers, watching)
    return Health(True, min(free, places), min(viewers.max_viewers, conversations.max_created), watching)


def health_handler(viewers: ViewerPlaces,
                   conversations: Conversations | None) -> Callable[[web.Request], Awaitable[web.Response]]:
    """The `GET /health` handler for one service's viewers and conversations."""

    async def health(request: web.Request) -> web.Response:
        now = health_of(viewers, conversations)
        timing = viewers.voice_timing
        body = {"ready": now.ready, "free_conversations": now.free_conversations,
                "max_conversations": now.max_conversations, "viewers": now.viewers,
                "instance": _instance(request),
                "voice": {"frames": timing.frames, "late_20ms": timing.late_20ms, "late_60ms": timing.late_60ms,
                          "max_late_ms": round(timing.max_late_ns / 1e6, 1)}}
        headers = {READY_HEADER: "yes" if now.ready else "no", FREE_HEADER: str(now.free_conversations),
                   "Cache-Control": "no-store"}  # a cached answer would hide a host that filled up or died
        return web.json_response(body, status=now.status, headers=headers)

    return health


def _instance(request: web.Request) -> str:
    """The address and port this request came in on: several hosts behind one balancer tell themselves apart."""
    sockname = request.transport.get_extra_info("sockname") if request.transport is not None else None
    if isinstance(sockname, tuple) and len(sockname) >= 2:
        host = str(sockname[0])
        return f"[{host}]:{sockname[1]}" if ":" in host else f"{host}:{sockname[1]}"
    return ""
