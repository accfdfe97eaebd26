"""configs/face.toml and configs/flexor_units.toml: loading, and errors naming file and key."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from eca.agent.config import ConfigError
from eca.agent.face.flexors import FLEXOR_INDEX, FLEXOR_NAMES
from eca.agent.face.settings import load_face_settings, load_flexor_units


def _face_text(settle: dict[str, str] | None = None, idle: str = "rate_hz = 0.4\nnod = 0.04") -> str:
    values = {name: "0.3" for name in FLEXOR_NAMES}
    values.update(settle or {})
    body = "\n".join(f"{name} = {value}" for name, value in values.items() if value is not None)
    return f"[settle_s]\n{body}\n\n[idle_noise]\n{idle}\n"


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "face_case.toml"
    path.write_text(text)
    return path


def test_the_shipped_face_settings_load() -> None:
    settings = load_face_settings()
    assert np.all(settings.settle_s > 0)
    assert settings.idle_rate_hz > 0
    assert settings.idle_amplitude[FLEXOR_INDEX["look_x"]] == 0.0  # the eyes have their own models
    assert 0 < settings.idle_amplitude[FLEXOR_INDEX["nod"]] <= 0.1


def test_the_shipped_flexor_units_load() -> None:
    units = load_flexor_units()
    assert units.look_x_deg == 30.0 and units.turn_deg == 40.0


def test_a_settings_file_is_read_as_written(tmp_path: Path) -> None:
    settings = load_face_settings(_write(tmp_path, _face_text({"smile_l": "1.25"})))
    assert settings.settle_s[FLEXOR_INDEX["smile_l"]] == 1.25
    assert settings.idle_amplitude[FLEXOR_INDEX["nod"]] == 0.04


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (_face_text({"smile_l": None}), r"\[settle_s\]: missing key 'smile_l'"),
        (_face_text({"smile_l": "-0.5"}), r"\[settle_s\]: 'smile_l' must be a finite number >= 0"),
        (_face_text({"smile_l": '"slow"'}), r"\[settle_s\]: 'smile_l' must be float"),
        (_face_text({"grin": "0.5"}), r"\[settle_s\]: unknown flexor 'grin'"),
        (_face_text(idle="rate_hz = 0.4\nwiggle = 0.1"), r"\[idle_noise\]: unknown flexor 'wiggle'"),
        (_face_text(idle="nod = 0.1"), r"\[idle_noise\]: missing key 'rate_hz'"),
        (_face_text(idle="rate_hz = 1\nnod = 1.5"), r"\[idle_noise\]: 'nod' = 1.5 exceeds"),
        ("[idle_noise]\nrate_hz = 1\n", r"missing table \[settle_s\]"),
        ("settle_s = 3\n[idle_noise]\nrate_hz = 1\n", r"\[settle_s\] must be a table"),
    ],
)
def test_bad_face_settings_name_file_and_key(tmp_path: Path, text: str, message: str) -> None:
    path = _write(tmp_path, text)
    with pytest.raises(ConfigError, match=message) as caught:
        load_face_settings(path)
    assert str(path) in str(caught.value)


def test_bad_flexor_units_name_file_and_key(tmp_path: Path) -> None:
    path = tmp_path / "units.toml"
    path.write_text("[eyes]\nlook_x_deg = 30.0\nlook_y_deg = 0.0\n[head]\nturn_deg = 1\nnod_deg = 1\ntilt_deg = 1\n")
    with pytest.raises(ConfigError,
                       match=r"units.toml: \[eyes\] 'look_y_deg' must be a number of degrees in \(0, 90\]"):
        load_flexor_units(path)
    path.write_text("[eyes]\nlook_x_deg = 30.0\nlook_y_deg = 30.0\n")
    with pytest.raises(ConfigError, match=r"missing table \[head\]"):
        load_flexor_units(path)
