"""`eca render` of a dialogue of several agents: one gaze engine, one face each, side by side; deterministic for a
seed; each mouth follows its own agent's lines; listeners turn toward the speaker's face on the screen."""

from __future__ import annotations

import csv
import wave
from pathlib import Path

import av
import numpy as np
import pytest

from eca.agent.face.flexors import FLEXOR_INDEX
from eca.agent.script import load_scripts
from eca.services.tools.cli import main as eca
from eca.services.tools.offline import AUDIO_RATE, RenderSettings
from eca.services.tools.offline_conversation import (
    AGENT_VOICES,
    CONVERSATION_CSV_COLUMNS,
    animate_conversation,
    voice_of,
    write_conversation_csv,
)
from eca.services.tools.playback import AGENT_VOICE, PARTNER_VOICE
from eca.services.tools.video_render import panel_widths

AGENTS = ("ada", "bob", "cy")
TURN, SAY_AH = FLEXOR_INDEX["turn"], FLEXOR_INDEX["say_ah"]


def _voiced(path: Path, seconds: float) -> None:
    """A buzz with a rising and falling loudness, as a vowel sounds to the lip-sync."""
    t = np.arange(int(AUDIO_RATE * seconds)) / AUDIO_RATE
    buzz = sum(np.sin(2 * np.pi * 120 * h * t) / h for h in range(1, 30)) * 0.3 * np.sin(np.pi * t / seconds)
    with wave.open(str(path), "wb") as fh:
        fh.setnchannels(1)
        fh.setsampwidth(2)
        fh.setframerate(AUDIO_RATE)
        fh.writeframes((buzz * 32767).astype(np.int16).tobytes())


@pytest.fixture
def script(tmp_path: Path) -> Path:
    for name in ("ada", "user", "cy"):
        _voiced(tmp_path / f"{name}.wav", 1.0)
    path = tmp_path / "three.xml"
    path.write_text(
        '<dialogue agents="ada bob cy" gap="0.5">\n'
        '  <turn speaker="ada" audio="ada.wav" emotion="happy">Hello both.</turn>\n'  # 0.0 - 1.0
        '  <turn speaker="user" audio="user.wav">Hi.</turn>\n'  # 1.5 - 2.5
        '  <turn speaker="cy" to="ada" audio="cy.wav">Hello Ada.</turn>\n'  # 3.0 - 4.0
        '  <turn speaker="bob" to="cy" duration="3">Long story.</turn>\n'  # 4.5 - 7.5
        "</dialogue>\n")
    return path


def _animate(script: Path, seed: int, fps: float = 10.0):  # type: ignore[no-untyped-def]
    run = load_scripts([script])
    return animate_conversation(run.timeline, run.agents, RenderSettings(fps=fps, seed=seed), voices=None)


def test_the_same_seed_gives_the_same_csv_and_another_changes_only_the_eyes(script: Path, tmp_path: Path) -> None:
    paths = []
    for k, seed in enumerate((4, 4, 5)):
        paths.append(tmp_path / f"{k}.csv")
        write_conversation_csv(paths[-1], _animate(script, seed))
    assert paths[0].read_bytes() == paths[1].read_bytes()
    first, other = (list(csv.DictReader(open(p))) for p in (paths[0], paths[2]))
    assert [r["role"] for r in first] == [r["role"] for r in other]
    assert [r["emotion"] for r in first] == [r["emotion"] for r in other]
    assert [r["eye_yaw_deg"] for r in first] != [r["eye_yaw_deg"] for r in other]


def test_each_mouth_follows_its_own_agents_lines(script: Path) -> None:
    result = _animate(script, seed=1)
    t = result.t_s
    ada, cy = ((t > 0.2) & (t < 0.8)), ((t > 3.2) & (t < 3.8))
    user = (t > 1.7) & (t < 2.3)
    mouths = {a: face.flexors[:, SAY_AH] for a, face in zip(result.agents, result.faces, strict=True)}
    assert mouths["ada"][ada].mean() > mouths["ada"][cy].mean() + 0.15
    assert mouths["cy"][cy].mean() > mouths["cy"][ada].mean() + 0.15
    assert np.ptp(mouths["bob"][t < 4.5]) < 0.02  # bob's mouth stays as his emotion holds it; his line is silent
    for agent in AGENTS:
        assert np.ptp(mouths[agent][user]) < 0.02, agent  # the user is heard, not mouthed
    assert np.abs(result.audio[int(1.7 * AUDIO_RATE):int(2.3 * AUDIO_RATE)]).max() > 0.05  # heard in the mix


def test_listeners_turn_toward_the_speakers_face_on_the_screen(script: Path) -> None:
    result = _animate(script, seed=2)
    t = result.t_s
    head_deg = {a: face.flexors[:, TURN] * 40.0 for a, face in zip(result.agents, result.faces, strict=True)}
    speaking = {speaker: np.array([s == speaker for s in result.speaker]) & (t > 0) for speaker in ("ada", "bob")}
    # ada sits on the left: bob and cy listen to her toward their right (the viewer's left)...
    settled = speaking["ada"] & (t > 0.7)
    assert head_deg["bob"][settled].min() > 5 and head_deg["cy"][settled].min() > 5
    # ...and bob, in the middle, speaking to cy, turns to his left; ada listening to him turns to hers.
    settled = speaking["bob"] & (t > 5.2)
    assert head_deg["bob"][settled].max() < -5 and head_deg["ada"][settled].max() < -5
    assert head_deg["cy"][settled].min() > 5
    assert {s for s in result.speaker} == {"ada", "bob", "cy", "user", ""}


def test_voices_differ_by_seat_and_the_user_keeps_the_partners() -> None:
    voices = [voice_of(a, AGENTS) for a in AGENTS]
    assert voices[0] == AGENT_VOICE and len(set(voices)) == 3 and PARTNER_VOICE not in AGENT_VOICES
    assert voice_of("user", AGENTS) == PARTNER_VOICE


def test_the_picture_is_split_among_the_faces() -> None:
    assert panel_widths(100, 3) == [34, 33, 33]
    with pytest.raises(ValueError, match="too narrow for 3 faces"):
        panel_widths(40, 3)


@pytest.mark.gl
def test_eca_render_draws_three_faces_side_by_side_and_writes_the_csvs(script: Path, tmp_path: Path,
                                                                      capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "out" / "three.mp4"
    assert eca(["render", str(script), "-o", str(out), "--size", "192x48", "--fps", "5", "--no-voice"]) == 0
    assert "agents ada, bob, cy" in capsys.readouterr().out
    rows = list(csv.reader(open(out.with_suffix(".csv"))))
    assert tuple(rows[0]) == CONVERSATION_CSV_COLUMNS
    assert [r[1] for r in rows[1:4]] == list(AGENTS) and len(rows[1:]) % 3 == 0
    with av.open(str(out)) as container:
        frames = [f.to_ndarray(format="rgb24") for f in container.decode(video=0)]
        kinds = sorted(s.type for s in container.streams)
    assert kinds == ["audio", "video"] and len(frames) == len(rows[1:]) // 3
    for agent in AGENTS:  # the rig frames: a Live Link Face CSV per agent beside the CSV, a line per frame
        rig = list(csv.reader(open(out.parent / f"three_rig_{agent}.csv")))
        assert rig[0][:3] == ["Timecode", "BlendShapeCount", "EyeBlinkLeft"] and len(rig[1:]) == len(frames)
    picture = frames[len(frames) // 2].astype(int)
    assert picture.shape == (48, 192, 3)
    background = picture[2, 2]
    for k in range(3):  # a face in the middle of each third, plain background between them
        panel = picture[:, 64 * k:64 * (k + 1)]
        assert np.abs(panel[24, 32] - background).sum() > 60, k
    for edge in (64, 128):
        assert np.abs(picture[24, edge - 1:edge + 1] - background).sum() < 30
    assert eca(["render", str(script), "-o", str(tmp_path / "n.mp4"), "--size", "40x24", "--no-voice"]) == 1
    assert "too narrow for 3 faces" in capsys.readouterr().err
    assert not (tmp_path / "n.mp4").exists()


def _pausing_voice(path: Path, stretches: int) -> None:
    """`stretches` one-second voiced stretches, each followed by 0.6 s of silence: pauses to answer."""
    t = np.arange(AUDIO_RATE) / AUDIO_RATE
    buzz = sum(np.sin(2 * np.pi * 120 * h * t) / h for h in range(1, 30)) * 0.3 * (0.6 + 0.4 * np.sin(np.pi * t))
    gap = np.zeros(int(0.6 * AUDIO_RATE))
    voice = np.concatenate([np.concatenate([buzz, gap]) for _ in range(stretches)])
    with wave.open(str(path), "wb") as fh:
        fh.setnchannels(1)
        fh.setsampwidth(2)
        fh.setframerate(AUDIO_RATE)
        fh.writeframes((voice * 32767).astype(np.int16).tobytes())


def test_listeners_nod_at_the_speakers_pauses_only_in_the_recommended_mode(tmp_path: Path) -> None:
    import dataclasses

    from eca.agent.conversation_animator import ConversationAnimator
    from eca.agent.gaze.backchannel import BackchannelParams
    from eca.services.tools.offline_conversation import gather_lines

    _pausing_voice(tmp_path / "user.wav", 6)
    _pausing_voice(tmp_path / "ada.wav", 3)
    path = tmp_path / "pauses.xml"
    path.write_text('<dialogue agents="ada bob">\n  <turn speaker="user" audio="user.wav">Well.</turn>\n'
                    '  <turn speaker="ada" audio="ada.wav">So.</turn>\n</dialogue>\n')
    run = load_scripts([path])
    params = BackchannelParams.load()
    heard, spoken, speech = gather_lines(run.timeline, run.agents, None, params.min_pause_s)
    user_stops = [t for t, who, started in speech if who == "user" and not started]
    assert len(user_stops) == 6  # the pauses are found in the audio
    nod = FLEXOR_INDEX["nod"]

    def nods(eyes: str, probability: float) -> np.ndarray:
        chosen = dataclasses.replace(params, nod_probability=probability, blink_probability=0.0)
        animator = ConversationAnimator(run.timeline, run.agents, seed=3, eyes=eyes, utterances=spoken,
                                        sample_rate=AUDIO_RATE, speech=speech, backchannel=chosen)
        return np.array([[f.flexors[nod] for f in animator.frame_at(k / 30).faces] for k in range(30 * 16)])

    always, never = nods("saccade+noise+blink", 1.0), nods("saccade+noise+blink", 0.0)
    dips = never - always  # > 0 where a nod lowers the chin
    t = np.arange(len(dips)) / 30
    for a, agent in enumerate(run.agents):
        down = t[dips[:, a] > 0.05]
        assert down.size, f"{agent} never nodded"
        # every nod starts within a second after a pause in the other speaker's speech ...
        stops = [s for s, who, started in speech if who != agent and not started]
        assert all(any(0 < x - s < 1.4 for s in stops) for x in down), agent
        # ... and never while the agent itself speaks
        own = [(s, e) for (s, who, on), (e, _, _) in zip(speech[::2], speech[1::2], strict=True) if who == agent]
        assert not any(s <= x <= e for x in down for s, e in own), agent
    # the user's six pauses are answered by both listeners; refractory times keep nods apart
    assert (dips[t < 9.6, 1] > 0.05).any() and (dips[t < 9.6, 0] > 0.05).any()
    # the paper's conditions never backchannel: the same render with and without nods is the same
    assert np.array_equal(nods("saccade+blink", 1.0), nods("saccade+blink", 0.0))
