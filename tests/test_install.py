"""eca installs as a library: the sdist and the wheel are built from the source tree, the wheel is installed
(not editable) into a fresh virtual environment outside the repository, and from a bot project's folder that
has its own `services/`, `agent/` and `protocol/` packages the installed eca runs: `eca --help`, `eca snapshot`
(its first drawing compiles the renderer's code, and says so), `eca up` with a command and a say, and a
pipecat pipeline with the face, whose tool is called before the pipeline starts. The wheel holds `eca/` and
its data only; `import services` fails in that environment.

The environment's packages come from pip's cache when the machine has installed them before (setup did), so
this costs about two minutes of one worker.
"""

from __future__ import annotations

import os
import secrets
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from tests.support.bus import REPO_ROOT, LineReader

# Installing into a fresh environment takes one to three minutes on a loaded 2-core machine: each step has
# its own subprocess timeout, the test as a whole this one.
pytestmark = [pytest.mark.slow, pytest.mark.timeout(1200)]

PIPELINE = '''
import asyncio
import sys

import numpy as np
from pipecat.frames.frames import OutputImageRawFrame, TTSAudioRawFrame, TTSStartedFrame, TTSStoppedFrame
from pipecat.tests.utils import SleepFrame, run_test

from eca.pipecat import EcaFaceParams, EcaTools, EcaVideoService


async def main() -> None:
    face = EcaVideoService(EcaFaceParams(start_eca=True, instance=sys.argv[1], width=160, height=120, fps=15))
    tools = EcaTools(face)
    early = asyncio.create_task(tools.set_emotion("surprised", 0.7))  # before the pipeline starts
    rate = 24_000
    tone = (8000 * np.sin(2 * np.pi * 220 * np.arange(rate) / rate)).astype("<i2").tobytes()
    frames = [TTSStartedFrame(), TTSAudioRawFrame(tone, rate, 1), TTSStoppedFrame(), SleepFrame(sleep=1.5)]
    down, _ = await run_test(face, frames_to_send=frames, start_timeout=90.0)
    pictures = [f for f in down if isinstance(f, OutputImageRawFrame)]
    print("tool:", await early)
    print("pictures:", len(pictures), pictures[0].size if pictures else None)
    print("audio out:", sum(isinstance(f, TTSAudioRawFrame) for f in down))


asyncio.run(main())
'''


def run(argv: list[str], cwd: Path, env: dict[str, str], timeout_s: float = 300.0) -> subprocess.CompletedProcess[str]:
    done = subprocess.run(argv, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout_s)
    assert done.returncode == 0, f"{' '.join(argv)} exited {done.returncode}:\n{done.stdout}\n{done.stderr}"
    return done


def source_copy(destination: Path) -> Path:
    """The project's files as a clone has them (tracked, and new ones not ignored), without build leftovers."""
    listed = subprocess.run(["git", "ls-files", "--cached", "--others", "--exclude-standard", "-z"], cwd=REPO_ROOT,
                            capture_output=True, check=True).stdout.decode().split("\0")
    for name in filter(None, listed):
        source = REPO_ROOT / name
        if source.is_file():
            (destination / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(source, destination / name)
    return destination


def clean_env() -> dict[str, str]:
    """The environment without this interpreter's virtual environment or paths: the fresh venv's own."""
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV", "PYTHONHOME")}
    env["PATH"] = os.pathsep.join(p for p in env.get("PATH", "").split(os.pathsep)
                                  if not p.startswith(str(REPO_ROOT)))
    env["PYTHONUNBUFFERED"] = "1"
    return env


@pytest.fixture(scope="module")
def built(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """The sdist and the wheel, built from a copy of the source tree as `python -m build` builds them."""
    root = tmp_path_factory.mktemp("build")
    source = source_copy(root / "source")
    dist = root / "dist"
    run([sys.executable, "-m", "build", "--outdir", str(dist), str(source)], root, dict(os.environ), 600.0)
    (sdist,) = dist.glob("eca_face-*.tar.gz")
    (wheel,) = dist.glob("eca_face-*-py3-none-any.whl")
    return sdist, wheel


def test_the_wheel_holds_the_eca_package_and_its_data_only(built: tuple[Path, Path]) -> None:
    _, wheel = built
    names = zipfile.ZipFile(wheel).namelist()
    tops = {n.split("/")[0] for n in names}
    assert {t for t in tops if not t.endswith(".dist-info")} == {"eca"}, sorted(tops)
    assert "eca/configs/emotions.toml" in names and "eca/configs/demo/dialogue.xml" in names
    assert "eca/services/processes/web/static/index.html" in names
    assert "eca/services/pipecat/static/client.html" in names and "eca/py.typed" in names
    assert "eca/assets/default_head.glb" in names and "eca/assets/default_head.NOTICE.md" in names
    assert not [n for n in names if n.startswith(("tests/", "bench/", ".ci/", "examples/", "docs/"))]
    metadata = next(n for n in names if n.endswith(".dist-info/METADATA"))
    text = zipfile.ZipFile(wheel).read(metadata).decode()
    assert "Name: eca-face" in text and "Provides-Extra: pipecat" in text


def test_the_installed_wheel_runs_beside_a_project_of_its_own(built: tuple[Path, Path], tmp_path: Path) -> None:
    _, wheel = built
    env = clean_env()
    venv = tmp_path / "venv"
    run([sys.executable, "-m", "venv", str(venv)], tmp_path, env)
    python, eca = venv / "bin" / "python", venv / "bin" / "eca"
    run([str(python), "-m", "pip", "install", "-q", f"{wheel}[pipecat]"], tmp_path, env, 900.0)

    # Nothing but `eca` at the top: the names a bot project uses stay its own.
    neutral = tmp_path / "neutral"
    neutral.mkdir()
    for name in ("services", "agent", "protocol"):
        failed = subprocess.run([str(python), "-c", f"import {name}"], cwd=neutral, env=env, capture_output=True,
                                text=True, timeout=60)
        assert failed.returncode != 0 and "ModuleNotFoundError" in failed.stderr, (name, failed.stderr)
    located = run([str(python), "-c", "import eca, eca.pipecat; print(eca.__file__, eca.__version__)"], neutral, env)
    assert str(venv) in located.stdout and str(REPO_ROOT) not in located.stdout

    project = tmp_path / "project"
    for name in ("services", "agent", "protocol"):
        (project / name).mkdir(parents=True)
        (project / name / "__init__.py").write_text(f"raise ImportError('the project\\'s own {name}')\n")

    assert "A live conversational-agent face" in run([str(eca), "--help"], project, env).stdout

    shot = run([str(eca), "snapshot", "--emotion", "happy", "-o", "face.png", "--size", "320x240"], project, env)
    assert "compiling the face's drawing code" in shot.stderr, shot.stderr  # a new install compiles, and says so
    picture = np.asarray(Image.open(project / "face.png").convert("RGB")).astype(int)
    skin = ((picture[..., 0] > 150) & (picture[..., 0] - picture[..., 2] > 50)).mean()
    assert picture.shape == (240, 320, 3) and 0.1 < skin < 0.7, skin

    instance = f"inst-{secrets.token_hex(4)}"
    up = subprocess.Popen([str(eca), "up", "--headless", "--quiet", "--silent-audio", "--instance", instance],
                          cwd=project, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                          start_new_session=True)
    try:
        reader = LineReader(up.stdout)
        try:
            reader.wait_for("[up] ready in", 120.0)
        except TimeoutError:
            raise AssertionError("eca up was not ready:\n" + "\n".join(reader.lines)) from None
        send = [str(eca), "send", "--instance", instance]
        state = run([*send, "emotion", "happy", "--intensity", "0.8"], project, env, 60.0)
        assert "happy" in state.stdout, state.stdout
        said = run([*send, "say", "--text", "Hello from the wheel.", "--wait"], project, env, 60.0)
        assert "speech_finished" in said.stdout or "finished" in said.stdout, said.stdout
    finally:
        os.killpg(up.pid, 2)
        try:
            up.wait(timeout=30)
        except subprocess.TimeoutExpired:
            os.killpg(up.pid, 9)
            up.wait(timeout=10)
    assert up.returncode == 0, up.returncode

    (project / "pipeline.py").write_text(PIPELINE)
    piped = run([str(python), "pipeline.py", f"pipe-{secrets.token_hex(4)}"], project, env, 180.0)
    lines = {line.split(":", 1)[0]: line.split(":", 1)[1].strip() for line in piped.stdout.splitlines() if ":" in line}
    assert lines["tool"].startswith("{'ok': True, 'applied': 'set_emotion'"), piped.stdout
    count, size = lines["pictures"].split(" ", 1)
    assert int(count) >= 15 and size == "(160, 120)", piped.stdout
    assert lines["audio out"] == "1", piped.stdout
    assert "PortAudio" not in piped.stdout + piped.stderr, "a sound-card warning where the voice goes to the pipeline"
