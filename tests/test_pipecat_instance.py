"""An eca the face starts for its pipeline (`start_eca`: `eca up` in the background, services/pipecat/
instance.py): it serves the pipeline, stops with it, and leaves nothing behind, not even when the process
that started it is killed.
"""

from __future__ import annotations

import asyncio
import os
import secrets
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("pipecat.frames.frames", reason="pipecat is not installed: pip install 'eca[pipecat]'")

from pipecat.frames.frames import TTSAudioRawFrame, TTSStartedFrame, TTSStoppedFrame  # noqa: E402
from pipecat.tests.utils import SleepFrame, run_test  # noqa: E402

from eca.protocol.endpoints import default_runtime_root  # noqa: E402
from eca.services.pipecat import EcaFaceParams, EcaVideoService  # noqa: E402
from eca.services.tools.child_processes import LineReader, subprocess_env  # noqa: E402
from tests.support.bus import REPO_ROOT  # noqa: E402

pytestmark = [pytest.mark.slow, pytest.mark.filterwarnings("ignore::DeprecationWarning")]  # pipecat's own
RATE = 16_000


def processes_of(instance: str) -> list[int]:
    """Every process whose command line names the instance (eca up, its services, the guard)."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            cmdline = (entry / "cmdline").read_bytes()
        except OSError:
            continue  # gone meanwhile, or not ours to read
        if instance.encode() in cmdline.split(b"\0"):
            found.append(int(entry.name))
    return found


def wait_until(predicate: object, timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():  # type: ignore[operator]
            return True
        time.sleep(0.1)  # polling other processes: there is no event to wait on
    return bool(predicate())  # type: ignore[operator]


def test_an_eca_started_for_the_pipeline_serves_it_and_stops_with_it() -> None:
    name = f"pc-{secrets.token_hex(4)}"
    face = EcaVideoService(EcaFaceParams(instance=name, start_eca=True, video=False))
    tone = (0.3 * np.sin(2 * np.pi * 200 * np.arange(RATE // 2) / RATE) * 32767).astype("<i2").tobytes()
    during: dict[str, object] = {}

    frames = [TTSStartedFrame(), TTSAudioRawFrame(tone, RATE, 1), TTSStoppedFrame(), SleepFrame(sleep=1.2)]

    async def run() -> None:
        pipeline = asyncio.create_task(run_test(face, frames_to_send=frames, start_timeout=60.0))
        # While the pipeline runs, the instance is up with its services (a face that never connects ends
        # the pipeline without one, and the look with it).
        while face.face_link is None and not pipeline.done():
            await asyncio.sleep(0.05)  # polling the face's start from the side
        if face.face_link is not None:
            during["processes"] = processes_of(name)
            during["directory"] = (default_runtime_root() / name).is_dir()
        await pipeline

    asyncio.run(run())
    assert during, "the face never connected to the eca it started"
    assert during["directory"] is True
    assert len(during["processes"]) >= 5  # type: ignore[arg-type]  # the guard, eca up, broker, dialogue, ...
    assert face.eca_offsets_s, "eca never started the say: it was not serving the pipeline"
    assert wait_until(lambda: not processes_of(name), 5.0), processes_of(name)
    assert not (default_runtime_root() / name).exists()


def test_an_eca_left_by_a_killed_process_stops_by_itself() -> None:
    name = f"pc-{secrets.token_hex(4)}"
    starter = ("import sys, time\n"
               "from eca.services.pipecat.instance import EcaInstance\n"
               f"EcaInstance.start({name!r})\n"
               "print('eca is up', flush=True)\n"
               "time.sleep(120)\n")
    proc = subprocess.Popen([sys.executable, "-c", starter], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            env=subprocess_env(), cwd=REPO_ROOT, start_new_session=True)
    reader = LineReader(proc.stdout)
    try:
        reader.wait_for("eca is up", 60.0)
        assert len(processes_of(name)) >= 5
        os.kill(proc.pid, signal.SIGKILL)  # no cleanup of its own: the guard must do it
        proc.wait(timeout=5.0)
        assert wait_until(lambda: not processes_of(name), 20.0), processes_of(name)
        assert wait_until(lambda: not (default_runtime_root() / name).exists(), 5.0)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=5.0)
        for pid in processes_of(name):  # a failed test leaves nothing running either
            os.kill(pid, signal.SIGKILL)
