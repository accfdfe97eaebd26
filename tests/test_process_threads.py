"""A service process keeps numpy's matrix products on its own threads: OpenBLAS' pool of workers, which spin
between the products a service makes every frame slot, is not started (runtime.one_maths_thread, as run.py calls
it before the service's module loads numpy)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from eca.services.tools.child_processes import subprocess_env

# Threads of a fresh interpreter before numpy loads and after products large enough for OpenBLAS to share out
# (a 600 x 600 product; the web service's posing of its faces crosses the threshold from 22 agents on).
PROBE = """
import os
{prepare}
before = len(os.listdir("/proc/self/task"))
import numpy as np
a = np.ones((600, 600))
for _ in range(3):
    a @ a
print("THREADS", before, len(os.listdir("/proc/self/task")))
"""


def threads(prepare: str) -> tuple[int, int]:
    env = subprocess_env()
    for name in ("OPENBLAS_NUM_THREADS", "GOTO_NUM_THREADS", "OMP_NUM_THREADS"):  # what OpenBLAS reads, in its order
        env.pop(name, None)
    done = subprocess.run([sys.executable, "-c", PROBE.format(prepare=prepare)], capture_output=True, text=True,
                          env=env, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    line = next(line for line in done.stdout.splitlines() if line.startswith("THREADS"))
    before, after = map(int, line.split()[1:])
    return before, after


@pytest.mark.skipif(not os.path.isdir("/proc/self/task") or (os.cpu_count() or 1) < 2,
                    reason="counts threads in /proc; OpenBLAS shares out only with more than one core")
def test_a_service_process_starts_no_blas_workers() -> None:
    # unprepared, numpy's OpenBLAS starts workers (what the preparation is for: a check that the probe can fail)
    before, after = threads("")
    assert after > before, "numpy started no BLAS workers unprepared: the probe cannot tell"
    before, after = threads("from eca.services.processes.runtime import one_maths_thread; one_maths_thread()")
    assert after == before


def test_an_operators_own_setting_wins(monkeypatch: pytest.MonkeyPatch) -> None:
    from eca.services.processes.runtime import one_maths_thread

    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "4")
    one_maths_thread()
    assert os.environ["OPENBLAS_NUM_THREADS"] == "4"
    monkeypatch.delenv("OPENBLAS_NUM_THREADS")
    one_maths_thread()
    assert os.environ["OPENBLAS_NUM_THREADS"] == "1"
