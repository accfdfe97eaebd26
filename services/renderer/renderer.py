"""The face renderer: draws one flexor frame with cel shading and outlines into any framebuffer.

All GPU objects (programs, buffers, vertex arrays, the offscreen target) are made once in __init__;
a frame writes a handful of uniforms and one small vertex buffer (brows and mouth), so the same
Renderer can draw every frame of a window, a headless test or a video.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import moderngl
import numpy as np

from agent.face.flexors import N_FLEXORS
from services.renderer.config import VIEWS, RenderConfig, load_render_config
from services.renderer.context import check_size, create_offscreen_target
from services.renderer.mesh import (
    EYE_Y,
    IRIS_ANGLE,
    MATERIALS,
    N_BONES,
    PUPIL_ANGLE,
    FacePoser,
    Pose,
    TriangleSelector,
    build_static_mesh,
    eye_centre,
    skin_positions,
)
from services.renderer.shaders import (
    EYE_FRAGMENT,
    FACE_VERTEX,
    FLAT_FRAGMENT,
    OVERLAY_FRAGMENT,
    OVERLAY_VERTEX,
    SURFACE_FRAGMENT,
    variant,
)

VERTEX_FORMAT = ("3f 3f 3f 4f", "in_pos", "in_normal", "in_aux", "in_info")
MAX_TRAJECTORY_POINTS = 600  # a longer overlay_points keeps its most recent points
REFERENCE_HEIGHT = 480.0  # outline and overlay widths are given in pixels at this image height
_OVERLAY_FLOATS = 5  # x, y, r, g, b
_FRAME_BLOCK = 0  # uniform-block binding point of the per-frame matrices
SURFACE, OUTLINE = "surface", "outline"  # the two triangle sets of a FrameIndices


@dataclass
class RenderToggles:
    """The paper's front-end switches (its 'Face Properties' panel)."""

    eyebrows: bool = True
    eye_cover: bool = True  # the lids
    wireframe: bool = False  # the polygon mesh over the surface
    surface_3d: bool = False  # smooth 3D shading instead of flat cartoon bands
    eye_centre: bool = False  # a marker on each pupil centre
    trajectory: bool = True  # the recent gaze polyline, when render() is given overlay_points


def perspective(fov_deg: float, aspect: float, near: float, far: float) -> np.ndarray:
    f = 1.0 / math.tan(math.radians(fov_deg) / 2.0)
    return np.array(
        [
            [f / aspect, 0, 0, 0],
            [0, f, 0, 0],
            [0, 0, (far + near) / (near - far), 2 * far * near / (near - far)],
            [0, 0, -1, 0],
        ]
    )


def _gl(matrix: np.ndarray) -> bytes:
    """A row-major numpy matrix as the column-major float32 bytes GLSL expects."""
    return np.ascontiguousarray(np.asarray(matrix, dtype=np.float32).swapaxes(-1, -2)).tobytes()


class Renderer:
    """Draws the face for a flexor vector; see render().

    Angles follow the agent's own frame (agent/face/flexors.py): look_x and turn at +1 turn toward the
    agent's right, which is the viewer's LEFT in the picture, since the face looks at the camera.
    """

    def __init__(
        self,
        ctx: moderngl.Context,
        size: tuple[int, int] = (640, 480),
        config: RenderConfig | None = None,
    ) -> None:
        self.ctx = ctx
        self.size = check_size(size)
        self.config = config or load_render_config()
        self.poser = FacePoser(self.config.units)
        cfg = self.config

        # Cel and smooth ("3D surface") shading are separate programs rather than a branch: software
        # GL pays for both sides of a branch on every pixel.
        self.programs: dict[str, moderngl.Program] = {
            "surface": ctx.program(vertex_shader=FACE_VERTEX, fragment_shader=variant(SURFACE_FRAGMENT, False)),
            "surface_3d": ctx.program(vertex_shader=FACE_VERTEX, fragment_shader=variant(SURFACE_FRAGMENT, True)),
            "eye": ctx.program(vertex_shader=FACE_VERTEX, fragment_shader=variant(EYE_FRAGMENT, False)),
            "eye_3d": ctx.program(vertex_shader=FACE_VERTEX, fragment_shader=variant(EYE_FRAGMENT, True)),
            "flat": ctx.program(vertex_shader=FACE_VERTEX, fragment_shader=FLAT_FRAGMENT),
        }
        self.flat_prog = self.programs["flat"]
        self.overlay_prog = ctx.program(vertex_shader=OVERLAY_VERTEX, fragment_shader=OVERLAY_FRAGMENT)
        self._programs = tuple(self.programs.values())
        # Bones and camera go in one uniform block that every program reads: one write per frame.
        self.frame_ubo = ctx.buffer(reserve=(N_BONES + 2) * 64, dynamic=True)
        for prog in self._programs:
            prog["Frame"].binding = _FRAME_BLOCK

        static = build_static_mesh(self.config.mesh_detail)
        self.static = static
        self._static_rest = static.vertices[:, 0:3].astype(np.float64)
        self._static_info = static.vertices[:, 10:13]
        self.static_vbo = ctx.buffer(static.vertices.tobytes())
        sample = self.poser.pose(np.zeros(N_FLEXORS))
        dyn_indices, dyn_ranges = self.poser.layout.indices(sample.dynamic)
        self.dynamic_vbo = ctx.buffer(reserve=sample.dynamic.nbytes, dynamic=True)
        # Index buffers are rewritten each frame with only the triangles that can show (see select()).
        self.meshes = {
            "static": FrameIndices(ctx, static.indices, static.ranges, static.vertices.shape[0]),
            "dynamic": FrameIndices(ctx, dyn_indices, dyn_ranges, sample.dynamic.shape[0]),
        }
        self._vaos: dict[tuple[str, str], moderngl.VertexArray] = {}
        for mesh_name, vbo in (("static", self.static_vbo), ("dynamic", self.dynamic_vbo)):
            ibo = self.meshes[mesh_name].ibo
            for prog_name, prog in self.programs.items():
                if mesh_name == "dynamic" and prog_name.startswith("eye"):
                    continue
                self._vaos[mesh_name, prog_name] = ctx.vertex_array(
                    prog, [(vbo, *VERTEX_FORMAT)], index_buffer=ibo, index_element_size=4, skip_errors=True
                )
        # Overlay: two polylines (one per eye) as quads, plus two cross markers.
        self._overlay_capacity = (2 * (MAX_TRAJECTORY_POINTS - 1) + 4) * 6
        self.overlay_vbo = ctx.buffer(reserve=self._overlay_capacity * _OVERLAY_FLOATS * 4, dynamic=True)
        self.overlay_vao = ctx.vertex_array(self.overlay_prog, [(self.overlay_vbo, "2f 3f", "in_pos", "in_color")])
        self.target = create_offscreen_target(ctx, self.size)

        colors = cfg.colors
        palette = {
            "skin": colors["skin"],
            "hair": colors["hair"],
            "brow": colors["brow"],
            "lip": colors["lip"],
            "mouth": colors["mouth"],
            "teeth": colors["teeth"],
            "tongue": colors["tongue"],
            "eye": colors["sclera"],
            "lid": colors["lid"],
            "blush": colors["blush"],
        }
        light = np.asarray(cfg.light, dtype=np.float64)
        constants: dict[str, object] = {
            "u_palette": np.array([palette[m] for m in MATERIALS], dtype=np.float32).tobytes(),
            "u_sclera": colors["sclera"],
            "u_iris": colors["iris"],
            "u_pupil": colors["pupil"],
            "u_blush": colors["blush"],
            "u_light": tuple(light / np.linalg.norm(light)),
            "u_light_v": tuple(light / np.linalg.norm(light)),
            "u_band_edges": cfg.band_edges,
            "u_band_levels": cfg.band_levels,
            "u_ambient": cfg.ambient,
            "u_specular": cfg.specular,
            "u_cos_iris": math.cos(IRIS_ANGLE),
            "u_cos_iris_rim": math.cos(IRIS_ANGLE - 0.12),
            "u_cos_pupil": math.cos(PUPIL_ANGLE),
        }
        for prog in self._programs:
            for name, value in constants.items():
                if name in prog:
                    if isinstance(value, bytes):
                        prog[name].write(value)
                    else:
                        prog[name].value = value
        self.last_pose: Pose | None = None

    def release(self) -> None:
        """Free every GL object this renderer made (the context itself stays the caller's)."""
        for vao in self._vaos.values():
            vao.release()
        self.overlay_vao.release()
        for obj in (
            *self._programs,
            self.overlay_prog,
            self.frame_ubo,
            self.static_vbo,
            self.dynamic_vbo,
            *(mesh.ibo for mesh in self.meshes.values()),
            self.overlay_vbo,
        ):
            obj.release()
        for attachment in (*self.target.color_attachments, self.target.depth_attachment):
            attachment.release()
        self.target.release()
        self._vaos.clear()

    @property
    def fbo(self) -> moderngl.Framebuffer:
        """The renderer's own offscreen target, used when render() is given no target."""
        return self.target

    def camera(self, view: str, aspect: float, model: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """View and projection matrices framing `view` ("full" or "upper") at this aspect ratio.

        The upper view follows the eyes (their midpoint, moved by the head pose `model`) so a nod or
        turn cannot take them out of frame; the head's rotation still shows. The full view is fixed.
        """
        if view not in VIEWS:
            raise ValueError(f"unknown view {view!r}; choose one of {', '.join(VIEWS)}")
        framing = self.config.framings[view]
        # Keep the framed width of a 4:3 image on narrower targets, so the face is never cropped.
        height = framing.height * max(1.0, (4.0 / 3.0) / aspect)
        distance = (height / 2.0) / math.tan(math.radians(framing.fov_deg) / 2.0)
        target = np.array([0.0, framing.center_y, 0.0])
        if view == "upper" and model is not None:
            eyes_rest = np.array([0.0, EYE_Y, float(eye_centre(1)[2]), 1.0])
            target[:2] += (model @ eyes_rest)[:2] - eyes_rest[:2]
        view_m = np.eye(4)
        view_m[0, 3] = -target[0]
        view_m[1, 3] = -target[1]
        view_m[2, 3] = -(distance + framing.depth_z)
        fov = 2.0 * math.degrees(math.atan((height / 2.0) / distance))
        depth = distance + framing.depth_z
        proj = perspective(fov, aspect, max(0.05, depth - 3.0), depth + 3.0)
        return view_m, proj

    def to_pixels(self, points: np.ndarray, view: str = "full", size: tuple[int, int] | None = None) -> np.ndarray:
        """Pixel coordinates (x right, y down, top-left origin) of world points (N, 3) in an image of `size`,
        with the camera of the last rendered frame."""
        width, height = size or self.size
        model = self.last_pose.model if self.last_pose is not None else None
        view_m, proj = self.camera(view, width / height, model)
        ndc = _project(np.asarray(points, dtype=np.float64).reshape(-1, 3), proj @ view_m)
        return np.stack([(ndc[:, 0] + 1) * 0.5 * width, (1 - ndc[:, 1]) * 0.5 * height], 1)

    def render(
        self,
        flexors: np.ndarray,
        target: moderngl.Framebuffer | None = None,
        view: str = "full",
        toggles: RenderToggles | None = None,
        overlay_points: np.ndarray | None = None,
    ) -> moderngl.Framebuffer:
        """Draw one frame and return the framebuffer drawn into.

        flexors: (N_FLEXORS,) in FLEXOR_NAMES order (or a FlexorFrame); NaN counts as relaxed 0 and
        values are clipped to [-1, 1]. target: any framebuffer (a window's, an offscreen one); None
        draws into this renderer's own offscreen target (`fbo`). overlay_points: recent gaze as rows of
        (look_x, look_y) flexor values, oldest first, drawn as each pupil centre's path.
        """
        toggles = toggles or RenderToggles()
        fbo = target if target is not None else self.target
        pose = self.poser.pose(flexors)
        self.last_pose = pose
        ctx = self.ctx
        fbo.use()
        _, _, width, height = fbo.viewport
        view_m, proj = self.camera(view, width / max(height, 1), pose.model)
        bg = self.config.colors["background"]
        fbo.clear(bg[0], bg[1], bg[2], 1.0, depth=1.0)

        modelview = view_m @ pose.model
        frame = np.empty((N_BONES + 2, 4, 4), dtype=np.float32)
        frame[:N_BONES] = pose.bones
        frame[N_BONES] = modelview
        frame[N_BONES + 1] = proj
        self.frame_ubo.write(_gl(frame))
        self.frame_ubo.bind_to_uniform_block(_FRAME_BLOCK)
        self.dynamic_vbo.write(pose.dynamic)
        # The eye in the head frame (modelview is a rigid motion): where every facing test looks from.
        eye = -modelview[:3, :3].T @ modelview[:3, 3]
        self.meshes["static"].update(skin_positions(self._static_rest, self._static_info, pose.bones), eye)
        dyn = pose.dynamic
        self.meshes["dynamic"].update(skin_positions(dyn[:, 0:3].astype(np.float64), dyn[:, 10:13], pose.bones), eye)
        suffix = "_3d" if toggles.surface_3d else ""
        self.flat_prog["u_viewport"].value = (float(width), float(height))

        ctx.enable(moderngl.DEPTH_TEST | moderngl.CULL_FACE)
        ctx.wireframe = False
        ctx.cull_face = "back"
        surface_static = ["decals", "face"] + (["lids"] if toggles.eye_cover else [])
        dynamic_groups = (["brows"] if toggles.eyebrows else []) + ["lips", "inner"]
        outlined_dynamic = [g for g in dynamic_groups if g != "inner"]
        # Front to back: what lies on the face first, so the head's hidden pixels fail the depth test early.
        self._draw("dynamic", "surface" + suffix, dynamic_groups)
        self._draw("static", "eye" + suffix, ["eyes"])
        self._draw("static", "surface" + suffix, surface_static)

        # Inverted hull: back faces pushed out along their normals show only around silhouettes.
        flat = self.flat_prog
        outline_px = self.config.outline_px * height / REFERENCE_HEIGHT
        if outline_px > 0:
            ctx.cull_face = "front"
            flat["u_outline"].value = outline_px
            flat["u_flat"].value = self.config.colors["outline"]
            # Closed lids hide the eyeballs' silhouettes: outline the eyes only when the lids are off.
            self._draw("static", "flat", ["face"] + (["lids"] if toggles.eye_cover else ["eyes"]), OUTLINE)
            self._draw("dynamic", "flat", outlined_dynamic, OUTLINE)
            flat["u_outline"].value = 0.0
            ctx.cull_face = "back"

        if toggles.wireframe:
            ctx.wireframe = True
            flat["u_flat"].value = self.config.colors["wireframe"]
            flat["u_depth_bias"].value = 0.002
            self._draw("static", "flat", surface_static + ["eyes"])
            self._draw("dynamic", "flat", dynamic_groups)
            ctx.wireframe = False
            flat["u_depth_bias"].value = 0.0

        overlay = self._overlay(pose, proj @ view_m, toggles, overlay_points, height)
        if overlay is not None:
            ctx.disable(moderngl.DEPTH_TEST | moderngl.CULL_FACE)
            self.overlay_vbo.write(overlay)
            self.overlay_vao.render(moderngl.TRIANGLES, vertices=overlay.shape[0])
        ctx.disable(moderngl.DEPTH_TEST | moderngl.CULL_FACE)
        return fbo

    def _draw(self, mesh_name: str, prog_name: str, groups: list[str], kind: str = SURFACE) -> None:
        vao = self._vaos[mesh_name, prog_name]
        ranges = self.meshes[mesh_name].ranges
        for first, count in _merge_ranges([ranges[kind, g] for g in groups]):
            if count:
                vao.render(moderngl.TRIANGLES, vertices=count, first=first)

    def _overlay(
        self,
        pose: Pose,
        view_proj: np.ndarray,
        toggles: RenderToggles,
        overlay_points: np.ndarray | None,
        height: int,
    ) -> np.ndarray | None:
        pieces: list[np.ndarray] = []
        px = 2.0 / max(height, 1)  # one pixel in NDC, vertically
        aspect = view_proj[1, 1] / view_proj[0, 0]
        scale = height / REFERENCE_HEIGHT
        if toggles.trajectory and overlay_points is not None:
            pts = np.asarray(overlay_points, dtype=np.float64)
            if pts.ndim != 2 or pts.shape[1] != 2:
                raise ValueError(f"overlay_points must be rows of (look_x, look_y), got shape {pts.shape}")
            pts = np.nan_to_num(pts[-MAX_TRAJECTORY_POINTS:])
            if pts.shape[0] >= 2:
                world = self.poser.gaze_points(pts, pose.model)
                for k in range(2):
                    ndc = _project(world[k], view_proj)
                    pieces.append(_polyline(ndc, max(1.0, 1.2 * scale) * px, aspect, self.config.colors["trajectory"]))
        if toggles.eye_centre:
            ndc = _project(pose.pupils, view_proj)
            for p in ndc:
                pieces.append(
                    _cross(
                        p,
                        max(4.0, 7.0 * scale) * px,
                        max(1.0, 1.3 * scale) * px,
                        aspect,
                        self.config.colors["eye_centre"],
                    )
                )
        if not pieces:
            return None
        return np.ascontiguousarray(np.concatenate(pieces).astype(np.float32))


class FrameIndices:
    """One mesh's index buffer, rewritten each frame: the triangles facing the camera, then the band
    around the silhouette that the outline pass needs (mesh.TriangleSelector), each by named group."""

    def __init__(
        self, ctx: moderngl.Context, indices: np.ndarray, ranges: dict[str, tuple[int, int]], n_vertices: int
    ) -> None:
        self.triangles = np.ascontiguousarray(indices, dtype=np.uint32).reshape(-1, 3)
        self.selector = TriangleSelector(self.triangles, n_vertices)
        # Group bounds in triangles, in index order; a group's triangles stay in their original order.
        self.groups = sorted((first // 3, (first + count) // 3, name) for name, (first, count) in ranges.items())
        self.ibo = ctx.buffer(reserve=2 * self.triangles.nbytes, dynamic=True)
        self.ranges: dict[tuple[str, str], tuple[int, int]] = {}
        self.update_masks(np.ones(len(self.triangles), dtype=bool), np.ones(len(self.triangles), dtype=bool))

    def update(self, positions: np.ndarray, eye: np.ndarray) -> None:
        """Select and upload the triangles for head-frame vertex `positions` seen from `eye`."""
        self.update_masks(*self.selector.select(positions, eye))

    def update_masks(self, surface: np.ndarray, outline: np.ndarray) -> None:
        offset = 0
        for kind, mask in ((SURFACE, surface), (OUTLINE, outline)):
            before = np.concatenate([[0], np.cumsum(mask)])  # selected triangles before each one
            for start, stop, name in self.groups:
                self.ranges[kind, name] = (3 * (offset + int(before[start])), 3 * int(before[stop] - before[start]))
            offset += int(before[-1])
        self.ibo.write(np.concatenate([self.triangles[surface], self.triangles[outline]]))


def _merge_ranges(ranges: list[tuple[int, int]]) -> list[tuple[int, int]]:
    """Adjacent index ranges joined, so a frame needs as few draw calls as possible."""
    out: list[tuple[int, int]] = []
    for first, count in sorted(ranges):
        if out and out[-1][0] + out[-1][1] == first:
            out[-1] = (out[-1][0], out[-1][1] + count)
        else:
            out.append((first, count))
    return out


def _project(points: np.ndarray, view_proj: np.ndarray) -> np.ndarray:
    h = np.concatenate([points, np.ones((points.shape[0], 1))], axis=1) @ view_proj.T
    return h[:, :2] / h[:, 3:4]


def _polyline(ndc: np.ndarray, half_width: float, aspect: float, color: tuple[float, float, float]) -> np.ndarray:
    """Quads (two triangles each) along a polyline in NDC, of constant pixel width."""
    a, b = ndc[:-1], ndc[1:]
    d = (b - a) * np.array([aspect, 1.0])
    length = np.linalg.norm(d, axis=1, keepdims=True)
    normal = np.stack([-d[:, 1], d[:, 0]], 1) / np.maximum(length, 1e-9) * half_width
    normal[:, 0] /= aspect
    quads = np.stack([a - normal, a + normal, b + normal, a - normal, b + normal, b - normal], 1).reshape(-1, 2)
    out = np.empty((quads.shape[0], _OVERLAY_FLOATS))
    out[:, :2] = quads
    out[:, 2:] = color
    return out


def _cross(
    p: np.ndarray, arm: float, half_width: float, aspect: float, color: tuple[float, float, float]
) -> np.ndarray:
    ax = np.array([arm / aspect, 0.0])
    ay = np.array([0.0, arm])
    return np.concatenate(
        [
            _polyline(np.stack([p - ax, p + ax]), half_width, aspect, color),
            _polyline(np.stack([p - ay, p + ay]), half_width, aspect, color),
        ]
    )
