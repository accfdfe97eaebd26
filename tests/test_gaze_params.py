"""Gaze configs: the shipped values, and clear errors naming the file and key for bad ones."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from eca.agent.config import SHIPPED_DIR, ConfigError
from eca.agent.counter_rng import uniform01
from eca.agent.gaze.engine import GazeEngine
from eca.agent.gaze.generator import SACCADE_STREAM, derive_seed
from eca.agent.gaze.params import GazeParams
from eca.agent.gaze.rows import COUNTER_SACCADE, KEY_SACCADE, row_uniforms

EMOTIONS = ("natural", "happy", "surprised", "arrogant", "angry", "half-angry", "disappointed", "annoyed", "frightened")


def _write_variant(tmp_path: Path, edit: str, old: str, new: str) -> Path:
    source = (SHIPPED_DIR / f"{edit}.toml").read_text()
    assert old in source
    path = tmp_path / f"{edit}.toml"
    path.write_text(source.replace(old, new, 1))
    return path


def test_shipped_constants() -> None:
    params = GazeParams.load()
    assert (params.p_max, params.p_ref, params.a_scale_deg) == (15.0, 15.7, 6.9)
    assert (params.d0_s, params.d_s_per_deg) == (0.025, 0.0024)
    assert params.roles["talking"].mutual_probability == 0.41
    assert params.roles["listening"].mutual_probability == 0.75
    assert params.default_mode == "saccade+noise+blink"
    assert tuple(params.emotions) == EMOTIONS
    assert params.emotion("natural", 1.0) == params.emotion("angry", 0.0)


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        (
            "mutual_probability = 0.41",
            "mutual_probability = 1.41",
            r"\[talking\]: 'mutual_probability' must be in \[0, 1\]",
        ),
        ("d0_s = 0.025", 'd0_s = "fast"', r"\[duration\]: 'd0_s' must be float"),
        ('like = "listening"', 'like = "shouting"', r"\[silence\]: 'like' must be one of talking, listening"),
        ('default = "saccade+noise+blink"', 'default = "blinky"', r"\[modes\]: 'default' must be one of"),
        (
            "mutual_poly = [32.2815,",
            "mutual_poly = [-32.2815,",
            r"\[talking\]: mutual interval: the polynomial is not positive",
        ),
        ("percent = [15.54,", "percent = [15.54, 1.0,", r"\[direction\]: 'percent' must hold 8 numbers"),
    ],
)
def test_bad_gaze_config_names_file_and_key(tmp_path: Path, old: str, new: str, message: str) -> None:
    path = _write_variant(tmp_path, "gaze", old, new)
    with pytest.raises(ConfigError, match=message) as caught:
        GazeParams.load(gaze=str(path))
    assert str(path) in str(caught.value)


def test_bad_emotion_table(tmp_path: Path) -> None:
    path = _write_variant(tmp_path, "gaze_emotions", 'same_as = "angry"', 'same_as = "furious"')
    with pytest.raises(ConfigError, match=r"\[half-angry\]: 'same_as' names 'furious'"):
        GazeParams.load(emotions=str(path))
    path = _write_variant(tmp_path, "gaze_emotions", "[happy]\ninterval_scale = 0.9", "[happy]\ninterval_scale = -1")
    with pytest.raises(ConfigError, match=r"\[happy\]: 'interval_scale' must be > 0"):
        GazeParams.load(emotions=str(path))


def test_missing_config_file_is_named(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="not found"):
        GazeParams.load(gaze=str(tmp_path / "absent.toml"))


def test_engine_draws_are_the_counter_rng_streams() -> None:
    engine = GazeEngine(5, seed=99, role="talking")
    agents = np.array([1, 3, 4])
    rows = engine._rows[agents]
    before = rows[:, COUNTER_SACCADE].view(np.uint64).copy()
    drawn = row_uniforms(rows, KEY_SACCADE, COUNTER_SACCADE, 3)
    expected = uniform01(
        derive_seed(99, SACCADE_STREAM),
        agents[:, None].astype(np.uint64),
        before[:, None] + np.arange(3, dtype=np.uint64),
    )
    np.testing.assert_array_equal(drawn, expected.T)  # one row per draw
    assert np.all(rows[:, COUNTER_SACCADE].view(np.uint64) == before + 3)
