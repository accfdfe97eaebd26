"""The helper processes' side of a bench's stdin/stdout: the bench's commands come in as lines, the answers go out
as one JSON object a line."""

from __future__ import annotations

import asyncio
import json
import sys
import threading
from typing import Any


def stdin_lines() -> asyncio.Queue[str | None]:
    """This process's stdin, line by line (stripped), on a queue of the running event loop; None once it closes (the
    bench is done). A thread reads it: the loop never blocks on the bench."""
    loop = asyncio.get_running_loop()
    lines: asyncio.Queue[str | None] = asyncio.Queue()

    def read() -> None:
        for line in sys.stdin:
            loop.call_soon_threadsafe(lines.put_nowait, line.strip())
        loop.call_soon_threadsafe(lines.put_nowait, None)

    threading.Thread(target=read, daemon=True).start()
    return lines


def say(obj: dict[str, Any]) -> None:
    """One answer to the bench."""
    print(json.dumps(obj), flush=True)
