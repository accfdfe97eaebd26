"""The light on the face and how each material takes it.

A face is lit as a portrait is: a warm key light high and to one side, a dimmer cool fill from the other side
that keeps the shadow side readable, a rim light from behind that separates the head from the background, and a
little ambient light, brighter from above than from below. Everything is computed in linear light and written
out encoded (shaders.py: a 2.2 power, close to sRGB), so the face's shading falls off as light does, not
darker.

Skin gets wrapped diffuse light (the terminator softened, red wrapping furthest: a cheap stand-in for light
scattered under the skin) and no highlight at all: a face lit softly has none to speak of, and a broad sheen on
a sphere of a head reads as plastic. Only glossy materials (roughness under GLOSSY_ROUGHNESS: an eye, a cornea,
glasses) get a highlight, per pixel. Toon (VRM MToon) materials get the two-tone step instead.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from eca.services.processes.avatar.model import Material

# Names by which a material is taken for skin (glTF has no such notion; model files name their materials).
SKIN_WORDS = ("skin", "face", "head", "body", "neck", "lid", "ear", "nose", "cheek")
GLOSSY_ROUGHNESS = 0.35
GAMMA = 2.2
F0 = 0.04  # a dielectric's reflectance at normal incidence (cornea, glass)


def encode(c: tuple[float, ...]) -> tuple[float, ...]:
    """Linear values encoded with the drawer's power law (shaders.py)."""
    return tuple(float(max(v, 0.0)) ** (1.0 / GAMMA) for v in c)


def _unit(v: tuple[float, float, float]) -> tuple[float, float, float]:
    a = np.asarray(v, dtype=np.float64)
    x, y, z = (float(c) for c in a / np.linalg.norm(a))
    return (x, y, z)


@dataclass(frozen=True)
class Lights:
    """The light rig, camera space (x right, y up, z toward the camera), linear RGB intensities."""

    # From the viewer's upper left, as the 2D face's light; a little lower than that, so the eyes' catchlight falls
    # on the iris rather than under the upper lid.
    key_dir: tuple[float, float, float] = _unit((-0.5, 0.4, 0.75))
    key: tuple[float, float, float] = (1.0, 0.93, 0.85)
    fill_dir: tuple[float, float, float] = _unit((0.75, 0.05, 0.55))
    fill: tuple[float, float, float] = (0.16, 0.19, 0.25)
    rim_dir: tuple[float, float, float] = _unit((0.35, 0.5, -0.8))
    rim: tuple[float, float, float] = (0.55, 0.58, 0.65)
    sky: tuple[float, float, float] = (0.20, 0.22, 0.26)
    ground: tuple[float, float, float] = (0.10, 0.08, 0.07)
    exposure: float = 1.0

    def uniforms(self) -> dict[str, object]:
        return {
            "u_key_dir": self.key_dir,
            "u_key": self.key,
            "u_fill_dir": self.fill_dir,
            "u_fill": self.fill,
            "u_rim_dir": self.rim_dir,
            "u_rim": self.rim,
            "u_sky": self.sky,
            "u_ground": self.ground,
            "u_exposure": self.exposure,
            "u_key_encoded": encode(tuple(v * self.exposure for v in self.key)),
        }


def is_skin(material: Material) -> bool:
    name = material.name.lower()
    return any(word in name for word in SKIN_WORDS)


def shininess(roughness: float) -> float:
    """The Blinn-Phong exponent of a roughness (alpha = roughness^2, exponent 2 / alpha^2 - 2), kept within
    2..400 so a mirror-smooth cornea still has a catchlight some pixels wide (a true point light's reflection
    would fall between pixels)."""
    alpha = max(float(roughness), 0.02) ** 2
    return float(np.clip(2.0 / alpha**2 - 2.0, 2.0, 400.0))


def is_glossy(material: Material) -> bool:
    return material.roughness < GLOSSY_ROUGHNESS


def material_uniforms(material: Material) -> dict[str, object]:
    """How a material takes the light (the material uniforms of shaders.DRAW_VERTEX and FRAGMENT)."""
    skin = is_skin(material)
    r, g, b, a = material.base_color
    exponent = shininess(material.roughness)
    return {
        "u_base": (*encode((r, g, b)), float(a)),
        "u_cutoff": float(material.alpha_cutoff),
        "u_wrap": 0.6 if skin else 0.25,
        "u_wrap_tint": (1.0, 0.62, 0.48) if skin else (1.0, 1.0, 1.0),
        "u_shade": encode(material.shade_color),
        "u_ramp": 0.06,
        # Normalised Blinn-Phong at normal incidence: (n + 8) / (8 pi) times F0.
        "u_gloss": F0 * (exponent + 8.0) / (8.0 * 3.14159265),
        "u_shininess": exponent,
    }
