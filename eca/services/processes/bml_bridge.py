"""The BML bridge (`eca bml-bridge --stomp HOST:PORT`): BML blocks from ActiveMQ to the agents' realizer, and the
realizer's feedback back to ActiveMQ, in the shapes three BML systems already speak.

On the ActiveMQ side it is a STOMP client (stomp.py), on eca's side a bus client (`AgentClient`). Each block that
arrives on a request topic becomes a `bml` command (`cmd.<agent>.bml`, the bml service realizes it), and each
`bml_feedback` event of that block (`event.<agent>.bml_feedback`) goes back to the feedback topic of the system it
came from. What each system sends and expects (checked against their sources):

- AsapRealizer (ArticulatedSocialAgentsPlatform/AsapRealizer, AsapActiveMQAdapters: AMQBMLConstants,
  ActiveMQToBMLRealizerAdapter): JMS text messages on the topics `asap.bml.request` (a `<bml>` block) and
  `asap.bml.feedback` (one standard feedback element each). Blocks go to the realizer unchanged, feedback comes back
  unchanged: every kind, as the standard's XML.
- Greta (isir/greta, greta.auxiliary.activemq.semaine: BMLReceiver, BMLCallbacksSender): text messages on `greta.BML`;
  its callbacks go to `greta.output.feedback.BML` with an empty body and the properties `feedback-type`,
  `feedback-id` (the block's id) and `feedback-time` (milliseconds). Greta's callbacks are per block, so only
  block-level events go back: `start`, `end`, `stopped` (interrupted) and `dead` (refused or failed); the last two
  names follow Greta's own states of a block (greta.core.feedbacks.TemporizableList: dead, start, stop, end). The
  body carries the standard's XML of the same event for a reader that wants more.
- The Virtual Human Toolkit's VHMsg (SmartBody: DrAlta/smartbody core/smartbody/SmartBody/src/bml/bml_processor.cpp
  `vrAgentBML_cmd_func`, bml.cpp): text lines on the topic `DEFAULT_SCOPE` (the scope), each with the properties
  `ELVISH_SCOPE` (the scope) and `MESSAGE_PREFIX` (the line's first word), the rest of the line URL-encoded with '+'
  for spaces (the toolkit's vhmsg.js, VHMsg.cs). A request is `vrAgentBML <char> <msgId> request <xml>` (older
  SmartBody puts a recipient before the message id); the replies are `vrAgentBML <char> <msgId> start` and
  `vrAgentBML <char> <msgId> end complete|interrupted|error <message>`.

The feedback, mapped (the realizer's `bml_feedback` -> AsapRealizer's topic; Greta's `feedback-type`; the VHMsg line):

- blockProgress start -> its XML; `start`; `start`.
- syncPointProgress, predictionFeedback, a warningFeedback about one behaviour -> its XML; nothing; nothing.
- a warningFeedback whose type says INTERRUPT(ED) -> its XML; before the block's start `stopped`, `end interrupted`
  (no end follows), after it the end that follows counts as interrupted.
- a warningFeedback PARSING_FAILURE or IMPOSSIBLE_TO_SCHEDULE about the whole block (no behaviour), before its
  start -> its XML; `dead`; `end error <type>: <text>` (the realizer will not run it).
- blockProgress end -> its XML; `end`; `end complete`. Interrupted (`stopped`, `end interrupted`): after an
  interruption warning, with AsapRealizer's bmla:status INTERRUPTED or REVOKED (BMLABlockStatus), or with a reason in
  its `text` (eca's realizer ends a block it cut short so: REPLACE, a barge-in, an `interrupt`). Failed (`dead`,
  `end error`): bmla:status FAILED.
- an error on the bus about a block's command (`error.<agent>.error` with its request id; eca's realizer refuses a
  block with a warningFeedback and this error) -> a warningFeedback unless the realizer sent one; `dead`;
  `end error <type>: <text>`.

Each block ends exactly once on Greta's and VHMsg's side; feedback of blocks the bridge did not send (another client
on the bus) goes nowhere.

Limits, as for any bus client: a body over 65,536 characters (a VHMsg line's XML after decoding; the line itself at
most three times that, for its %XX escapes), one that is not UTF-8, or one that is not a `<bml>` block (or
SmartBody's `<act>` around one) is answered with a warningFeedback PARSING_FAILURE on the feedback topic (a VHMsg
`end error` line) and a log line, never a crash; so is a block for an agent that the instance does not have
(UNKNOWN_CHARACTER: its `characterId`, the VHMsg `<char>`, else `--agent`). Frames wait in a queue of at most
`QUEUE_MAX`; past that they are dropped and counted in a warning. A lost STOMP connection is retried with
backoff, logged once per outage; STOMP heart-beats find a dead broker.

What the bridge sends goes as STOMP frames without `content-length`: ActiveMQ makes such a frame a JMS TextMessage,
one with the header a BytesMessage, and AsapRealizer's and Greta's clients read TextMessages only.
"""

from __future__ import annotations

import html
import logging
import os
import queue
import random
import re
import signal
import threading
import time
import urllib.parse
from collections import OrderedDict
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any
from xml.sax.saxutils import escape, quoteattr

from eca.protocol.bus import BusTimeout
from eca.protocol.client import AgentClient
from eca.protocol.codec import ProtocolError, is_agent_id
from eca.protocol.endpoints import BusConfig
from eca.protocol.messages import (
    ALL_AGENTS,
    MAX_BML_CHARS,
    AgentsState,
    Bml,
    BmlFeedback,
    Error,
    Message,
)

log = logging.getLogger("bml-bridge")

BML_NS = "http://www.bml-initiative.org/bml/bml-1.0"
TRANSPORTS = ("asap", "greta", "vhmsg")
ASAP_REQUEST, ASAP_FEEDBACK = "asap.bml.request", "asap.bml.feedback"
GRETA_REQUEST, GRETA_FEEDBACK = "greta.BML", "greta.output.feedback.BML"
VHMSG_SCOPE = "DEFAULT_SCOPE"
VHMSG_PREFIX = "vrAgentBML"

MAX_BODY_CHARS = MAX_BML_CHARS  # what one `bml` command carries
VHMSG_ESCAPE_ROOM = 3  # a URL-encoded character is at most three ('%3C')
QUEUE_MAX = 1000  # frames waiting for the bus: a flood beyond this is dropped, not buffered without bound
PENDING_MAX = 4096  # blocks awaiting their end; the oldest is forgotten first (its realizer never ended it)
BATCH = 200  # frames handled between two looks at the bus, so neither side starves the other
HEARTBEAT_MS = 5000  # STOMP heart-beats both ways: a dead broker is noticed within 1.5 of these
CONNECT_TIMEOUT_S = 5.0
BACKOFF_S = (0.25, 10.0)  # first and longest wait between two connection attempts (doubling, 10 % jitter)
MAX_TEXT = 500  # a warning's text, so that an echo of a huge bad frame stays small
REFUSALS_SAID = 10  # refused frames logged one by one per second; the rest counted

# Block-level warnings that mean the realizer will not run the block at all.
REFUSING = frozenset({"PARSING_FAILURE", "IMPOSSIBLE_TO_SCHEDULE"})
UNKNOWN_CHARACTER = "UNKNOWN_CHARACTER"  # the standard has no type for a characterId no agent has


class Refused(Exception):
    """A frame the bridge answers itself with a warningFeedback (it never reaches the bus)."""

    def __init__(self, kind: str, text: str, block: str = "", character: str = "",
                 vh: VhAddress | None = None) -> None:
        super().__init__(text)
        self.kind = kind
        self.text = text
        self.block = block
        self.character = character
        self.vh = vh


# --- routes ------------------------------------------------------------------------------------------------------


def topic(name: str) -> str:
    return f"/topic/{name}"


@dataclass(frozen=True)
class Routes:
    """The STOMP destinations of each transport."""

    vhmsg_scope: str = VHMSG_SCOPE

    def request(self, transport: str) -> str:
        return topic({"asap": ASAP_REQUEST, "greta": GRETA_REQUEST, "vhmsg": self.vhmsg_scope}[transport])

    def feedback(self, transport: str) -> str:
        return topic({"asap": ASAP_FEEDBACK, "greta": GRETA_FEEDBACK, "vhmsg": self.vhmsg_scope}[transport])


def parse_transports(text: str) -> frozenset[str]:
    """`asap,greta,vhmsg` (any of them, in any order) -> the set; ValueError names a wrong one."""
    names = [n.strip().lower() for n in text.split(",") if n.strip()]
    if not names:
        raise ValueError("--topics names no transport (give some of asap, greta, vhmsg)")
    wrong = [n for n in names if n not in TRANSPORTS]
    if wrong:
        raise ValueError(f"--topics: unknown transport {wrong[0]!r} (known: {', '.join(TRANSPORTS)})")
    return frozenset(names)


def parse_host_port(text: str) -> tuple[str, int]:
    """`HOST:PORT` or `[v6]:PORT` -> (host, port); ValueError says what is wrong."""
    host, sep, port_text = text.strip().rpartition(":")
    host = host.strip()
    if host.startswith("[") and host.endswith("]"):
        host = host[1:-1]
    if not sep or not host or not port_text.isdigit():
        raise ValueError(f"--stomp {text!r}: expected HOST:PORT, e.g. 127.0.0.1:61613")
    port = int(port_text)
    if not 1 <= port <= 65535:
        raise ValueError(f"--stomp {text!r}: port must be 1-65535")
    return host, port


# --- bodies and blocks -------------------------------------------------------------------------------------------


def decode_body(raw: bytes, max_chars: int = MAX_BODY_CHARS) -> str:
    """A frame's body as text: UTF-8, at most `max_chars` characters; Refused (PARSING_FAILURE) otherwise."""
    if len(raw) > 4 * max_chars:  # more bytes than the longest UTF-8 of max_chars: no need to decode it all
        raise Refused("PARSING_FAILURE", f"the frame's body is {len(raw)} bytes, over the limit of {max_chars} "
                                         "characters")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise Refused("PARSING_FAILURE", f"the frame's body is not UTF-8 (byte {exc.start})") from None
    if len(text) > max_chars:
        raise Refused("PARSING_FAILURE", f"the frame's body is {len(text)} characters, over the limit of "
                                         f"{max_chars}")
    return text


_ATTRS = r"((?:\s+[^\s=/>]+\s*=\s*(?:\"[^\"]*\"|'[^']*'))*)\s*/?>"
_PROLOG = re.compile(r"\ufeff?\s*(?:<\?xml\b[^>]*\?>\s*)?(?:<!--.*?-->\s*)*", re.DOTALL)
_ROOT = re.compile(r"<(?:[\w.-]+:)?(bml|act)" + _ATTRS)
_INNER_BML = re.compile(r"<(?:[\w.-]+:)?bml" + _ATTRS)
_ATTR = re.compile(r"(?:^|\s)([\w.:-]+)\s*=\s*(?:\"([^\"]*)\"|'([^']*)')")
_ANY_ID = re.compile(r"<(?:[\w.-]+:)?bml\b[^>]*?\sid\s*=\s*[\"']([^\"'<>]{1,64})[\"']")


def attributes(attr_text: str) -> dict[str, str]:
    return {m.group(1): html.unescape(m.group(2) if m.group(2) is not None else m.group(3))
            for m in _ATTR.finditer(attr_text)}


@dataclass(frozen=True)
class BlockHead:
    """What the bridge reads of a block (the realizer parses the rest): its id and characterId."""

    block: str
    character: str


def block_head(xml: str) -> BlockHead:
    """The id and characterId of a `<bml>` block (or of the one inside SmartBody's `<act>`), read off the start tags
    alone (no XML parser runs on what a stranger sent); Refused (PARSING_FAILURE) when it does not look like one."""
    start = _PROLOG.match(xml)
    at = start.end() if start else 0
    root = _ROOT.match(xml, at)
    if root is None or not xml.rstrip().endswith(">"):
        raise Refused("PARSING_FAILURE", "not a <bml> block (nor SmartBody's <act> around one)", block=guess_block(xml))
    attrs = attributes(root.group(2))
    if root.group(1) == "act":
        inner = _INNER_BML.search(xml, root.end())
        if inner is None:
            raise Refused("PARSING_FAILURE", "<act> holds no <bml> block")
        attrs = attributes(inner.group(1))
    return BlockHead(block=attrs.get("id", ""), character=attrs.get("characterId", ""))


def guess_block(text: str) -> str:
    """The block id of something that may be a broken block, for the warning about it; '' if none shows."""
    m = _ANY_ID.search(text[:4096])
    return m.group(1) if m else ""


# --- VHMsg lines -------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class VhAddress:
    """Who a VHMsg reply goes to: the request's character and message id (and the older form's recipient)."""

    character: str
    message_id: str
    recipient: str | None = None

    def reply(self, words: str) -> str:
        """The reply line `vrAgentBML <char> [<recipient>] <msgId> <words>`, encoded as VHMsg sends it."""
        who = [self.character] + ([self.recipient] if self.recipient is not None else []) + [self.message_id]
        return vhmsg_line(VHMSG_PREFIX, " ".join([*who, words]))


@dataclass(frozen=True)
class VhRequest:
    address: VhAddress
    xml: str


def vhmsg_line(prefix: str, args: str) -> str:
    """A VHMsg message as its clients put it on the wire: the first word, a space, the rest URL-encoded ('+' for a
    space; vhmsg.js `encodeURIComponent(..).replace(/%20/g, "+")`, VHMsg.cs `HttpUtility.UrlEncode`)."""
    return f"{prefix} {urllib.parse.quote_plus(args, safe='')}"


def vhmsg_split(line: str) -> tuple[str, str]:
    """(first word, the rest decoded). A rest that holds a space or '<' was not encoded (a client that sends plain
    text; an encoder escapes both), so it is taken as it is."""
    prefix, _, rest = line.strip().partition(" ")
    rest = rest.strip()
    if " " in rest or "<" in rest:
        return prefix, rest
    return prefix, urllib.parse.unquote_plus(rest)


def parse_vhmsg(line: str) -> VhRequest | None:
    """A `vrAgentBML ... request <xml>` line -> its address and XML; None for any other VHMsg traffic (other
    prefixes, `start`/`end` replies, ours among them). Refused, with the address to answer, when a request is
    malformed."""
    prefix, args = vhmsg_split(line)
    if prefix != VHMSG_PREFIX:
        return None
    words = args.split(None, 3)
    if len(words) >= 3 and words[2] == "request":
        address, xml = VhAddress(words[0], words[1]), (words[3] if len(words) > 3 else "")
    else:  # the older form: vrAgentBML <char> <recipient> <msgId> request <xml> (SmartBody's USE_RECIPIENT)
        words = args.split(None, 4)
        if len(words) < 4 or words[3] != "request":
            return None
        address, xml = VhAddress(words[0], words[2], recipient=words[1]), (words[4] if len(words) > 4 else "")
    xml = xml.strip()
    if len(xml) >= 2 and xml[0] == xml[-1] == '"':  # SmartBody accepts the XML in double quotes
        xml = xml[1:-1]
    if not xml:
        raise Refused("PARSING_FAILURE", "vrAgentBML request without XML", character=address.character, vh=address)
    if len(xml) > MAX_BODY_CHARS:
        raise Refused("PARSING_FAILURE", f"the request's XML is {len(xml)} characters, over the limit of "
                                         f"{MAX_BODY_CHARS}", character=address.character, vh=address)
    return VhRequest(address, xml)


# --- feedback ----------------------------------------------------------------------------------------------------


def one_line(text: str, limit: int = MAX_TEXT) -> str:
    flat = " ".join(text.split())
    return flat if len(flat) <= limit else flat[: limit - 3] + "..."


def warning_xml(block: str, kind: str, text: str, character: str = "") -> str:
    """The standard's warningFeedback element."""
    who = f" characterId={quoteattr(character)}" if character else ""
    return (f"<warningFeedback xmlns=\"{BML_NS}\" id={quoteattr(block or 'unknown')}{who} type={quoteattr(kind)}>"
            f"{escape(one_line(text))}</warningFeedback>")


def feedback_xml(fb: BmlFeedback) -> str:
    """The realizer's own XML of a feedback, or one built from its fields when it sent none."""
    if fb.xml:
        return fb.xml
    who = f" characterId={quoteattr(fb.agent)}"
    if fb.kind == "blockProgress":
        return (f"<blockProgress xmlns=\"{BML_NS}\" id={quoteattr(f'{fb.block}:{fb.sync}')}"
                f" globalTime=\"{fb.global_ns / 1e9:.3f}\"{who}/>")
    if fb.kind == "syncPointProgress":
        return (f"<syncPointProgress xmlns=\"{BML_NS}\" id={quoteattr(f'{fb.block}:{fb.behaviour}:{fb.sync}')}"
                f" time=\"{fb.time_s:.3f}\" globalTime=\"{fb.global_ns / 1e9:.3f}\"{who}/>")
    if fb.kind == "warningFeedback":
        block = f"{fb.block}:{fb.behaviour}" if fb.behaviour else fb.block
        return warning_xml(block, fb.sync or "CUSTOM", fb.text, fb.agent)
    return (f"<predictionFeedback xmlns=\"{BML_NS}\"{who}><bml id={quoteattr(fb.block)}"
            f" globalStart=\"{fb.global_ns / 1e9:.3f}\" globalEnd=\"{fb.end_ns / 1e9:.3f}\"/></predictionFeedback>")


_STATUS = re.compile(r"\bstatus\s*=\s*[\"']([A-Za-z_]+)[\"']")


def end_status(fb: BmlFeedback) -> str:
    """How an end blockProgress says the block ended: complete, interrupted or error (AsapRealizer's bmla:status
    DONE, INTERRUPTED/REVOKED, FAILED; none: complete)."""
    m = _STATUS.search(fb.xml)
    status = m.group(1).upper() if m else ""
    if status in ("INTERRUPTED", "REVOKED"):
        return "interrupted"
    if status == "FAILED":
        return "error"
    return "complete"


@dataclass(frozen=True)
class Outgoing:
    """One STOMP frame to send."""

    destination: str
    body: str
    headers: dict[str, str] = field(default_factory=dict)


@dataclass
class Origin:
    """Where a block came from, to send its feedback back there."""

    transport: str
    agent: str
    block: str
    vh: VhAddress | None = None
    started: bool = False
    interrupted: bool = False
    warning: tuple[str, str] | None = None  # the realizer's latest warning about it: (type, text)


class FeedbackRouter:
    """The blocks on their way (by the request id of their `bml` command) and what each feedback becomes on the
    STOMP side. Pure: no sockets, so the mapping is tested on its own."""

    def __init__(self, routes: Routes | None = None, max_pending: int = PENDING_MAX) -> None:
        self.routes = routes or Routes()
        self.max_pending = max_pending
        self.pending: OrderedDict[str, Origin] = OrderedDict()
        self.forgotten = 0

    def open(self, request_id: str, origin: Origin) -> None:
        self.pending[request_id] = origin
        while len(self.pending) > self.max_pending:
            self.pending.popitem(last=False)
            self.forgotten += 1

    def feedback(self, fb: BmlFeedback, now_ms: int) -> list[Outgoing]:
        origin = self.pending.get(fb.request_id)
        if origin is None:
            return []  # a block another client sent on the bus, or one already ended
        if origin.transport == "asap":
            out = [Outgoing(self.routes.feedback("asap"), feedback_xml(fb))]
        else:
            out = []
        if fb.kind == "blockProgress" and fb.sync == "start":
            if not origin.started:
                origin.started = True
                out += self._block_event(origin, "start", fb, now_ms)
        elif fb.kind == "blockProgress" and fb.sync == "end":
            status = "interrupted" if origin.interrupted else end_status(fb)
            if status == "complete" and fb.text:  # eca's realizer ends a block it cut short with the reason
                status = "interrupted"
            out += self._end(fb.request_id, origin, status, "", fb, now_ms)
        elif fb.kind == "warningFeedback":
            origin.warning = (fb.sync, fb.text)
            if "INTERRUPT" in fb.sync.upper():  # the type, not the text: "<bmla:interrupt> ignored" is no interruption
                origin.interrupted = True
                if not origin.started:  # stopped before it began: no end follows that a client could wait for
                    out += self._end(fb.request_id, origin, "interrupted", "", fb, now_ms)
            elif not fb.behaviour and fb.sync in REFUSING and not origin.started:
                out += self._end(fb.request_id, origin, "error", f"{fb.sync}: {fb.text}", fb, now_ms)
        return out

    def rejected(self, error: Error, now_ms: int) -> list[Outgoing]:
        """The bus refused a block's command (an Error with its request id): a warning, and the block ends."""
        origin = self.pending.get(error.request_id)
        if origin is None:
            return []
        out = []
        if origin.warning is not None and origin.warning[1] == error.reason:
            # eca's realizer refuses a block with a warningFeedback (passed on already) and this error: its type
            kind, text = origin.warning
        else:
            kind = "IMPOSSIBLE_TO_SCHEDULE" if error.kind in ("rejected", "busy") else "PARSING_FAILURE"
            text = f"{error.service or 'eca'} refused the block: {error.reason}"
            if origin.transport == "asap":
                out.append(Outgoing(self.routes.feedback("asap"), self._warning(origin, kind, text)))
        return out + self._end(error.request_id, origin, "error", f"{kind}: {text}", None, now_ms,
                               self._warning(origin, kind, text))

    def _warning(self, origin: Origin, kind: str, text: str) -> str:
        return warning_xml(origin.block or (origin.vh.message_id if origin.vh else ""), kind, text, origin.agent)

    def refused(self, transport: str, problem: Refused, now_ms: int) -> list[Outgoing]:
        """The bridge's own answer to a frame it could not forward."""
        block = problem.block or (problem.vh.message_id if problem.vh else "")
        xml = warning_xml(block, problem.kind, problem.text, problem.character)
        if transport == "asap":
            return [Outgoing(self.routes.feedback("asap"), xml)]
        if transport == "greta":
            return [self._greta("dead", block, now_ms, xml)]
        if problem.vh is not None:
            return [self._vh(problem.vh, f"end error {problem.kind}: {one_line(problem.text)}")]
        return []  # a VHMsg frame too broken to say whom to answer: the log line is all

    def _end(self, request_id: str, origin: Origin, status: str, text: str, fb: BmlFeedback | None, now_ms: int,
             xml: str = "") -> list[Outgoing]:
        del self.pending[request_id]
        if origin.transport == "greta":
            kind = {"complete": "end", "interrupted": "stopped", "error": "dead"}[status]
            return [self._greta(kind, origin.block, greta_ms(fb, now_ms), xml or (feedback_xml(fb) if fb else ""))]
        if origin.transport == "vhmsg" and origin.vh is not None:
            words = f"end {status}" + (f" {one_line(text)}" if status == "error" and text else "")
            return [self._vh(origin.vh, words)]
        return []

    def _block_event(self, origin: Origin, what: str, fb: BmlFeedback, now_ms: int) -> list[Outgoing]:
        if origin.transport == "greta":
            return [self._greta(what, origin.block, greta_ms(fb, now_ms), feedback_xml(fb))]
        if origin.transport == "vhmsg" and origin.vh is not None:
            return [self._vh(origin.vh, what)]
        return []

    def _greta(self, kind: str, block: str, time_ms: int, xml: str) -> Outgoing:
        headers = {"feedback-type": kind, "feedback-id": block or "unknown", "feedback-time": str(time_ms)}
        return Outgoing(self.routes.feedback("greta"), xml, headers)

    def _vh(self, address: VhAddress, words: str) -> Outgoing:
        scope = self.routes.vhmsg_scope
        return Outgoing(self.routes.feedback("vhmsg"), address.reply(words),
                        {"ELVISH_SCOPE": scope, "MESSAGE_PREFIX": VHMSG_PREFIX})


def greta_ms(fb: BmlFeedback | None, now_ms: int) -> int:
    """Greta's `feedback-time`: milliseconds, on the master clock when the realizer said when."""
    return fb.global_ns // 1_000_000 if fb is not None and fb.global_ns else now_ms


# --- frames in ---------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Frame:
    transport: str
    body: bytes


class InboundQueue:
    """Frames from the STOMP thread to the bridge's loop, at most `maxsize`; the rest dropped and counted."""

    def __init__(self, maxsize: int = QUEUE_MAX) -> None:
        self._q: queue.Queue[Frame] = queue.Queue(maxsize)
        self._lock = threading.Lock()
        self.dropped = 0

    def put(self, frame: Frame) -> bool:
        try:
            self._q.put_nowait(frame)
            return True
        except queue.Full:
            with self._lock:
                self.dropped += 1
            return False

    def take(self, limit: int) -> list[Frame]:
        out: list[Frame] = []
        while len(out) < limit:
            try:
                out.append(self._q.get_nowait())
            except queue.Empty:
                break
        return out

    def __len__(self) -> int:
        return self._q.qsize()


@dataclass(frozen=True)
class Forward:
    """A block to send on the bus: its command and where its feedback goes."""

    command: Bml
    origin: Origin


class Translator:
    """Frames -> `bml` commands, or the bridge's own warnings. Pure but for the request ids it makes."""

    def __init__(self, default_agent: str, prefix: str | None = None) -> None:
        self.default_agent = default_agent
        self.prefix = prefix or f"bmlb-{os.urandom(3).hex()}"
        self.agents: frozenset[str] | None = None  # the live agents (state.*.agents); None until known
        self._count = 0

    def request_id(self) -> str:
        self._count += 1
        return f"{self.prefix}-{self._count}"

    def translate(self, frame: Frame) -> Forward | None:
        """The block in a frame; None for VHMsg traffic that is not a BML request; Refused when it is bad."""
        vh: VhAddress | None = None
        try:
            if frame.transport == "vhmsg":
                if frame.body.lstrip()[: len(VHMSG_PREFIX) + 1].rstrip() != VHMSG_PREFIX.encode():
                    return None  # the scope's other traffic, whatever it holds, is none of the bridge's business
                request = parse_vhmsg(decode_body(frame.body, VHMSG_ESCAPE_ROOM * MAX_BODY_CHARS + 1024))
                if request is None:
                    return None
                vh, xml = request.address, request.xml
            else:
                xml = decode_body(frame.body)
        except Refused as problem:  # too long or not UTF-8: its id, if one shows, so the sender knows which
            problem.block = problem.block or guess_block(frame.body[:4096].decode("utf-8", "replace"))
            raise
        try:
            head = block_head(xml)
        except Refused as problem:
            problem.vh, problem.character = vh, vh.character if vh else problem.character
            raise
        agent = vh.character if vh is not None else (head.character or self.default_agent)
        if not is_agent_id(agent) or agent == ALL_AGENTS or (self.agents is not None and agent not in self.agents):
            raise Refused(UNKNOWN_CHARACTER, f"no agent {agent[:40]!r} in this instance"
                          + (f" (it has {', '.join(sorted(self.agents))})" if self.agents is not None else ""),
                          block=head.block, character=agent[:64], vh=vh)
        command = Bml(agent=agent, request_id=self.request_id(), xml=xml)
        return Forward(command, Origin(frame.transport, agent, head.block, vh))


# --- the STOMP side ----------------------------------------------------------------------------------------------


class StompLink:
    """The connection to the ActiveMQ broker in a thread of its own: connects, subscribes (waiting for the broker's
    receipts, so nothing sent afterwards is missed), and on a lost connection connects again with backoff, logged
    once per outage. Frames go to `on_frame` (in stomp.py's receiver thread)."""

    def __init__(self, host: str, port: int, subscriptions: dict[str, str], on_frame: Callable[[Frame], object],
                 user: str | None = None, password: str | None = None, heartbeat_ms: int = HEARTBEAT_MS) -> None:
        self.host, self.port = host, port
        self.subscriptions = subscriptions  # destination -> transport
        self.on_frame = on_frame
        self.user, self.password = user, password
        self.heartbeat_ms = heartbeat_ms
        self.where = f"{host}:{port}"
        self.connections = 0  # how many times it connected (a test sees a reconnection)
        self.unsent = 0  # frames that could not go out while no connection was up
        self._conn: Any = None
        self._stop = threading.Event()
        self._lost = threading.Event()
        self._connected = threading.Event()
        self._receipts: dict[str, threading.Event] = {}
        self._why = ""
        self._generation = 0  # whose callbacks count: an old connection's late "disconnected" must not end a new one
        self._thread = threading.Thread(target=self._run, name="stomp", daemon=True)
        # stomp.py logs every failed attempt and every connection; the link says what matters, once per outage
        logging.getLogger("stomp.py").setLevel(logging.ERROR)

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        conn = self._conn
        if conn is not None:
            try:
                conn.disconnect()  # DISCONNECT with a receipt; stomp.py closes the socket when it comes
            except Exception:  # a connection already gone has nothing to close
                pass
            self._lost.wait(2.0)
            _close(conn)
        self._thread.join(timeout=5.0)

    @property
    def connected(self) -> bool:
        return self._conn is not None and not self._lost.is_set()

    def send(self, out: Outgoing) -> bool:
        """Send one frame without `content-length` (a JMS TextMessage on ActiveMQ); False when no connection is up."""
        conn = self._conn
        if conn is None or self._lost.is_set():
            self.unsent += 1
            return False
        try:
            conn.send(out.destination, out.body, headers=dict(out.headers))
            return True
        except Exception:  # the connection just went: the link thread reconnects
            self.unsent += 1
            return False

    # -- the thread --

    def _run(self) -> None:
        delay = BACKOFF_S[0]
        down_since: float | None = None
        while not self._stop.is_set():
            try:
                conn = self._open()
            except Exception as exc:  # any failure to connect is retried
                if down_since is None:
                    down_since = time.monotonic()
                    log.warning("STOMP %s: cannot connect (%s); retrying with backoff up to %g s, logged once until "
                                "it connects", self.where, describe(exc), BACKOFF_S[1])
                self._stop.wait(delay * (1.0 + 0.1 * random.random()))
                delay = min(2 * delay, BACKOFF_S[1])
                continue
            self.connections += 1
            if down_since is not None and self.connections > 1:
                log.info("STOMP %s: reconnected after %.1f s", self.where, time.monotonic() - down_since)
            log.info("STOMP %s: connected; subscribed to %s", self.where, ", ".join(self.subscriptions))
            down_since, delay = None, BACKOFF_S[0]
            self._conn = conn
            while not self._stop.is_set() and not self._lost.wait(0.25):
                pass
            self._conn = None
            down_since = time.monotonic()
            # stomp.py says "disconnected" first and "heart-beat timeout" right after: a moment for the reason
            self._stop.wait(0.1)
            _close(conn)
            if self._stop.is_set():
                break
            log.warning("STOMP %s: connection lost (%s); reconnecting with backoff up to %g s, logged once until it "
                        "is back", self.where, self._why or "closed", BACKOFF_S[1])

    def _open(self) -> Any:
        import stomp  # type: ignore[import-untyped]  # stomp.py has no type information

        self._generation += 1
        self._lost.clear()
        self._connected.clear()
        self._why = ""
        # auto_decode off: bodies arrive as bytes, so one that is not UTF-8 is seen (not replaced); content-length
        # off: what the bridge sends is a TextMessage for JMS readers (see the module's docstring). The timeout is
        # the TCP connect's (stomp.py reads blocking); heart-beats tell a dead broker, TCP keep-alive one that
        # refuses heart-beats.
        conn = stomp.Connection([(self.host, self.port)], heartbeats=(self.heartbeat_ms, self.heartbeat_ms),
                                reconnect_attempts_max=1, timeout=CONNECT_TIMEOUT_S, keepalive=True,
                                auto_decode=False, auto_content_length=False)
        conn.set_listener("eca-bml-bridge", _Listener(self, self._generation))
        try:
            conn.connect(self.user, self.password, wait=False)
            if not self._connected.wait(CONNECT_TIMEOUT_S) or self._lost.is_set():
                raise ConnectionError(self._why or f"no CONNECTED within {CONNECT_TIMEOUT_S:g} s")
            for destination, name in self.subscriptions.items():
                receipt = f"sub-{name}-{os.urandom(4).hex()}"
                done = self._receipts[receipt] = threading.Event()
                conn.subscribe(destination, id=name, ack="auto", headers={"receipt": receipt})
                if not done.wait(CONNECT_TIMEOUT_S) or self._lost.is_set():
                    raise ConnectionError(self._why or f"no receipt for the subscription to {destination}")
                self._receipts.pop(receipt, None)
        except BaseException:
            _close(conn)
            raise
        return conn


class _Listener:
    """stomp.py's callbacks (its receiver thread), for one connection: those of a replaced one are ignored."""

    def __init__(self, link: StompLink, generation: int) -> None:
        self.link = link
        self.generation = generation

    @property
    def current(self) -> bool:
        return self.generation == self.link._generation

    def on_connected(self, frame: Any) -> None:
        if self.current:
            self.link._connected.set()

    def on_receipt(self, frame: Any) -> None:
        done = self.link._receipts.get(frame.headers.get("receipt-id", ""))
        if done is not None:
            done.set()

    def on_error(self, frame: Any) -> None:
        if self.current:
            message = frame.headers.get("message", "")
            self.link._why = f"broker error: {one_line(str(message), 200)}"
            log.warning("STOMP %s: %s", self.link.where, self.link._why)

    def on_heartbeat_timeout(self) -> None:
        if self.current:
            self.link._why = "no heart-beat from the broker"

    def on_disconnected(self) -> None:
        if self.current:
            self.link._lost.set()
            self.link._connected.set()  # wakes a connect that is waiting

    def on_message(self, frame: Any) -> None:
        transport = self.link.subscriptions.get(frame.headers.get("destination", ""))
        if transport is None:  # by the subscription id, should a broker rewrite the destination
            transport = frame.headers.get("subscription", "")
        body = frame.body if isinstance(frame.body, bytes) else str(frame.body).encode()
        if transport in TRANSPORTS:
            self.link.on_frame(Frame(transport, body))


def _close(conn: Any) -> None:
    try:
        conn.transport.disconnect_socket()
    except Exception:  # closing what may already be closed
        pass


def describe(exc: BaseException) -> str:
    text = str(exc)
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


# --- the bridge --------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class BridgeOptions:
    host: str
    port: int
    agent: str
    transports: frozenset[str] = frozenset(TRANSPORTS)
    user: str | None = None
    password: str | None = None
    vhmsg_scope: str = VHMSG_SCOPE
    heartbeat_ms: int = HEARTBEAT_MS
    queue_max: int = QUEUE_MAX


class BmlBridge:
    def __init__(self, config: BusConfig, options: BridgeOptions) -> None:
        self.config = config
        self.options = options
        self.routes = Routes(options.vhmsg_scope)
        self.router = FeedbackRouter(self.routes)
        self.translator = Translator(options.agent)
        self.inbound = InboundQueue(options.queue_max)
        self.refused = 0
        self._refused_window = (0.0, 0)  # (since, how many) refusals logged one by one in this second
        self._refused_unsaid = 0
        self._dropped_said = 0
        self._dropped_at = 0.0
        self._stop = threading.Event()
        subscriptions = {self.routes.request(t): t for t in TRANSPORTS if t in options.transports}
        self.link = StompLink(options.host, options.port, subscriptions, self.inbound.put, options.user,
                              options.password, options.heartbeat_ms)

    def request_stop(self) -> None:
        self._stop.set()

    def run(self, install_signals: bool = True) -> int:
        if install_signals:
            for sig in (signal.SIGINT, signal.SIGTERM):
                signal.signal(sig, lambda *_: self._stop.set())
        try:
            client = AgentClient(self.config, agent=self.options.agent, source="bml-bridge",
                                 timeout_s=self.config.connect_timeout_s)
        except BusTimeout as exc:
            log.error("no eca instance at %s: %s", self.config.backend, exc)
            return 1
        try:
            # every agent's feedback and errors, and the live agents (its cached state comes first)
            for prefix in ("event.", "error.", "state.*.agents"):
                client.sub.subscribe(prefix)
            for got in client.sub.wait_ready(self.config.connect_timeout_s):
                if got.message is not None:
                    self.on_bus(got.message)
            self.link.start()
            log.info("ready: bus %s (instance %r), STOMP %s, %s; default agent %r", self.config.backend,
                     self.config.instance, self.link.where, ", ".join(sorted(self.options.transports)),
                     self.options.agent)
            while not self._stop.is_set():
                self.step(client)
        except BusTimeout as exc:
            log.error("the bus did not answer: %s", exc)
            return 1
        finally:
            self.link.stop()
            client.close()
        log.info("stopped")
        return 0

    def step(self, client: AgentClient) -> None:
        """One turn: the bus's messages, then a batch of frames."""
        got = client.sub.recv(0.0 if len(self.inbound) else 0.02)
        received = [got] if got is not None else []
        received += client.sub.drain(BATCH) if got is not None else []
        for r in received:
            if r.message is not None:
                self.on_bus(r.message)
        for frame in self.inbound.take(BATCH):
            self.on_frame(client, frame)
        self._say_drops()

    def on_bus(self, msg: Message) -> None:
        now_ms = time.monotonic_ns() // 1_000_000
        if isinstance(msg, BmlFeedback):
            self._send(self.router.feedback(msg, now_ms))
        elif isinstance(msg, AgentsState):
            self.translator.agents = frozenset(msg.agents)
        elif isinstance(msg, Error) and msg.request_id:
            self._send(self.router.rejected(msg, now_ms))

    def on_frame(self, client: AgentClient, frame: Frame) -> None:
        now_ms = time.monotonic_ns() // 1_000_000
        try:
            forward = self.translator.translate(frame)
            if forward is None:
                return
            try:
                client.send(forward.command)
            except ProtocolError as exc:  # a block the codec refuses (it checks what the bridge did not)
                raise Refused("PARSING_FAILURE", str(exc), forward.origin.block, forward.origin.agent,
                              forward.origin.vh) from None
        except Refused as problem:
            self.refused += 1
            self._say_refused(frame.transport, problem)
            self._send(self.router.refused(frame.transport, problem, now_ms))
            return
        self.router.open(forward.command.request_id, forward.origin)

    def _send(self, frames: Iterable[Outgoing]) -> None:
        for out in frames:
            if not self.link.send(out):
                log.debug("no STOMP connection: dropped a frame for %s", out.destination)

    def _say_refused(self, transport: str, problem: Refused) -> None:
        """A line per refused frame, at most REFUSALS_SAID a second: a flood of bad frames must not become a flood
        of log lines (the rest are counted and said once a second)."""
        now = time.monotonic()
        since, said = self._refused_window
        if now - since >= 1.0:
            self._say_unsaid()
            since, said = now, 0
        if said < REFUSALS_SAID:
            log.warning("%s frame refused (%d so far): %s: %s", transport, self.refused, problem.kind,
                        one_line(problem.text, 200))
            said += 1
        else:
            self._refused_unsaid += 1
        self._refused_window = (since, said)

    def _say_unsaid(self) -> None:
        if self._refused_unsaid:
            log.warning("%d more frames refused (%d so far); the first %d of each second are logged one by one",
                        self._refused_unsaid, self.refused, REFUSALS_SAID)
            self._refused_unsaid = 0

    def _say_drops(self) -> None:
        if time.monotonic() - self._refused_window[0] >= 1.0:  # the flood of bad frames is over: its count
            self._say_unsaid()
        dropped = self.inbound.dropped
        if dropped > self._dropped_said and time.monotonic() - self._dropped_at >= 1.0:
            log.warning("flood: dropped %d frames (queue full at %d), %d in all", dropped - self._dropped_said,
                        self.options.queue_max, dropped)
            self._dropped_said, self._dropped_at = dropped, time.monotonic()
