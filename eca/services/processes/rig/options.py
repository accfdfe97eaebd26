"""The rig service's settings: its rate, its agents, and where its VMC and Live Link receivers listen.

From the config's [rig] table, overridden on the command line (`eca rig --vmc HOST:PORT ...`, `eca up --rig-vmc
HOST:PORT ...`; the service itself takes `eca rig`'s spelling). Everything is checked, and each receiver's host
resolved, before anything starts: a bad value is one `RigOptionsError` naming the option (as the user spelled it)
and what is wrong with it.

Several agents: each VMC stream carries one avatar (the protocol has no subject), so agent i of the list sends to
the VMC port + i; Live Link names its subjects, so every agent goes to the one Live Link port as a subject named
after the agent.
"""

from __future__ import annotations

import argparse
import math
import socket
from dataclasses import dataclass, fields, replace
from typing import Any

VMC_DEFAULT_PORT = 39539  # the VMC protocol's receiver ("Marionette") port
LIVELINK_DEFAULT_PORT = 11111  # Unreal's Live Link Face source
DEFAULT_HOST = "127.0.0.1"
VMC_SPELLINGS = ("vrm0", "vrm1", "arkit")
MIN_RATE_HZ, MAX_RATE_HZ = 1.0, 120.0


class RigOptionsError(ValueError):
    """A setting that cannot be: the message names the option and the problem, in one line."""


@dataclass(frozen=True)
class Target:
    """A receiver's address as given, and as resolved once (nothing is resolved again while sending)."""

    host: str
    port: int
    family: int = socket.AF_INET
    sockaddr: tuple[Any, ...] = ()

    @property
    def label(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"{host}:{self.port}"

    def with_port(self, port: int) -> Target:
        """The same host at another port (the VMC stream of the next agent)."""
        return replace(self, port=port, sockaddr=(self.sockaddr[0], port, *self.sockaddr[2:]))


@dataclass(frozen=True)
class RigOptions:
    rate_hz: float = 60.0
    agents: tuple[str, ...] = ()  # empty: every agent of the instance
    vmc: str = ""  # "HOST:PORT" (or "HOST", ":PORT"); empty: no VMC
    livelink: str = ""  # the same for Live Link
    vmc_names: tuple[str, ...] = ("vrm0", "arkit")
    vmc_neck_share: float = 0.3  # of the head's rotation on the Neck bone; the rest on Head

    def check(self, flags: dict[str, str] | None = None) -> RigOptions:
        """The options, checked; `flags` names each setting as the user spelled it (`--rig-rate`)."""
        name = {f.name: f.name for f in fields(self)} | (flags or {})
        if not (math.isfinite(self.rate_hz) and MIN_RATE_HZ <= self.rate_hz <= MAX_RATE_HZ):
            raise RigOptionsError(f"{name['rate_hz']}: {self.rate_hz:g} Hz is out of range; give a rate in "
                                  f"{MIN_RATE_HZ:g}..{MAX_RATE_HZ:g} Hz")
        if not self.vmc_names:
            raise RigOptionsError(f"{name['vmc_names']}: give at least one of {', '.join(VMC_SPELLINGS)}")
        unknown = [n for n in self.vmc_names if n not in VMC_SPELLINGS]
        if unknown:
            raise RigOptionsError(f"{name['vmc_names']}: unknown spelling {unknown[0]!r}; known: "
                                  f"{', '.join(VMC_SPELLINGS)}")
        if not (math.isfinite(self.vmc_neck_share) and 0.0 <= self.vmc_neck_share <= 1.0):
            raise RigOptionsError(f"{name['vmc_neck_share']}: must lie in 0..1, got {self.vmc_neck_share:g}")
        return self

    def agent_ids(self, instance_agents: tuple[str, ...], flag: str = "agents") -> tuple[str, ...]:
        """The agents to follow: the ones asked for (each an agent of the instance) or all of them."""
        unknown = [a for a in self.agents if a not in instance_agents]
        if unknown:
            raise RigOptionsError(f"{flag}: {unknown[0]!r} is not an agent of this instance "
                                  f"({', '.join(instance_agents)})")
        if len(set(self.agents)) != len(self.agents):
            raise RigOptionsError(f"{flag}: an agent is named twice")
        return self.agents or instance_agents


@dataclass(frozen=True)
class RigPlan:
    """What the service does, resolved: the agents, and for each its VMC receiver (or None), the Live Link
    receiver (or None)."""

    options: RigOptions
    agents: tuple[str, ...]
    vmc: tuple[Target, ...]  # one per agent, or empty
    livelink: Target | None


def plan(options: RigOptions, instance_agents: tuple[str, ...], flags: dict[str, str] | None = None) -> RigPlan:
    """Check the options against the instance and resolve the receivers: one RigOptionsError on any problem."""
    name = {f.name: f.name for f in fields(RigOptions)} | (flags or {})
    options = options.check(flags)
    agents = options.agent_ids(instance_agents, name["agents"])
    vmc: tuple[Target, ...] = ()
    if options.vmc:
        first = resolve(parse_target(options.vmc, VMC_DEFAULT_PORT, name["vmc"]), name["vmc"])
        last = first.port + len(agents) - 1
        if last > 65535:
            raise RigOptionsError(f"{name['vmc']}: {len(agents)} agents need the ports {first.port}..{last} (one VMC "
                                  "stream each), past 65535; give a lower port")
        vmc = tuple(first.with_port(first.port + i) for i in range(len(agents)))
    livelink = resolve(parse_target(options.livelink, LIVELINK_DEFAULT_PORT, name["livelink"]),
                       name["livelink"]) if options.livelink else None
    return RigPlan(options, agents, vmc, livelink)


def parse_target(text: str, default_port: int, flag: str) -> Target:
    """`HOST:PORT`, `[IPv6]:PORT`, `HOST` (the default port) or `:PORT` (this machine) as a Target, unresolved."""
    text = text.strip()
    host, port_text = text, ""
    if text.startswith("["):
        end = text.find("]")
        if end < 0:
            raise RigOptionsError(f"{flag} {text!r}: an IPv6 address opens '[' without closing it")
        host, rest = text[1:end], text[end + 1:]
        if rest and not rest.startswith(":"):
            raise RigOptionsError(f"{flag} {text!r}: expected [ADDRESS]:PORT")
        port_text = rest[1:]
    elif text.count(":") == 1:
        host, port_text = text.split(":")
    elif text.count(":") > 1:
        raise RigOptionsError(f"{flag} {text!r}: write an IPv6 address in brackets, [ADDRESS]:PORT")
    host = host or DEFAULT_HOST
    port = default_port
    if port_text:
        try:
            port = int(port_text)
        except ValueError:
            raise RigOptionsError(f"{flag} {text!r}: the port {port_text!r} is not a whole number") from None
    if not 1 <= port <= 65535:
        raise RigOptionsError(f"{flag} {text!r}: port {port} is out of range; give 1..65535")
    return Target(host, port)


def resolve(target: Target, flag: str) -> Target:
    """The target with its address looked up (once, before anything starts)."""
    try:
        infos = socket.getaddrinfo(target.host, target.port, type=socket.SOCK_DGRAM)
    except (socket.gaierror, UnicodeError) as exc:
        reason = exc.strerror if isinstance(exc, socket.gaierror) else "not a valid host name"
        raise RigOptionsError(f"{flag} {target.label}: cannot resolve host {target.host!r} ({reason})") from None
    family, _, _, _, sockaddr = infos[0]
    return replace(target, family=int(family), sockaddr=tuple(sockaddr))


def options_from_table(table: dict[str, Any], where: str = "[rig]") -> RigOptions:
    """Options from a config's [rig] table; unknown keys and wrong types are errors naming them."""
    known = {f.name: f for f in fields(RigOptions)}
    values: dict[str, Any] = {}
    for key, value in table.items():
        if key not in known:
            raise RigOptionsError(f"{where}: unknown key {key!r}; known: {', '.join(sorted(known))}")
        if key in ("agents", "vmc_names"):
            if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
                raise RigOptionsError(f"{where}: {key!r} must be a list of strings")
            values[key] = tuple(value)
        elif key in ("vmc", "livelink"):
            if not isinstance(value, str):
                raise RigOptionsError(f"{where}: {key!r} must be a string \"HOST:PORT\" (empty: none)")
            values[key] = value
        else:
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise RigOptionsError(f"{where}: {key!r} must be a number")
            values[key] = float(value)
    return RigOptions(**values)


def spellings(text: str) -> tuple[str, ...]:
    """`vrm0,vrm1,arkit` as a tuple (checked with the rest of the options)."""
    return tuple(part.strip() for part in text.split(",") if part.strip())


# Each setting's command-line option: `eca rig --vmc ...`; `eca up` puts `rig-` before each (`--rig-vmc`).
ARGUMENTS: dict[str, str] = {"vmc": "vmc", "livelink": "livelink", "agents": "agent", "rate_hz": "rate",
                             "vmc_names": "vmc-names"}


def add_arguments(parser: argparse.ArgumentParser | argparse._ArgumentGroup, prefix: str = "") -> None:
    """The rig options (`prefix` = "rig-" under `eca up`). A bare `--vmc` or `--livelink` sends to this machine's
    default port of that receiver."""
    p = f"--{prefix}"
    parser.add_argument(f"{p}vmc", nargs="?", const=f"{DEFAULT_HOST}:{VMC_DEFAULT_PORT}", default=None,
                        metavar="HOST:PORT", help=f"send to a VMC receiver (VSeeFace, Warudo, VMagicMirror ...); "
                                                  f"bare: {DEFAULT_HOST}:{VMC_DEFAULT_PORT}; agent i at PORT+i")
    parser.add_argument(f"{p}livelink", nargs="?", const=f"{DEFAULT_HOST}:{LIVELINK_DEFAULT_PORT}", default=None,
                        metavar="HOST:PORT", help=f"send to Unreal's Live Link Face source, one subject per agent; "
                                                  f"bare: {DEFAULT_HOST}:{LIVELINK_DEFAULT_PORT}")
    parser.add_argument(f"{p}agent", action="append", default=None, metavar="AGENT",
                        help="only this agent (repeatable; default every agent of the instance)")
    parser.add_argument(f"{p}rate", type=str, default=None, metavar="HZ",
                        help=f"frames per second (default 60, {MIN_RATE_HZ:g}..{MAX_RATE_HZ:g})")
    parser.add_argument(f"{p}vmc-names", default=None, metavar="LIST",
                        help="blend-shape names sent over VMC, comma-separated: vrm0 (Joy, A, Blink_L ...), vrm1 "
                             "(happy, aa, blinkLeft ...), arkit (Perfect Sync: EyeBlinkLeft ...); default vrm0,arkit")


def given(args: argparse.Namespace, prefix: str = "") -> dict[str, Any]:
    """The rig options given on the command line, by setting (those not given are absent)."""
    out: dict[str, Any] = {}
    for setting, option in ARGUMENTS.items():
        value = getattr(args, f"{prefix}{option}".replace("-", "_"), None)
        if value is not None:
            out[setting] = value
    return out


def flag_names(cli: dict[str, Any], prefix: str = "", where: str = "[rig]") -> dict[str, str]:
    """Where each setting came from, for error messages: its option as the user spelled it (`--rig-rate`) when
    given on the command line (`cli`, as `given` returns it), else its key in the config (`[rig] rate_hz`)."""
    return {f.name: f"--{prefix}{ARGUMENTS[f.name]}" if f.name in cli else f"{where} {f.name}"
            for f in fields(RigOptions)}


def options_from(table: dict[str, Any], cli: dict[str, Any], prefix: str = "") -> RigOptions:
    """The config's [rig] table overridden by the options given on the command line (`given`); not yet checked."""
    options = options_from_table(table)
    changes: dict[str, Any] = {}
    for setting, value in cli.items():
        if setting == "rate_hz":
            try:
                changes[setting] = float(value)
            except ValueError:
                raise RigOptionsError(f"--{prefix}rate {value!r}: not a number of frames per second") from None
        elif setting == "vmc_names":
            changes[setting] = spellings(value)
        elif setting == "agents":
            changes[setting] = tuple(value)
        else:
            changes[setting] = value
    return replace(options, **changes)


def argv_from(cli: dict[str, Any]) -> list[str]:
    """The options given (by setting, as `given` returns them) as the service's own command line (`eca rig`'s
    spelling): what `eca up` passes to the rig service it starts."""
    argv: list[str] = []
    for setting, value in cli.items():
        option = f"--{ARGUMENTS[setting]}"
        if setting == "agents":
            for agent in value:
                argv += [option, agent]
        else:
            argv += [option, str(value)]
    return argv
