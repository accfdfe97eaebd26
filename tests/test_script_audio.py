"""A script's audio files: each way one can be wrong gives its own message, naming the file."""

from __future__ import annotations

import pickle
import shutil
from pathlib import Path

import numpy as np
import pytest
import soundfile

from eca.agent.script import AudioFileError, ScriptError, load_dialogue, wav_duration
from eca.services.tools.cli import main as eca
from eca.services.tools.script_input import sound_duration

DATA = Path(__file__).parent / "data" / "scripts"


@pytest.fixture
def sounds(tmp_path: Path) -> Path:
    """A folder with a good WAV, a FLAC, a folder named like a WAV, an empty WAV and a text 'WAV'."""
    shutil.copy(DATA / "clip.wav", tmp_path / "good.wav")
    soundfile.write(str(tmp_path / "good.flac"), np.zeros(11_025, dtype=np.float32), 22_050)
    (tmp_path / "folder.wav").mkdir()
    (tmp_path / "empty.wav").write_bytes(b"")
    (tmp_path / "text.wav").write_text("not a sound\n")
    return tmp_path


def turns_dialogue(folder: Path, audio: list[str], duration: str = "") -> Path:
    turns = "".join(f'  <turn speaker="ada" audio="{name}"{duration}>Line.</turn>\n' for name in audio)
    path = folder / "d.xml"
    path.write_text(f'<dialogue agent="ada">\n{turns}</dialogue>\n')
    return path


def test_check_names_each_bad_audio_file_and_its_cause(sounds: Path, capsys: pytest.CaptureFixture[str]) -> None:
    script = turns_dialogue(sounds, ["folder.wav", "empty.wav", "text.wav", "missing.wav", "good.wav", "good.flac"])
    assert eca(["check", str(script)]) == 1
    lines = capsys.readouterr().err.splitlines()
    assert lines == [
        f"{script}:2:3: <turn>: audio 'folder.wav' is a directory, not a sound file",
        f"{script}:3:3: <turn>: audio 'empty.wav' is empty (0 bytes)",
        f"{script}:4:3: <turn>: audio 'text.wav' is not a sound file soundfile can read: Format not recognised",
        f"{script}:5:3: <turn>: audio 'missing.wav' not found (looked for {sounds / 'missing.wav'})",
    ]


def test_a_given_duration_does_not_excuse_a_file_that_cannot_play(sounds: Path,
                                                                   capsys: pytest.CaptureFixture[str]) -> None:
    script = turns_dialogue(sounds, ["empty.wav", "good.flac"], duration=' duration="1"')
    assert eca(["check", str(script)]) == 1
    assert capsys.readouterr().err.splitlines() == [f"{script}:2:3: <turn>: audio 'empty.wav' is empty (0 bytes)"]


def test_render_refuses_an_empty_wav_before_rendering_anything(sounds: Path,
                                                               capsys: pytest.CaptureFixture[str]) -> None:
    script = turns_dialogue(sounds, ["empty.wav"])
    out = sounds / "x.mp4"
    assert eca(["render", str(script), "-o", str(out), "--no-voice"]) == 1
    err = capsys.readouterr().err
    assert f"{script}:2:3: <turn>: audio 'empty.wav' is empty (0 bytes)" in err and "nothing rendered" in err
    assert not out.exists()


def test_the_services_measure_reads_what_soundfile_reads(sounds: Path) -> None:
    assert sound_duration(sounds / "good.wav") == pytest.approx(wav_duration(sounds / "good.wav"))
    assert sound_duration(sounds / "good.flac") == pytest.approx(0.5)
    dialogue = load_dialogue(turns_dialogue(sounds, ["good.flac"]), duration_of=sound_duration)
    assert dialogue.timeline.length_s == pytest.approx(0.5)


@pytest.mark.parametrize(("name", "problem"), [
    ("empty.wav", "is empty (0 bytes)"),
    ("folder.wav", "is a directory, not a sound file"),
    ("missing.wav", "not found"),
    ("text.wav", "is not a WAV file Python's wave module can read: "),
    ("good.flac", "is .flac audio, which only the audio services can measure"),
])
def test_the_stdlib_measure_says_what_is_wrong_and_names_the_file(sounds: Path, name: str, problem: str) -> None:
    with pytest.raises(AudioFileError) as info:
        wav_duration(sounds / name)
    assert info.value.problem.startswith(problem)
    assert str(info.value).startswith(f"audio file '{sounds / name}' {problem}")
    assert info.value.problem.split(":")[-1].strip()  # a cause after the colon, never an empty one
    again = pickle.loads(pickle.dumps(info.value))
    assert (type(again), str(again)) == (type(info.value), str(info.value))


def test_without_the_services_hook_a_given_duration_covers_formats_wav_only_readers_cannot_measure(
    sounds: Path,
) -> None:
    timed = load_dialogue(turns_dialogue(sounds, ["good.flac"], duration=' duration="2"'))
    assert timed.timeline.length_s == 2.0
    with pytest.raises(ScriptError, match="is .flac audio, which only the audio services can measure; use WAV "
                                          "or give the turn a duration"):
        load_dialogue(turns_dialogue(sounds, ["good.flac"]))


def test_a_hook_that_fails_without_words_still_gets_a_message(sounds: Path) -> None:
    def silent_failure(path: Path) -> float:
        raise EOFError()

    with pytest.raises(ScriptError) as info:
        load_dialogue(turns_dialogue(sounds, ["good.wav"]), duration_of=silent_failure)
    assert info.value.message == "<turn>: audio 'good.wav' cannot be measured: EOFError"
