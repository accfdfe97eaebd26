"""`eca snapshot`: render the face to a PNG (one pose), or a labelled contact sheet of the nine emotions."""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from eca.agent.config import ConfigError
from eca.agent.face.composed import ComposedFace
from eca.agent.face.emotions import PAPER_EMOTIONS, EmotionTable, load_emotion_table
from eca.agent.face.flexors import FLEXOR_INDEX, N_FLEXORS
from eca.agent.face.frame import FlexorFrame
from eca.agent.face.settings import load_flexor_units
from eca.services.processes.renderer import (
    FaceDrawer,
    FlexorFaceDrawer,
    HeadlessContextError,
    RenderToggles,
    check_face,
    create_headless_context,
    load_render_config,
    make_drawer,
    read_rgb,
)
from eca.services.processes.renderer.config import VIEWS, RenderConfig

MOUTHS: tuple[str, ...] = ("rest", "ah", "oo", "ee", "mm", "ff")
VISEMES: tuple[str, ...] = ("say_ah", "say_oo", "say_ee", "say_mm", "say_ff")
DEFAULT_CELL = (400, 300)


class SnapshotError(ValueError):
    """A bad argument; the message names it."""


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "snapshot",
        help="render the face to a PNG, or a contact sheet of the nine emotions",
        description=(
            "Render one still of the cartoon face, or (--sheet) a 3x3 labelled sheet of the paper's nine "
            "emotions. Gaze and head angles are in the agent's own frame: positive yaw/turn is toward "
            "the agent's right, which is the viewer's left in the picture."
        ),
    )
    p.add_argument("-o", "--output", required=True, help="PNG file to write")
    p.add_argument("--sheet", action="store_true", help="a 3x3 contact sheet of the nine emotions")
    p.add_argument("--emotion", default="natural", help="emotion name (default natural)")
    p.add_argument("--intensity", type=float, default=1.0, help="emotion intensity in [0, 1] (default 1)")
    p.add_argument("--yaw", type=float, default=0.0, help="gaze yaw in degrees, + = agent's right")
    p.add_argument("--pitch", type=float, default=0.0, help="gaze pitch in degrees, + = up")
    p.add_argument("--turn", type=float, default=None, help="head turn flexor in [-1, 1], + = agent's right")
    p.add_argument("--nod", type=float, default=None, help="head nod flexor in [-1, 1], + = chin up")
    p.add_argument("--tilt", type=float, default=None, help="head tilt flexor in [-1, 1], + = right shoulder")
    p.add_argument("--blink", type=float, default=None, help="both lids closed by this much, [0, 1]")
    p.add_argument("--mouth", choices=MOUTHS, default=None, help="mouth shape; overrides the emotion's mouth")
    p.add_argument("--view", choices=VIEWS, default="full", help="full face or upper face (eyes and brows)")
    p.add_argument("--face", default="flexor", metavar="FACE",
                   help="flexor (the paper's 2D face, default), head (eca's 3D head) or a .glb/.gltf/.vrm file")
    p.add_argument("--size", default=None, help="image (or, with --sheet, cell) size WxH; default 640x480 / 400x300")
    p.add_argument("--supersample", type=int, default=None, help="render N times larger and filter down (1-4)")
    p.add_argument("--no-eyebrows", action="store_true", help="hide the eyebrows")
    p.add_argument("--no-eye-cover", action="store_true", help="hide the lids")
    p.add_argument("--wireframe", action="store_true", help="draw the polygon mesh")
    p.add_argument("--surface-3d", action="store_true", help="smooth 3D shading instead of cartoon bands")
    p.add_argument("--eye-centre", action="store_true", help="mark the pupil centres")
    p.set_defaults(func=run)


def parse_size(text: str) -> tuple[int, int]:
    """'640x480' -> (640, 480); SnapshotError naming the argument otherwise."""
    parts = text.lower().split("x")
    if len(parts) != 2 or not all(p.strip().isdigit() for p in parts):
        raise SnapshotError(f"--size must look like WIDTHxHEIGHT (e.g. 640x480), got {text!r}")
    width, height = int(parts[0]), int(parts[1])
    if not (16 <= width <= 8192 and 16 <= height <= 8192):
        raise SnapshotError(f"--size must be between 16x16 and 8192x8192, got {text!r}")
    return width, height


def _check_range(name: str, value: float | None, lo: float, hi: float, unit: str = "") -> None:
    if value is not None and not (lo <= value <= hi):  # also rejects NaN
        raise SnapshotError(f"{name} must lie in [{lo:g}, {hi:g}]{unit}, got {value:g}")


def pose_flexors(
    table: EmotionTable,
    config: RenderConfig,
    emotion: str = "natural",
    intensity: float = 1.0,
    yaw: float = 0.0,
    pitch: float = 0.0,
    turn: float | None = None,
    nod: float | None = None,
    tilt: float | None = None,
    blink: float | None = None,
    mouth: str | None = None,
) -> np.ndarray:
    """The flexor vector for a snapshot: the emotion's pose, then gaze, head, lids and mouth on top."""
    if emotion not in table:
        raise SnapshotError(f"unknown emotion {emotion!r}; known: {', '.join(table.names)}")
    _check_range("--intensity", intensity, 0.0, 1.0)
    units = config.units
    _check_range("--yaw", yaw, -units.look_x_deg, units.look_x_deg, " degrees (the eye range in flexor_units.toml)")
    _check_range("--pitch", pitch, -units.look_y_deg, units.look_y_deg, " degrees (the eye range in flexor_units.toml)")
    for name, value in (("--turn", turn), ("--nod", nod), ("--tilt", tilt)):
        _check_range(name, value, -1.0, 1.0)
    _check_range("--blink", blink, 0.0, 1.0)
    f = np.nan_to_num(table.pose(emotion, intensity), nan=0.0)
    f[FLEXOR_INDEX["look_x"]] = yaw / units.look_x_deg
    f[FLEXOR_INDEX["look_y"]] = pitch / units.look_y_deg
    for name, value in (("turn", turn), ("nod", nod), ("tilt", tilt)):
        if value is not None:
            f[FLEXOR_INDEX[name]] = value
    if blink is not None:
        f[FLEXOR_INDEX["blink_l"]] = f[FLEXOR_INDEX["blink_r"]] = blink
    if mouth is not None:
        for viseme in VISEMES:
            f[FLEXOR_INDEX[viseme]] = 0.0
        if mouth != "rest":
            f[FLEXOR_INDEX["say_" + mouth]] = 1.0
    assert f.shape == (N_FLEXORS,)
    return f


def render_image(
    drawer: FaceDrawer,
    flexors: np.ndarray,
    size: tuple[int, int],
    view: str = "full",
    toggles: RenderToggles | None = None,
) -> Image.Image:
    """Draw the face of `flexors` into the drawer's own target (size x supersample) and filter it down to
    `size`."""
    face = ComposedFace.from_frame(FlexorFrame(flexors), load_flexor_units())
    image = Image.fromarray(read_rgb(drawer.draw(face, view=view, toggles=toggles)))
    if image.size != size:
        image = image.resize(size, Image.Resampling.LANCZOS)
    return image


def contact_sheet(
    drawer: FaceDrawer,
    table: EmotionTable,
    cell: tuple[int, int],
    intensity: float = 1.0,
    view: str = "full",
    toggles: RenderToggles | None = None,
    names: tuple[str, ...] = PAPER_EMOTIONS,
) -> Image.Image:
    """A 3-column grid of the emotions, each labelled with its name under the face."""
    width, height = cell
    font = ImageFont.load_default(size=max(12, height // 12))
    label_h = max(18, height // 8)
    cols = 3
    rows = (len(names) + cols - 1) // cols
    sheet = Image.new("RGB", (cols * width, rows * (height + label_h)), (255, 255, 255))
    draw = ImageDraw.Draw(sheet)
    for i, name in enumerate(names):
        f = np.nan_to_num(table.pose(name, intensity), nan=0.0)
        x, y = (i % cols) * width, (i // cols) * (height + label_h)
        picture = render_image(drawer, f, cell, view, toggles)
        if i == 0:  # the sheet's ground is the drawer's own background (the top-left pixel of a picture)
            sheet.paste(picture.getpixel((0, 0)), (0, 0, sheet.width, sheet.height))
        sheet.paste(picture, (x, y))
        label = name if intensity == 1.0 else f"{name} {intensity:g}"
        draw.text((x + width / 2, y + height + label_h / 2), label, fill=(30, 30, 40), font=font, anchor="mm")
    return sheet


def run(args: argparse.Namespace) -> int:
    try:
        return _run(args)
    except (SnapshotError, ConfigError) as exc:
        print(f"eca snapshot: error: {exc}", file=sys.stderr)
        return 2
    except HeadlessContextError as exc:
        print(f"eca snapshot: {exc}", file=sys.stderr)
        return 1


def _run(args: argparse.Namespace) -> int:
    output = Path(args.output)
    if output.suffix.lower() != ".png":
        raise SnapshotError(f"-o must name a .png file, got {str(output)!r}")
    if not output.parent.exists():
        raise SnapshotError(f"-o {str(output)!r}: folder {str(output.parent)!r} does not exist")
    config = load_render_config()
    config = dataclasses.replace(config, mesh_detail=config.still_detail)  # a still can afford a finer mesh
    size = parse_size(args.size) if args.size else (DEFAULT_CELL if args.sheet else config.size)
    supersample = config.supersample if args.supersample is None else args.supersample
    _check_range("--supersample", supersample, 1, 4)
    table = load_emotion_table()
    try:
        face = args.face if args.face == "flexor" else check_face(args.face, "--face")
    except ValueError as exc:
        raise SnapshotError(str(exc)) from None
    toggles = RenderToggles(
        eyebrows=not args.no_eyebrows,
        eye_cover=not args.no_eye_cover,
        wireframe=args.wireframe,
        surface_3d=args.surface_3d,
        eye_centre=args.eye_centre,
    )
    # Validate everything before paying for a GL context.
    flexors = pose_flexors(
        table,
        config,
        args.emotion,
        args.intensity,
        args.yaw,
        args.pitch,
        args.turn,
        args.nod,
        args.tilt,
        args.blink,
        args.mouth,
    )
    ctx = create_headless_context()
    try:
        drawn = (size[0] * supersample, size[1] * supersample)
        drawer = FlexorFaceDrawer(ctx, drawn, config) if face == "flexor" else make_drawer(ctx, drawn, face)
        if args.sheet:
            image = contact_sheet(drawer, table, size, args.intensity, args.view, toggles)
        else:
            image = render_image(drawer, flexors, size, args.view, toggles)
        image.save(output)
    finally:
        ctx.release()
    print(f"wrote {output} ({image.size[0]}x{image.size[1]})")
    return 0
