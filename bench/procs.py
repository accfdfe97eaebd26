"""What the benches read of processes from /proc: every process's parent and CPU time, a process tree, a
process's memory and what it is. One place, so every bench counts CPU and memory the same way."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

MEMORY_KINDS = ("pss", "rss", "uss")
RUN_MODULE = "eca.services.processes.run"  # `python -m eca.services.processes.run NAME`: an eca service


@dataclass(frozen=True)
class ProcStat:
    ppid: int
    state: str
    own_ticks: int  # utime + stime: its own CPU
    reaped_ticks: int  # cutime + cstime: that of the children it has reaped
    start: int  # starttime (ticks after boot): with the pid, names the process even if the pid is reused

    @property
    def cpu_ticks(self) -> int:
        return self.own_ticks + self.reaped_ticks


def _stat(pid: int | str) -> ProcStat:
    # The command name (field 2) may hold spaces and parentheses: the fields after its last ')' are fixed.
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return ProcStat(int(fields[1]), fields[0], int(fields[11]) + int(fields[12]), int(fields[13]) + int(fields[14]),
                    int(fields[19]))


def proc_table() -> dict[int, ProcStat]:
    """Every process of the machine now."""
    table: dict[int, ProcStat] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                table[int(entry.name)] = _stat(entry.name)
            except (OSError, IndexError, ValueError):
                continue  # gone meanwhile
    return table


def descendants(root: int, table: dict[int, ProcStat] | None = None) -> list[int]:
    """`root` and every process below it, each after its parent."""
    table = proc_table() if table is None else table
    children: dict[int, list[int]] = {}
    for pid, stat in table.items():
        children.setdefault(stat.ppid, []).append(pid)
    tree, todo = [], [root]
    while todo:
        pid = todo.pop()
        if pid in table:
            tree.append(pid)
            todo.extend(sorted(children.get(pid, []), reverse=True))
    return tree


def cpu_seconds(pid: int) -> float:
    """The process's own CPU time (user + system) so far."""
    return _stat(pid).own_ticks / os.sysconf("SC_CLK_TCK")


def memory_kib(pid: int) -> dict[str, int] | None:
    """PSS, RSS and USS in KiB, from smaps_rollup; None when the process is gone (or not ours to read). PSS splits
    each shared page among the processes that map it, so a tree's sum counts shared libraries once; USS is what
    the process alone holds."""
    try:
        text = Path(f"/proc/{pid}/smaps_rollup").read_text()
    except OSError:
        return None
    fields: dict[str, int] = {}
    for line in text.splitlines():
        parts = line.split()
        if len(parts) >= 2 and parts[0].endswith(":") and parts[1].isdigit():
            fields[parts[0][:-1]] = int(parts[1])
    return {"pss": fields.get("Pss", 0), "rss": fields.get("Rss", 0),
            "uss": fields.get("Private_Clean", 0) + fields.get("Private_Dirty", 0)}


def pss_mib(pid: int) -> float:
    got = memory_kib(pid)
    return got["pss"] / 1024 if got is not None else float("nan")


def argv_of(pid: int) -> list[str] | None:
    try:
        return [w.decode("utf-8", "replace") for w in Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0") if w]
    except OSError:
        return None


def eca_label(pid: int, root: int, root_label: str = "supervisor") -> str:
    """`root_label` for the tree's root, the service's name for an eca service, else the program's name."""
    if pid == root:
        return root_label
    words = argv_of(pid)
    if words is None:
        return f"pid {pid}"
    if RUN_MODULE in words:
        at = words.index(RUN_MODULE)
        if at + 1 < len(words):
            return words[at + 1]
    return Path(words[0]).name if words else f"pid {pid}"
