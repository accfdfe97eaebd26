"""An asyncio event loop on a thread of its own: where the web service's HTTP server and WebRTC peers
live, beside the service's bus loop (zmq sockets stay on that one's thread)."""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Coroutine
from typing import Any, TypeVar

T = TypeVar("T")


def new_event_loop() -> asyncio.AbstractEventLoop:
    """uvloop's event loop (libuv: its scheduling and UDP transports in C) where it is installed, else the
    standard library's. Every conversation's packets pass through this loop: with 12 conversations on a 2-core
    machine uvloop took about 6 % off the web service's CPU (bench/conversations.py, three alternated pairs)."""
    try:
        import uvloop
    except ImportError:  # a platform uvloop does not build for
        return asyncio.new_event_loop()
    return uvloop.new_event_loop()


class EventLoopThread:
    def __init__(self, name: str = "web-event-loop") -> None:
        self.loop = new_event_loop()
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)

    def _run(self) -> None:
        asyncio.set_event_loop(self.loop)
        self.loop.run_forever()

    def start(self) -> EventLoopThread:
        self._thread.start()
        return self

    def call(self, coro: Coroutine[Any, Any, T], timeout_s: float) -> T:
        """Run `coro` on the loop and wait for its result (or its exception) from another thread."""
        return asyncio.run_coroutine_threadsafe(coro, self.loop).result(timeout_s)

    def stop(self, timeout_s: float = 5.0) -> None:
        if self._thread.is_alive():
            self.loop.call_soon_threadsafe(self.loop.stop)
            self._thread.join(timeout_s)
        if not self.loop.is_running():
            self.loop.close()
