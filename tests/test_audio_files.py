"""Audio-file errors: each problem gets its own plain sentence naming the file, from the opener, the
slice reader, the offline loader and (as a speech_failed reason) the player."""

from __future__ import annotations

import errno
import os
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf

from eca.agent.clock import VirtualClock
from eca.agent.script import audiofile
from eca.services.processes.audio import FakeSink, Player, PlayerFailed
from eca.services.processes.audio.files import AudioFileError, MonoReader, open_sound_file, read_sound_file
from eca.services.tools.offline import AUDIO_RATE, load_audio

SR = 16_000


def noise_wav(path: Path, seconds: float, sr: int = SR, subtype: str = "PCM_16", seed: int = 0) -> Path:
    x = np.random.default_rng(seed).uniform(-0.3, 0.3, round(seconds * sr)).astype(np.float32)
    sf.write(path, x, sr, subtype=subtype)
    return path


def problem_of(path: Path, **kwargs: float) -> str:
    with pytest.raises(AudioFileError) as info:
        open_sound_file(path, **kwargs).close()
    message = str(info.value)
    assert str(path) in message and info.value.path == str(path)  # names the file
    assert "\n" not in message and "Error" not in message and "Errno" not in message  # one plain line
    return message


@pytest.fixture
def bad_files(tmp_path: Path) -> dict[str, Path]:
    directory = tmp_path / "voice.wav"
    directory.mkdir()
    empty = tmp_path / "empty.wav"
    empty.touch()
    text = tmp_path / "notes.wav"
    text.write_text("these are notes, not sound\n")
    header_only = tmp_path / "header-only.wav"
    sf.write(header_only, np.zeros(0, np.float32), SR)
    return {"missing": tmp_path / "nope.wav", "directory": directory, "empty": empty, "text": text,
            "header_only": header_only, "long": noise_wav(tmp_path / "long.wav", 3.0)}


def test_each_problem_has_its_own_message(bad_files: dict[str, Path], monkeypatch: pytest.MonkeyPatch) -> None:
    messages = {
        "missing": problem_of(bad_files["missing"]),
        "directory": problem_of(bad_files["directory"]),
        "empty": problem_of(bad_files["empty"]),
        "text": problem_of(bad_files["text"]),
        "header_only": problem_of(bad_files["header_only"]),
        "long": problem_of(bad_files["long"], max_seconds=2.5),
    }
    assert messages["missing"].endswith("not found")
    assert messages["directory"].endswith("is a directory, not a sound file")
    assert messages["empty"].endswith("is empty (0 bytes)")
    # soundfile's own cause, without its "Error opening '<path>':" preamble or a class name
    assert messages["text"].endswith("is not a sound file soundfile can read: Format not recognised")
    assert "LibsndfileError" not in messages["text"]
    assert messages["header_only"].endswith("holds no samples (its header announces none)")
    assert messages["long"].endswith("lasts 3.0 s, longer than the limit of 2.5 s")
    assert len(set(messages.values())) == len(messages)
    assert all(m.startswith("audio file '") for m in messages.values())


def test_a_file_that_may_not_be_read(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    locked = noise_wav(tmp_path / "locked.wav", 0.1)
    locked.chmod(0)
    if os.access(locked, os.R_OK):  # root reads anything: make the OS refuse as it would anyone else
        real_open = os.open

        def refuse(path: str, flags: int, *args: int) -> int:
            if path == str(locked):
                raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), path)
            return real_open(path, flags, *args)

        monkeypatch.setattr(audiofile.os, "open", refuse)
    assert problem_of(locked).endswith("cannot be read: permission denied")


def test_a_path_through_a_file_does_not_exist(tmp_path: Path) -> None:
    plain = noise_wav(tmp_path / "plain.wav", 0.1)
    assert "not found (a directory in its path is a file)" in problem_of(plain / "inner.wav")


def test_a_named_pipe_is_refused_without_blocking(tmp_path: Path) -> None:
    fifo = tmp_path / "pipe.wav"
    os.mkfifo(fifo)
    assert problem_of(fifo).endswith("is not a regular file")


def test_a_long_path_is_shortened_from_the_front(tmp_path: Path) -> None:
    deep = tmp_path / ("d" * 150) / ("e" * 150)
    deep.mkdir(parents=True)
    with pytest.raises(AudioFileError) as info:
        open_sound_file(deep / "speech.wav")
    message = str(info.value)
    assert "speech.wav' not found" in message and len(message) < 260


def test_a_good_file_opens_and_reads_whole(tmp_path: Path) -> None:
    path = noise_wav(tmp_path / "ok.flac", 1.0, subtype="PCM_16")
    with open_sound_file(path, max_seconds=1.0) as fh:
        assert fh.frames == SR and fh.samplerate == SR
    mono, rate = read_sound_file(path, slice_frames=1000)
    assert rate == SR and np.array_equal(mono, sf.read(path, dtype="float32")[0])


def test_a_file_cut_short_after_opening_fails_where_it_ends(tmp_path: Path) -> None:
    path = noise_wav(tmp_path / "cut.wav", 3.0)
    reader = MonoReader(open_sound_file(path), path)
    assert len(reader.read(SR)) == SR
    os.truncate(path, 44 + 2 * SR * 2)
    assert len(reader.read(SR)) == SR
    with pytest.raises(AudioFileError) as info:
        reader.read(SR)
    reader.close()
    assert str(info.value) == f"audio file '{path}' ended after 2.0 s of the 3.0 s its header announces " \
                              "(it was cut short or changed while it played)"


def test_a_file_that_cannot_be_decoded_mid_way(tmp_path: Path) -> None:
    path = noise_wav(tmp_path / "damaged.flac", 4.0)
    raw = bytearray(path.read_bytes())
    middle = len(raw) // 2
    raw[middle : middle + 4000] = bytes(4000)  # a run of zeros where FLAC frames were
    path.write_bytes(bytes(raw))
    with pytest.raises(AudioFileError) as info:
        read_sound_file(path, slice_frames=SR // 4)
    message = str(info.value)
    assert message.startswith(f"audio file '{path}' could not be decoded after ")
    assert "LibsndfileError" not in message and "Error :" not in message


def test_offline_loading_reports_the_same_problems(bad_files: dict[str, Path], tmp_path: Path) -> None:
    with pytest.raises(AudioFileError, match="is empty"):
        load_audio(bad_files["empty"])
    with pytest.raises(AudioFileError, match="is a directory"):
        load_audio(bad_files["directory"])
    speech = noise_wav(tmp_path / "speech.wav", 0.5)
    assert len(load_audio(speech)) == pytest.approx(0.5 * AUDIO_RATE, abs=2)


def test_the_player_fails_each_bad_file_with_its_message(bad_files: dict[str, Path]) -> None:
    clock = VirtualClock(1_000_000_000)
    sink = FakeSink(clock, 48_000, 480)
    events: list[object] = []
    with Player(sink, events.append, clock=clock) as player:
        for name, path in bad_files.items():
            if name != "long":
                player.say_file(name, path)
        for _ in range(20):
            sink.advance(1)
        assert player.idle
    failed = {e.request_id: e.reason for e in events if isinstance(e, PlayerFailed)}
    assert set(failed) == set(bad_files) - {"long"}
    for name, reason in failed.items():
        assert reason == problem_of(bad_files[name])  # the opener's sentence, as it is
        assert len(reason) <= 500
