"""What the end-to-end benchmarks share: figures against targets, the table they print, the machine.

Each benchmark (bench/reliability.py, bench/web.py, ...) collects `Figure`s in a `Report`, prints them as
a table of value, target and verdict under a header naming the machine, and can print the whole report as
one JSON object.
"""

from __future__ import annotations

import os
import signal
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO


@dataclass
class Figure:
    name: str
    value: Any
    target: str
    met: bool | None  # None: for information, no target
    unit: str = ""
    note: str = ""


@dataclass
class Report:
    figures: list[Figure] = field(default_factory=list)
    details: dict[str, Any] = field(default_factory=dict)

    def add(self, name: str, value: Any, target: str = "-", met: bool | None = None, unit: str = "",
            note: str = "") -> None:
        self.figures.append(Figure(name, value, target, met, unit, note))

    @property
    def met(self) -> bool:
        return all(f.met for f in self.figures if f.met is not None)

    def print_table(self, header: str, out: TextIO, said: list[str] = (), said_title: str = "",
                    value_width: int = 24) -> None:
        """The figures, one per line: name, value, target and verdict (met, MISSED, info), then up to eight
        notable lines the system under test said."""
        print(header, file=out)
        name_w = max((len(f.name) for f in self.figures), default=10)
        value_w = max((len(format_value(f, value_width)) for f in self.figures), default=8)
        target_w = max((len(f.target) for f in self.figures), default=6)
        for f in self.figures:
            verdict = "info" if f.met is None else ("met" if f.met else "MISSED")
            print(f"  {f.name:<{name_w}}  {format_value(f, value_width):>{value_w}}  target "
                  f"{f.target:<{target_w}}  {verdict:<6}  {f.note}".rstrip(), file=out)
        if said:
            print(said_title, file=out)
            for line in list(said)[:8]:
                print(f"  {line[:200]}", file=out)
        out.flush()

    def as_json(self) -> dict[str, Any]:
        return {"figures": [f.__dict__ for f in self.figures], "met": self.met, "details": self.details}


def format_value(f: Figure, width: int = 24) -> str:
    text = f"{f.value}{' ' + f.unit if f.unit and not isinstance(f.value, str) else ''}"
    return text if len(text) <= width else text[: width - 3] + "..."  # the JSON keeps it whole


def machine() -> dict[str, Any]:
    """Cores, CPU model and load: the caveat every figure carries on a shared machine."""
    model = ""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {"cores": os.cpu_count(), "cpu": model, "load_average": [round(x, 2) for x in os.getloadavg()]}


def percentile(values: list[float], q: float) -> float:
    """The q-quantile (q in [0, 1]) by linear interpolation between order statistics."""
    s = sorted(values)
    pos = (len(s) - 1) * q
    lo = int(pos)
    hi = min(lo + 1, len(s) - 1)
    return s[lo] + (s[hi] - s[lo]) * (pos - lo)


def wait_until_ns(t_ns: int, while_waiting: Callable[[float], None] | None = None) -> None:
    """Pacing: return at the scheduled monotonic time (the measurement's schedule, not a synchronisation);
    `while_waiting(left_s)` is given the time to use, at most half a second at a time."""
    while (left := t_ns - time.monotonic_ns()) > 0:
        if while_waiting is not None:
            while_waiting(min(left / 1e9, 0.5))
        else:
            time.sleep(min(left / 1e9, 0.5))


@dataclass
class Run:
    """One guarded run of a benchmark: its report, the machine at the start and the wall time."""

    report: Report
    host: dict[str, Any]
    wall_s: float

    def header(self, what: str, setting: str = "") -> str:
        """The table's header: what ran, on what machine, under what load, for how long."""
        h = self.host
        return (f"{what} on {h['cores']} cores ({h['cpu'] or 'unknown CPU'}), load average "
                f"{'/'.join(f'{x:g}' for x in h['load_average'])} at start; {self.wall_s:.0f} s"
                f"{'; ' + setting if setting else ''}. Figures come from a shared machine: other work on it "
                "moves them.")


def stop_on_signal(signum: int, frame: Any) -> None:
    raise KeyboardInterrupt(f"signal {signum}")


def run_guarded(run: Callable[[Report], None]) -> Run:
    """Run a benchmark so that Ctrl-C or SIGTERM unwinds it like an exception (its instances and helpers
    stop) and a failure becomes a figure of the report rather than a traceback."""
    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.signal(signal.SIGTERM, stop_on_signal)
    host = machine()
    t0 = time.monotonic()
    report = Report()
    try:
        run(report)
    except KeyboardInterrupt:
        report.add("run", "interrupted", "complete", False)
    except Exception as exc:  # the bench reports its own failure as a figure rather than dying
        report.add("run", "bench failed", "complete", False, "", f"{type(exc).__name__}: {exc}"[:200])
        report.details.setdefault("exceptions", []).append(traceback.format_exc())
    return Run(report, host, time.monotonic() - t0)
