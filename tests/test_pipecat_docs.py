"""The pipecat bot that README.md and docs/pipecat.md print runs as written.

The block after the `bot.py` marker is taken from both documents (they must carry the same code), written to
a folder of its own that also holds a `services/` and an `agent/` package of the bot's project (eca must not
be hidden by them), and run with pipecat's development runner. A real headless Chromium opens eca's page
beside it and connects: the face's video is decoded, the greeting is heard, and the bot's `set_emotion`,
called as the bot starts, before its face is connected, answers ok.
"""

from __future__ import annotations

import re
import socket
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path

import pytest

pytest.importorskip("pipecat.runner.run", reason="pipecat's runner is not installed: pip install 'eca-face[pipecat]'")

from eca.protocol.endpoints import default_runtime_root  # noqa: E402
from tests.support.browser import (  # noqa: E402
    audio_energy,
    browser_available,
    chromium,
    face_skin_share,
    poll,
    video_stats,
    wait_for,
    wait_for_frames,
)
from tests.support.bus import REPO_ROOT, running  # noqa: E402
from tests.support.web_client import user_speech_wav  # noqa: E402

MARKER = "<!-- bot.py:"
DOCUMENTS = (REPO_ROOT / "README.md", REPO_ROOT / "docs" / "pipecat.md")


def documented_bot(document: Path) -> str:
    """The first ```python block after the marker line."""
    text = document.read_text(encoding="utf-8")
    at = text.find(MARKER)
    assert at >= 0, f"{document.name} has no {MARKER} marker before its bot"
    block = re.search(r"```python\n(.*?)```", text[at:], re.DOTALL)
    assert block is not None, f"{document.name}: no python block after the marker"
    return block.group(1)


def test_the_readme_and_the_pipecat_doc_carry_the_same_bot() -> None:
    readme, doc = (documented_bot(d) for d in DOCUMENTS)
    assert readme == doc
    compile(doc, "bot.py", "exec")


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def wait_http(url: str, timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            with urllib.request.urlopen(url, timeout=2.0) as response:
                if response.status == 200:
                    return
        except (urllib.error.URLError, ConnectionError, TimeoutError):
            pass
        if time.monotonic() > deadline:
            raise TimeoutError(f"{url} did not answer within {timeout_s} s")
        time.sleep(0.2)  # a server starting in another process: nothing to wait on but its port


def project_folder(tmp_path: Path) -> Path:
    """A bot's project: bot.py beside packages named as eca's own folders once were."""
    for name in ("services", "agent", "protocol"):
        (tmp_path / name).mkdir(parents=True)
        (tmp_path / name / "__init__.py").write_text(f"raise ImportError('the bot project\\'s own {name}')\n")
    (tmp_path / "bot.py").write_text(documented_bot(DOCUMENTS[1]))
    return tmp_path


@pytest.mark.slow
@pytest.mark.gl
@pytest.mark.skipif(browser_available() is not None, reason=str(browser_available()))
def test_the_documented_bot_connects_speaks_and_sets_its_emotion(tmp_path: Path) -> None:
    folder = project_folder(tmp_path / "project")
    microphone = user_speech_wav(tmp_path / "user.wav", "Hi.", before_s=40.0, after_s=1.0)  # quiet meanwhile
    port = free_port()
    argv = [sys.executable, "bot.py", "-t", "webrtc", "--host", "127.0.0.1", "--port", str(port)]
    with running(argv, stop_timeout_s=30.0, cwd=folder) as (proc, reader):
        try:
            wait_http(f"http://127.0.0.1:{port}/eca", 60.0)
        except TimeoutError:
            raise AssertionError("the bot's page did not come up:\n" + "\n".join(reader.lines[-30:])) from None
        with chromium(microphone_wav=microphone) as driver:
            driver.get(f"http://127.0.0.1:{port}/eca")
            driver.find_element("id", "connect").click()
            wait_for(driver, "return window.eca.state", 30.0, "the page connecting", lambda s: s == "connected")
            emotion = reader.lines[reader.wait_for("set_emotion:", 60.0)]
            said = reader.lines[reader.wait_for("the face of eca agent 'ada' on instance '", 10.0)]
            instance = re.search(r"on instance '([^']+)'", said).group(1)  # type: ignore[union-attr]
            frames = wait_for_frames(driver, 30, 30.0)
            energy = poll(lambda: audio_energy(driver), lambda e: e > 0.01, 30.0) or 0.0  # the greeting
            wait_for_frames(driver, frames["framesDecoded"] + 15, 10.0)  # the face while it speaks
            screenshot = tmp_path / "pipecat_docs_bot.png"
            driver.save_screenshot(str(screenshot))
            skin = face_skin_share(driver, screenshot)
            size = (video_stats(driver).get("frameWidth"), video_stats(driver).get("frameHeight"))
    assert "{'ok': True, 'applied': 'set_emotion', 'emotion': 'happy'" in emotion, emotion
    assert frames["framesDecoded"] >= 30 and size == (640, 480)
    assert energy > 0.01, f"the greeting was not heard (audio energy {energy})"
    assert 0.1 < skin < 0.6, f"{skin:.1%} of the video's box is skin-coloured ({screenshot})"
    assert not any("PortAudio" in line for line in reader.lines), "a sound-card warning in the bot's log"
    # The bot's eca goes with the bot (stopped by the pipeline, or by its guard once the bot has gone).
    assert poll(lambda: float((default_runtime_root() / instance).exists()), lambda left: not left, 20.0) == 0.0, \
        "the bot's eca left its runtime directory behind"
