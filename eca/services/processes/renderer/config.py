"""The renderer's settings (configs/render.toml), validated with errors that name the file and key."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from eca.agent.config import ConfigError, config_path, load_toml, require
from eca.agent.face.settings import FlexorUnits, load_flexor_units

COLOR_NAMES: tuple[str, ...] = (
    "background",
    "skin",
    "blush",
    "hair",
    "brow",
    "lip",
    "mouth",
    "teeth",
    "tongue",
    "sclera",
    "iris",
    "pupil",
    "lid",
    "outline",
    "wireframe",
    "eye_centre",
    "trajectory",
)
VIEWS: tuple[str, ...] = ("full", "upper")


@dataclass(frozen=True)
class Framing:
    center_y: float
    height: float
    fov_deg: float
    depth_z: float = 0.0  # the head-frame z of the plane that `height` measures (0 = the head's centre)


@dataclass(frozen=True)
class RenderConfig:
    colors: dict[str, tuple[float, float, float]]
    framings: dict[str, Framing]
    light: tuple[float, float, float] = (-0.45, 0.6, 0.75)
    band_edges: tuple[float, float] = (0.05, 0.5)
    band_levels: tuple[float, float, float] = (0.72, 0.88, 1.0)
    ambient: float = 0.35
    specular: float = 0.25
    outline_px: float = 2.2
    size: tuple[int, int] = (640, 480)
    supersample: int = 2
    mesh_detail: float = 1.0  # tessellation of the live mesh; stills use still_detail
    still_detail: float = 2.0
    units: FlexorUnits = field(default_factory=load_flexor_units)


def _floats(table: dict[str, Any], key: str, n: int, where: str, lo: float, hi: float) -> tuple[float, ...]:
    value = require(table, key, list, where)
    if len(value) != n or not all(isinstance(v, int | float) and not isinstance(v, bool) for v in value):
        raise ConfigError(f"{where}: '{key}' must be a list of {n} numbers, got {value!r}")
    if not all(lo <= float(v) <= hi for v in value):
        raise ConfigError(f"{where}: '{key}' values must lie in [{lo}, {hi}], got {value!r}")
    return tuple(float(v) for v in value)


def _number(table: dict[str, Any], key: str, where: str, lo: float, hi: float) -> float:
    value = float(require(table, key, float, where))
    if not lo <= value <= hi:
        raise ConfigError(f"{where}: '{key}' must lie in [{lo}, {hi}], got {value}")
    return value


def _table(doc: dict[str, Any], key: str, where: str) -> dict[str, Any]:
    value = require(doc, key, dict, where)
    return value


def load_render_config(name: str | Path = "render", units: str | Path = "flexor_units") -> RenderConfig:
    """Read configs/render.toml (or another file) and the flexor units; ConfigError names file and key."""
    doc = load_toml(name)
    where = str(config_path(str(name)))
    colors_t = _table(doc, "colors", where)
    colors = {c: _floats(colors_t, c, 3, f"{where} [colors]", 0.0, 1.0) for c in COLOR_NAMES}
    camera = _table(doc, "camera", where)
    framings = {}
    for view in VIEWS:
        t = _table(camera, view, f"{where} [camera]")
        w = f"{where} [camera.{view}]"
        framings[view] = Framing(
            center_y=_number(t, "center_y", w, -3.0, 3.0),
            height=_number(t, "height", w, 0.1, 10.0),
            fov_deg=_number(t, "fov_deg", w, 1.0, 120.0),
            depth_z=_number(t, "depth_z", w, -2.0, 2.0) if "depth_z" in t else 0.0,
        )
    shading = _table(doc, "shading", where)
    ws = f"{where} [shading]"
    edges = _floats(shading, "band_edges", 2, ws, -1.0, 1.0)
    if edges[0] >= edges[1]:
        raise ConfigError(f"{ws}: 'band_edges' must increase, got {list(edges)}")
    outline = _table(doc, "outline", where)
    image = _table(doc, "image", where)
    mesh = _table(doc, "mesh", where)
    wi = f"{where} [image]"
    return RenderConfig(
        colors=colors,  # type: ignore[arg-type]
        framings=framings,
        light=_floats(shading, "light", 3, ws, -1.0, 1.0),  # type: ignore[arg-type]
        band_edges=edges,  # type: ignore[arg-type]
        band_levels=_floats(shading, "band_levels", 3, ws, 0.0, 2.0),  # type: ignore[arg-type]
        ambient=_number(shading, "ambient", ws, 0.0, 1.0),
        specular=_number(shading, "specular", ws, 0.0, 1.0),
        outline_px=_number(outline, "width_px", f"{where} [outline]", 0.0, 20.0),
        size=(int(_number(image, "width", wi, 16, 8192)), int(_number(image, "height", wi, 16, 8192))),
        supersample=int(_number(image, "supersample", wi, 1, 4)),
        mesh_detail=_number(mesh, "detail", f"{where} [mesh]", 0.5, 4.0),
        still_detail=_number(mesh, "still_detail", f"{where} [mesh]", 0.5, 4.0),
        units=load_flexor_units(units),
    )
