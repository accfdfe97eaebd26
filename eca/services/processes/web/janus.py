"""A client of Janus's HTTP API (aiohttp), as much as the web service needs to publish faces into Janus's Streaming
plugin: a session, a handle on janus.plugin.streaming, synchronous plugin requests (create, info, destroy).

Janus's HTTP API (janus-gateway docs, "RESTful, HTTP API"): `POST <url>` `{"janus": "create"}` makes a session,
`POST <url>/<session>` `{"janus": "attach", "plugin": ...}` a handle, `POST <url>/<session>/<handle>`
`{"janus": "message", "body": {...}}` a plugin request. The Streaming plugin answers `create`, `info`, `destroy`
synchronously (`{"janus": "success", "plugindata": {"data": {...}}}`; a refusal is `error_code` / `error` inside the
data). Every request names a `transaction`. A session with no request for `session_timeout` (60 s by default) is
dropped by Janus: whoever holds one must send something (a `keepalive`, or any request) well within that.
"""

from __future__ import annotations

import json
import secrets
import time
import urllib.error
import urllib.request
from collections import deque
from typing import Any

import aiohttp

STREAMING = "janus.plugin.streaming"
# Janus's error codes the publisher acts on (janus-gateway src/apierror.h, src/plugins/janus_streaming.c)
SESSION_NOT_FOUND = 458
HANDLE_NOT_FOUND = 459
NO_SUCH_MOUNTPOINT = 455
MOUNTPOINT_EXISTS = 456
MAX_ANSWER_BYTES = 1 << 20  # an answer larger than this is not Janus's
ROUND_TRIPS_KEPT = 12  # the latest requests' round trips the way to Janus is taken from


class JanusError(RuntimeError):
    """Janus refused a request (`code` is its error code), or did not answer (`code` 0)."""

    def __init__(self, reason: str, code: int = 0) -> None:
        super().__init__(reason)
        self.code = code

    @property
    def lost(self) -> bool:
        """Whether the session or handle is gone (Janus restarted, or the session timed out)."""
        return self.code in (SESSION_NOT_FOUND, HANDLE_NOT_FOUND)


def check_server(url: str, timeout_s: float = 5.0) -> dict[str, Any]:
    """Janus's `info` answer at `url`, checked to have the Streaming plugin (blocking: a start-up check). JanusError
    with a sentence when it does not answer, or is not a Janus with the plugin."""
    try:
        with urllib.request.urlopen(url.rstrip("/") + "/info", timeout=timeout_s) as response:
            body = json.loads(response.read(MAX_ANSWER_BYTES))
    except urllib.error.HTTPError as exc:
        raise JanusError(f"{url}/info answered HTTP {exc.code}, not Janus's info") from None
    except (OSError, urllib.error.URLError) as exc:
        reason = getattr(exc, "reason", None) or getattr(exc, "strerror", None) or exc
        raise JanusError(f"no answer from {url}/info ({reason})") from None
    except ValueError:
        raise JanusError(f"{url}/info did not answer JSON: is it Janus's HTTP API (its base path, /janus)?") from None
    if not isinstance(body, dict) or body.get("janus") != "server_info":
        raise JanusError(f"{url}/info did not answer Janus's server_info")
    plugins = body.get("plugins")
    if not isinstance(plugins, dict) or STREAMING not in plugins:
        raise JanusError(f"the Janus at {url} has no Streaming plugin ({STREAMING})")
    return body


async def _whole_answer(response: aiohttp.ClientResponse) -> bytes | None:
    """The answer's body to its end, or None past MAX_ANSWER_BYTES. Janus answers chunked (libmicrohttpd): a body may
    come in several chunks, and the chunk that ends it in a TCP segment of its own. One read takes only what has come,
    which cut an answer short (not JSON: taken for a Janus lost), or left its end unread, so the connection was not
    kept for the next request (a new one costs a round trip more, and the way to Janus was taken as twice as long)."""
    parts: list[bytes] = []
    size = 0
    async for part in response.content.iter_any():
        size += len(part)
        if size > MAX_ANSWER_BYTES:
            return None
        parts.append(part)
    return b"".join(parts)


class JanusClient:
    """One Janus session with one Streaming handle."""

    def __init__(self, url: str, timeout_s: float = 5.0) -> None:
        self.url = url.rstrip("/")
        self.timeout_s = timeout_s
        self.session_id = 0
        self.handle_id = 0
        self._http: aiohttp.ClientSession | None = None
        # the latest requests' round trips (s): the quickest is the network's, twice the way to Janus
        self.round_trips: deque[float] = deque(maxlen=ROUND_TRIPS_KEPT)

    def one_way_s(self) -> float:
        """How long a packet takes to reach Janus, from the quickest of the latest requests' round trips (half of
        it, as NTP takes it: a slow answer, held up anywhere, says least); 0 before any answer."""
        return min(self.round_trips) / 2 if self.round_trips else 0.0

    async def _post(self, path: str, body: dict[str, Any]) -> dict[str, Any]:
        if self._http is None or self._http.closed:
            self._http = aiohttp.ClientSession(timeout=aiohttp.ClientTimeout(total=self.timeout_s))
        try:
            sent = time.monotonic()
            async with self._http.post(self.url + path, json={**body, "transaction": secrets.token_hex(8)}) as r:
                raw = await _whole_answer(r)
            self.round_trips.append(time.monotonic() - sent)
        except (aiohttp.ClientError, TimeoutError, OSError) as exc:
            raise JanusError(f"no answer from Janus at {self.url} ({type(exc).__name__}: {exc})") from None
        if raw is None:
            raise JanusError(f"Janus at {self.url} answered more than {MAX_ANSWER_BYTES} bytes: not Janus's answer")
        try:
            answer = json.loads(raw)
        except ValueError:
            raise JanusError(f"Janus at {self.url} answered something that is not JSON") from None
        if not isinstance(answer, dict):
            raise JanusError(f"Janus at {self.url} answered something that is not a JSON object")
        if answer.get("janus") == "error":
            got = answer.get("error")
            error: dict[str, Any] = got if isinstance(got, dict) else {}
            raise JanusError(f"Janus: {error.get('reason', 'an error')}", int(error.get("code") or 0))
        return answer

    async def open(self) -> None:
        """A new session and a Streaming handle on it (whatever was open before is forgotten: Janus lost it)."""
        created = await self._post("", {"janus": "create"})
        self.session_id = int(created["data"]["id"])
        attached = await self._post(f"/{self.session_id}", {"janus": "attach", "plugin": STREAMING})
        self.handle_id = int(attached["data"]["id"])

    async def request(self, body: dict[str, Any]) -> dict[str, Any]:
        """A synchronous Streaming request; its answer's data. JanusError (with Janus's code) when refused."""
        answer = await self._post(f"/{self.session_id}/{self.handle_id}", {"janus": "message", "body": body})
        data = answer.get("plugindata", {}).get("data")
        if not isinstance(data, dict):
            raise JanusError(f"Janus answered {body.get('request')!r} without the plugin's data")
        if "error_code" in data or "error" in data:
            raise JanusError(f"Janus streaming: {data.get('error', 'an error')}", int(data.get("error_code") or 0))
        return data

    async def keepalive(self) -> None:
        await self._post(f"/{self.session_id}", {"janus": "keepalive"})

    async def close(self) -> None:
        """Destroy the session (Janus detaches its handle); then close the HTTP client. Errors are Janus's
        business now: the caller is stopping."""
        try:
            if self.session_id:
                await self._post(f"/{self.session_id}", {"janus": "destroy"})
        except JanusError:
            pass
        finally:
            self.session_id = self.handle_id = 0
            if self._http is not None:
                await self._http.close()
                self._http = None
