"""`eca rig-sheet`: the mapping tables of docs/rig.md are exactly what configs/rig.toml gives (so the document
cannot drift from the config), the heat map shows the golden weights of the nine emotions, and the command's
files and refusals."""

from __future__ import annotations

import json
from pathlib import Path

import matplotlib
import numpy as np
import pytest

from eca.agent.face.emotions import PAPER_EMOTIONS, load_emotion_table
from eca.agent.rig import ARKIT_NAMES, VRM_NAMES, Retargeter, load_rig_config
from eca.agent.rig.lookat import EYE_LOOK_NAMES
from eca.agent.rig.names import VRM_EMOTIONS
from eca.services.tools.cli import main as eca
from eca.services.tools.commands.rig_sheet import (
    BEGIN,
    END,
    PICTURE,
    SHIPPED_RIG,
    config_notes,
    emotion_figure,
    emotion_weights,
    generated_block,
    mapping_tables,
    replace_tables,
    term_text,
)

matplotlib.use("Agg")
DOC = Path(__file__).resolve().parent.parent / "docs" / "rig.md"
GOLDEN = Path(__file__).parent / "golden" / "rig_emotions.json"
CONFIG = load_rig_config(SHIPPED_RIG)
TEXT = SHIPPED_RIG.read_text(encoding="utf-8")


def test_the_documents_tables_are_the_configs() -> None:
    block = generated_block(DOC.read_text(encoding="utf-8"))
    assert block is not None, f"{DOC} has no generated block ({BEGIN} ... {END})"
    assert block == mapping_tables(CONFIG, TEXT), "docs/rig.md is out of date: run eca rig-sheet --doc docs/rig.md"


def test_every_row_has_its_note_from_the_config() -> None:
    notes = config_notes(TEXT)
    for name in (*[n for n in ARKIT_NAMES if n not in EYE_LOOK_NAMES], *VRM_EMOTIONS):
        assert notes.get(name), name
    assert notes["MouthSmileLeft"] == notes["MouthSmileRight"] == "AU12 lip-corner puller"
    assert notes["JawOpen"].startswith("AU26")
    assert notes["EyeBlinkLeft"].startswith("AU45") and notes["BrowDownLeft"].startswith("AU4 brow lowerer")
    assert notes["happy"].startswith("happy: AU12") and notes["relaxed"].startswith("relaxed (VRM 0.x")
    assert notes["surprised"].startswith("surprised: AU1+2")
    tables = mapping_tables(CONFIG, TEXT)
    assert len([line for line in tables.splitlines() if line.startswith("| ") and "`" in line.split("|")[2]]) == 52 + 5


def test_a_row_reads_as_its_sum() -> None:
    assert term_text({"blink_l+": 1.0, "lids_l-": 0.45}) == "`blink_l+` + 0.45 `lids_l-`"
    assert term_text({"brow_l+": -0.5, "brow_l-": 1.0, "brows_knit+": 0.35}) == (
        "`brow_l-` + 0.35 `brows_knit+` − 0.5 `brow_l+`")  # what adds, then what holds back
    assert term_text({"bias": 1.6, "smile_l+": -1.0}) == "1.6 − `smile_l+`"
    assert term_text({"bias": -0.3, "brow_l+": 0.75}) == "−0.3 + 0.75 `brow_l+`"
    assert term_text({"eye_l_yaw+": 1.0 / 30.0}) == "`eye_l_yaw+` / 30°"
    assert term_text({}) == "0"


def test_the_heat_map_holds_the_golden_weights_of_the_nine_emotions() -> None:
    names, arkit, vrm = emotion_weights(Retargeter(CONFIG), load_emotion_table())
    assert names == PAPER_EMOTIONS and arkit.shape == (9, 52) and vrm.shape == (9, 18)
    golden = json.loads(GOLDEN.read_text())
    for k, name in enumerate(names):
        assert np.allclose(arkit[k], list(golden[f"{name}@1"]["arkit"].values()), atol=1e-6), name
        assert np.allclose(vrm[k], list(golden[f"{name}@1"]["vrm"].values()), atol=1e-6), name
    row = {name: k for k, name in enumerate(names)}
    col = {name: i for i, name in enumerate(ARKIT_NAMES)}
    assert arkit[row["happy"], col["MouthSmileLeft"]] == arkit[row["happy"]].max()
    assert arkit[row["angry"], col["BrowDownLeft"]] == arkit[row["angry"]].max()
    figure = emotion_figure(names, arkit, vrm)
    arkit_axes, vrm_axes, scale = figure.axes
    assert [t.get_text() for t in arkit_axes.get_yticklabels()][:2] == ["eyeBlinkLeft", "eyeLookDownLeft"]
    assert len(arkit_axes.get_yticklabels()) == 52 and len(vrm_axes.get_yticklabels()) == len(VRM_NAMES)
    assert [t.get_text() for t in arkit_axes.get_xticklabels()] == list(PAPER_EMOTIONS)
    assert "weight" in scale.get_xlabel()


def test_the_command_writes_the_picture_and_the_tables(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    doc = tmp_path / "rig.md"
    doc.write_text(f"# Rig\n\nbefore\n\n{BEGIN}\nold table\n{END}\n\nafter\n")
    assert eca(["rig-sheet", "-o", str(tmp_path / "img"), "--doc", str(doc)]) == 0
    assert (tmp_path / "img" / PICTURE).read_bytes().startswith(b"\x89PNG")
    assert "wrote" in capsys.readouterr().out
    text = doc.read_text()
    assert text.startswith("# Rig\n\nbefore\n\n") and text.endswith("\n\nafter\n") and "old table" not in text
    assert generated_block(text) == mapping_tables(CONFIG, TEXT)
    assert replace_tables(text, mapping_tables(CONFIG, TEXT)) == text  # rewriting again changes nothing


def test_a_document_without_the_markers_is_refused_in_one_line(tmp_path: Path,
                                                               capsys: pytest.CaptureFixture[str]) -> None:
    doc = tmp_path / "plain.md"
    doc.write_text("# Nothing to rewrite\n")
    assert eca(["rig-sheet", "-o", str(tmp_path / "img"), "--doc", str(doc)]) == 1
    err = capsys.readouterr().err
    assert err.startswith(f"eca rig-sheet: {doc}: no generated block") and err.count("\n") == 1
    assert not (tmp_path / "img").exists() and doc.read_text() == "# Nothing to rewrite\n"
    assert eca(["rig-sheet", "-o", str(tmp_path / "img"), "--doc", str(tmp_path / "missing.md")]) == 1
    assert capsys.readouterr().err.strip() == f"eca rig-sheet: {tmp_path / 'missing.md'}: No such file or directory"
