"""A conversation per visitor (`--per-visitor`, `[web] per_visitor`): each page that asks gets an agent of its
own, created over the bus for it and removed when its page leaves, fails or goes silent.

`POST /conversation` asks for one: the web service names a new agent (`v-` and 10 random hex digits; web worker i
of several, `v<i>-`), sends
`create_agent` (docs/protocol.md, "Conversations created at run time") and answers once the dialogue service lists
the agent in `state.*.agents`: the agent's id and a key. The page then watches that agent as any other, and its
offer and commands must carry the key: no other page can watch it or speak for it. A conversation whose page does
not connect within the connect timeout, and one whose viewer closes, is removed (`remove_agent`). When all the
instance's conversations are in use the page is told "busy" at once (503, `retry: true`), and nothing is created.

The bookkeeping here is plain data used from the service's two threads under one lock: the event loop's (the
page's requests) and the bus loop's (the agents list, viewers leaving).
"""

from __future__ import annotations

import asyncio
import re
import secrets
import threading
from dataclasses import dataclass, field

KEY_BYTES = 16
AGENT_HEX = 10  # random hex digits in a conversation's agent id
_HEX = re.compile(f"[0-9a-f]{{{AGENT_HEX}}}")


class Busy(RuntimeError):
    """No conversation can be made now; the message says why, for the visitor."""


@dataclass
class Conversation:
    agent: str
    key: str
    asked_ns: int
    like: str = ""
    viewer: int | None = None  # the viewer that watches it, once its page connects
    live: bool = False  # listed by the dialogue service
    removing: bool = False
    created: asyncio.Future[None] | None = field(default=None, repr=False)
    loop: asyncio.AbstractEventLoop | None = field(default=None, repr=False)


class Conversations:
    """The web service's conversations, by agent id."""

    def __init__(self, connect_timeout_s: float, prefix: str = "v-") -> None:
        self.connect_timeout_ns = int(connect_timeout_s * 1e9)
        self.prefix = prefix  # this web worker's conversations' agent ids: the prefix, then AGENT_HEX hex digits
        self._lock = threading.Lock()
        self._by_agent: dict[str, Conversation] = {}
        self.created_count = 0  # in the instance, as the latest agents list says
        self.max_created: int | None = None  # unknown until the dialogue service's first list

    def begin(self, now_ns: int, loop: asyncio.AbstractEventLoop) -> Conversation:
        """A new conversation, not yet created (on the event loop). Busy when the instance's list is full."""
        with self._lock:
            if self.max_created is None:
                raise Busy("the instance is not ready for conversations yet (no list of agents from its dialogue "
                           "service); try again shortly")
            pending = sum(1 for c in self._by_agent.values() if not c.live)
            if self.created_count + pending >= self.max_created:
                raise Busy(f"busy: all {self.max_created} conversations are in use; try again later")
            agent = f"{self.prefix}{secrets.token_hex(AGENT_HEX // 2)}"
            conversation = Conversation(agent, secrets.token_urlsafe(KEY_BYTES), now_ns, created=loop.create_future(),
                                        loop=loop)
            self._by_agent[agent] = conversation
            return conversation

    def free(self) -> int | None:
        """How many more conversations `begin` would accept now (None until the dialogue service's first list):
        what the health endpoint reports to a load balancer (web/health.py). Read-only; counted as `begin` does."""
        with self._lock:
            if self.max_created is None:
                return None
            pending = sum(1 for c in self._by_agent.values() if not c.live)
            return max(0, self.max_created - self.created_count - pending)

    def refused(self, agent: str, reason: str) -> None:
        """The dialogue service refused to create it (on the bus loop): its page is told why."""
        with self._lock:
            conversation = self._by_agent.pop(agent, None)
        if conversation is not None and conversation.created is not None and conversation.loop is not None:
            conversation.loop.call_soon_threadsafe(_settle, conversation.created, Busy(reason))

    def listed(self, live: set[str], created_count: int, max_created: int) -> tuple[list[Conversation], list[str]]:
        """A new agents list (on the bus loop): the conversations it makes live (their pages are told by
        `ready`, once the service serves their agents), and ours it no longer lists (forgotten here; the service
        drops their agents)."""
        became: list[Conversation] = []
        with self._lock:
            self.created_count, self.max_created = created_count, max_created
            gone = [a for a, c in self._by_agent.items() if c.live and a not in live]
            for agent in gone:
                del self._by_agent[agent]
            for conversation in self._by_agent.values():
                if not conversation.live and conversation.agent in live:
                    conversation.live = True
                    became.append(conversation)
        return became, gone

    @staticmethod
    def ready(conversation: Conversation) -> None:
        """Tell the page that asked for `conversation` that its agent is served (from the bus loop)."""
        future, loop = conversation.created, conversation.loop
        if future is not None and loop is not None:
            loop.call_soon_threadsafe(_settle, future, None)

    def left_behind(self, created: list[str]) -> list[str]:
        """Of the instance's created agents, those named as this worker names its conversations but not held here:
        a previous run of this worker made them (it died or was restarted), and no page can reach them any more."""
        with self._lock:
            return [a for a in created if a not in self._by_agent and a.startswith(self.prefix)
                    and _HEX.fullmatch(a[len(self.prefix):]) is not None]

    def check_key(self, agent: str, key: object) -> bool:
        """Whether `key` is the one of `agent`'s conversation (False for an agent that is no conversation)."""
        with self._lock:
            conversation = self._by_agent.get(agent)
        return (conversation is not None and isinstance(key, str)
                and secrets.compare_digest(key.encode(), conversation.key.encode()))

    def is_conversation(self, agent: str) -> bool:
        with self._lock:
            return agent in self._by_agent

    def watched(self, agent: str, viewer: int) -> None:
        with self._lock:
            conversation = self._by_agent.get(agent)
            if conversation is not None:
                conversation.viewer = viewer

    def to_remove(self, now_ns: int, left: set[int]) -> list[str]:
        """Agents to remove now (on the bus loop): those whose viewer is among `left`, and live ones whose page
        never connected within the connect timeout. Each is returned once."""
        out = []
        with self._lock:
            for conversation in self._by_agent.values():
                if conversation.removing or not conversation.live:
                    continue
                never_came = conversation.viewer is None and now_ns - conversation.asked_ns > self.connect_timeout_ns
                if conversation.viewer in left or never_came:
                    conversation.removing = True
                    out.append(conversation.agent)
        return out

    def forget_unanswered(self, now_ns: int, timeout_ns: int) -> list[str]:
        """Conversations asked for but never listed within `timeout_ns` (the dialogue service did not answer):
        their pages were told busy; forgotten."""
        with self._lock:
            stale = [a for a, c in self._by_agent.items() if not c.live and now_ns - c.asked_ns > timeout_ns]
            for agent in stale:
                del self._by_agent[agent]
            return stale

    def __len__(self) -> int:
        with self._lock:
            return len(self._by_agent)


def _settle(future: asyncio.Future[None], error: BaseException | None) -> None:
    """Settle a page's wait (on the event loop), unless it gave up already."""
    if future.done():
        return
    if error is None:
        future.set_result(None)
    else:
        future.set_exception(error)
