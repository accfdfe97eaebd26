"""Real-time scheduling for the voice's path: the [realtime] settings, checked with clear errors; a service that
asks for it runs on SCHED_RR with every thread it makes afterwards, while the programs it starts run at the
ordinary priority; where the system does not allow it, the service says so and runs as before."""

from __future__ import annotations

import dataclasses
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from eca.protocol.endpoints import BusConfigError
from eca.services.processes.realtime import (
    DEFAULT_PRIORITY,
    DEFAULT_SERVICES,
    RealtimeSettings,
    ask_for_realtime,
    realtime_settings,
)
from eca.services.processes.run import KNOWN
from tests.support.bus import REPO_ROOT, eca_command, private_bus_config, running, subprocess_env

pytestmark = pytest.mark.skipif(not hasattr(os, "sched_setscheduler"), reason="no POSIX scheduling calls here")

PRIORITY = 7


def allowed(priority: int) -> bool:
    """Whether this system lets a process of ours take SCHED_RR at `priority` (root with CAP_SYS_NICE, or an
    RLIMIT_RTPRIO that high): asked of a throwaway child, so this process stays as it is."""
    probe = f"import os; os.sched_setscheduler(0, os.SCHED_RR, os.sched_param({priority}))"
    return subprocess.run([sys.executable, "-c", probe], capture_output=True, timeout=30).returncode == 0


def policy_of(tid: int) -> tuple[int, int]:
    """(policy without the reset-on-fork flag, priority) of one thread."""
    return os.sched_getscheduler(tid) & ~os.SCHED_RESET_ON_FORK, os.sched_getparam(tid).sched_priority


def test_the_settings_and_their_errors() -> None:
    with private_bus_config(realtime=True) as config:  # as shipped (the suite's own instances run without it)
        shipped = realtime_settings(config, KNOWN)
        assert shipped == RealtimeSettings(DEFAULT_PRIORITY, DEFAULT_SERVICES)
        assert realtime_settings(dataclasses.replace(config, raw={}), KNOWN) == shipped  # no table: the defaults
        for table, key in (({"priority": 100}, "'priority'"), ({"priority": -1}, "'priority'"),
                           ({"priority": "high"}, "'priority'"), ({"priority": True}, "'priority'"),
                           ({"services": ["web", "tts"]}, "'services'"), ({"services": "web"}, "'services'"),
                           ({"services": ["web"] * 100}, "'services'"), ({"nice": 5}, "'nice'")):
            with pytest.raises(BusConfigError) as err:
                realtime_settings(dataclasses.replace(config, raw={"realtime": table}), KNOWN)
            assert f"{config.config_path} [realtime]" in str(err.value) and key in str(err.value)
        with pytest.raises(BusConfigError, match="'realtime' must be a table"):
            realtime_settings(dataclasses.replace(config, raw={"realtime": 3}), KNOWN)
        off = realtime_settings(dataclasses.replace(config, raw={"realtime": {"priority": 0}}), KNOWN)
        assert ask_for_realtime("web", off) is None  # 0: nobody asks
        assert ask_for_realtime("gaze", shipped) is None  # not on the voice's path


ENGINE = ("import io, os, sys, wave; p = os.sched_getscheduler(0) & ~os.SCHED_RESET_ON_FORK; b = io.BytesIO(); "
          "w = wave.open(b, 'wb'); w.setnchannels(1); w.setsampwidth(2); w.setframerate(16000); "
          "w.writeframes(bytes(2 * (100 + p))); w.close(); sys.stdout.buffer.write(b.getvalue())")


def test_a_service_its_threads_and_the_programs_it_starts() -> None:
    # a TTS engine (the "command" kind) whose speech is 100 + its own scheduling policy samples long
    script = f"""
import os, subprocess, sys, threading
from eca.services.processes.audio.tts import EngineSettings, engine
from eca.services.processes.realtime import RealtimeSettings, ask_for_realtime
print(ask_for_realtime("audio", RealtimeSettings({PRIORITY}, ("audio",))))
tts = engine(EngineSettings(engine="command", command=(sys.executable, "-c", {ENGINE!r})))
seen = []
def preparer():
    seen.append(os.sched_getscheduler(0))
    plain = subprocess.run([sys.executable, "-c", "import os; print(os.sched_getscheduler(0))"], capture_output=True,
                           text=True, check=True)
    seen.append(int(plain.stdout))
    seen.append(len(tts.speak("hello")[0]) - 100)
later = threading.Thread(target=preparer)
later.start(); later.join()
print(os.sched_getscheduler(0), *seen)
"""
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60,
                          env=subprocess_env(), cwd=REPO_ROOT)
    assert done.returncode == 0, done.stderr
    said, policies = done.stdout.strip().splitlines()
    rr, other = str(os.SCHED_RR), str(os.SCHED_OTHER)
    if allowed(PRIORITY):
        assert said == f"real-time scheduling: SCHED_RR {PRIORITY}"
        # the process and a thread it makes afterwards run real-time, and so would a program that thread starts
        # as it is; the TTS engine it starts runs at the ordinary priority
        assert policies.split() == [rr, rr, rr, other]
    else:
        assert "not allowed here" in said and "docs/deploy.md" in said
        assert policies.split() == [other] * 4


# Without the right to it: no CAP_SYS_NICE (taken from the bounding set) and an RLIMIT_RTPRIO of 0 (as a root
# that keeps its capabilities, the test can say "not allowed" for sure only this way).
UNPRIVILEGED = ["prlimit", "--rtprio=0:0", "setpriv", "--bounding-set=-sys_nice", "--inh-caps=-sys_nice"]


@pytest.mark.parametrize("privileged", [True, False], ids=["as-the-test-runs", "without-the-right"])
def test_a_broker_process_runs_real_time_with_every_thread_or_says_why_not(privileged: bool) -> None:
    if not privileged and (os.geteuid() != 0 or not shutil.which("prlimit") or not shutil.which("setpriv")):
        pytest.skip("taking the right away needs root, prlimit and setpriv (util-linux)")
    extra = f'[realtime]\npriority = {PRIORITY}\nservices = ["broker"]\n'
    with private_bus_config(extra=extra) as config:
        argv = [sys.executable, "-m", "eca.services.processes.run", "broker", "--config", str(config.config_path),
                "--instance", config.instance]
        with running(argv if privileged else [*UNPRIVILEGED, *argv]) as (proc, out):
            line = out.lines[out.wait_for("real-time scheduling", timeout_s=30)]
            tasks = Path(f"/proc/{proc.pid}/task")
            deadline = time.monotonic() + 30
            while len(list(tasks.iterdir())) < 3 and time.monotonic() < deadline:  # zmq's threads, made later
                time.sleep(0.05)
            threads = [int(t.name) for t in tasks.iterdir()]
            assert len(threads) >= 3, "the broker never made its socket threads"
            if privileged and allowed(PRIORITY):
                expected = (os.SCHED_RR, PRIORITY)
            else:
                expected = (os.SCHED_OTHER, 0)
                assert "not allowed here" in line and "docs/deploy.md" in line
            assert [policy_of(tid) for tid in threads] == [expected] * len(threads), line
            out.wait_for("ready", timeout_s=30)  # allowed or not, it runs
            assert proc.poll() is None


def test_eca_up_refuses_a_bad_realtime_table_before_starting_anything() -> None:
    with private_bus_config(extra='[realtime]\npriority = 100\n') as config:
        done = subprocess.run(eca_command("up", "--config", str(config.config_path), "--instance", config.instance,
                                          "--quiet", "--seconds", "5"),
                              capture_output=True, text=True, timeout=60, env=subprocess_env(), cwd=REPO_ROOT)
        assert done.returncode == 2
        assert "[realtime]" in done.stderr and "'priority'" in done.stderr
        assert "[broker]" not in done.stdout + done.stderr  # nothing started
