"""Keeps a child command from outliving the process that started this one: run as a script (by path,
so it imports nothing of eca or pipecat) with that process's pid and the command:

    python services/pipecat/guard.py PARENT_PID [--clean DIR FILE...] -- eca up ...

It runs the command in its own process group, passes the command's output through (and keeps reading it
when its own output is gone, so the command never dies of a broken pipe half-way through its cleanup),
and exits with the command's exit code. A Ctrl-C to the group reaches the command, which stops as it
would in a terminal; the guard just waits for it. When the parent process dies without stopping it (a
SIGKILL, a crash), the guard sends the command SIGINT itself (SIGKILL after `GRACE_S`), so `eca up`
stops its services and removes its runtime files. Whatever the command left of the named FILEs in DIR
(an `eca up` whose services did not all stop keeps them) the guard removes, and DIR when it is empty:
no process and no file is left behind.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading

GRACE_S = 15.0
PARENT_POLL_S = 0.25  # Linux has no event for "my parent died" (but prctl, per thread): poll it


def _pass_through(stream: object) -> None:
    out = sys.stdout.buffer
    for line in iter(stream.readline, b""):  # type: ignore[attr-defined]
        try:
            out.write(line)
            out.flush()
        except OSError:  # the parent is gone: keep draining, so the command's writes never fail
            pass


def _clean(directory: str, names: list[str]) -> None:
    for name in names:
        try:
            os.unlink(os.path.join(directory, name))
        except OSError:
            pass  # already gone (the command removed it), or never made
    try:
        os.rmdir(directory)
    except OSError:
        pass  # something else lives there: not ours to remove


def main(argv: list[str]) -> int:
    if "--" not in argv or not argv[0].isdigit() or argv.index("--") == len(argv) - 1:
        print("usage: guard.py PARENT_PID [--clean DIR FILE...] -- COMMAND [ARG...]", file=sys.stderr)
        return 2
    split = argv.index("--")
    parent, options, command = int(argv[0]), argv[1:split], argv[split + 1:]
    clean = options[1:] if options[:1] == ["--clean"] and len(options) >= 2 else None
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # a Ctrl-C to the group is the command's to handle
    signal.signal(signal.SIGTERM, lambda *_: child.send_signal(signal.SIGINT))
    child = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                             preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    reader = threading.Thread(target=_pass_through, args=(child.stdout,), daemon=True)
    reader.start()
    while True:
        try:
            code = child.wait(timeout=PARENT_POLL_S)
            break
        except subprocess.TimeoutExpired:
            pass
        if os.getppid() != parent:
            child.send_signal(signal.SIGINT)
            try:
                code = child.wait(timeout=GRACE_S)
            except subprocess.TimeoutExpired:
                child.kill()
                code = child.wait()
            break
    reader.join(timeout=2.0)
    if clean is not None:
        _clean(clean[0], clean[1:])
    return code


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
