"""The face renderer: draws one flexor frame with cel shading and outlines into any framebuffer.

All GPU objects (programs, buffers, vertex arrays, the offscreen target) are made once in __init__;
a frame writes a handful of uniforms, the few hundred numbers the vertex shader builds the brows and
the mouth from (curves.curve_block), the static triangles that face the camera and the outline quads
along the static parts' silhouettes, so the same Renderer can draw every frame of a window, a
headless test or a video.
"""

from __future__ import annotations

import math

import moderngl
import numpy as np

from eca.agent.face.flexors import N_FLEXORS
from eca.services.processes.renderer.common import RenderToggles, perspective
from eca.services.processes.renderer.config import VIEWS, Framing, RenderConfig, load_render_config
from eca.services.processes.renderer.context import check_size, create_offscreen_target
from eca.services.processes.renderer.curves import CURVE_POINTS, TUBE_POINTS, shader_template
from eca.services.processes.renderer.geometry import (
    EYE_Y,
    IRIS_ANGLE,
    MATERIALS,
    N_BONES,
    PUPIL_ANGLE,
    build_static_mesh,
    eye_centre,
)
from eca.services.processes.renderer.kernels import ensure_compiled, static_frame_indices
from eca.services.processes.renderer.outline import RigidFacing, Silhouette, extruded_copy
from eca.services.processes.renderer.poser import FacePoser, Pose
from eca.services.processes.renderer.shaders import (
    EYE_FRAGMENT,
    FLAT_FRAGMENT,
    OVERLAY_FRAGMENT,
    OVERLAY_VERTEX,
    SURFACE_FRAGMENT,
    face_vertex,
    variant,
)

VERTEX_FORMAT = ("3f 3f 3f 4f", "in_pos", "in_normal", "in_aux", "in_info")
MAX_TRAJECTORY_POINTS = 600  # a longer overlay_points keeps its most recent points
REFERENCE_HEIGHT = 480.0  # outline and overlay widths are given in pixels at this image height
_OVERLAY_FLOATS = 5  # x, y, r, g, b
_FRAME_BLOCK, _CURVES_BLOCK = 0, 1  # uniform-block binding points of the per-frame matrices and curves
SURFACE, OUTLINE = "surface", "outline"  # the two index sets of a FrameIndices


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
        ensure_compiled()  # a first start after installing compiles here, and says so
        self.ctx = ctx
        self.size = check_size(size)
        self.config = config or load_render_config()
        self.poser = FacePoser(self.config.units)
        cfg = self.config

        # Cel and smooth ("3D surface") shading are separate programs rather than a branch: software
        # GL pays for both sides of a branch on every pixel. The static parts' programs also leave out
        # how the brows and mouth are built (shaders.face_vertex), which none of their vertices needs.
        fragments = {
            "surface": variant(SURFACE_FRAGMENT, False),
            "surface_3d": variant(SURFACE_FRAGMENT, True),
            "eye": variant(EYE_FRAGMENT, False),
            "eye_3d": variant(EYE_FRAGMENT, True),
            "flat": FLAT_FRAGMENT,
        }
        self.programs: dict[tuple[str, str], moderngl.Program] = {}
        for mesh_name, curves in (("static", False), ("dynamic", True)):
            vertex = face_vertex(curves)
            for prog_name, fragment in fragments.items():
                if mesh_name == "dynamic" and prog_name.startswith("eye"):
                    continue
                self.programs[mesh_name, prog_name] = ctx.program(vertex_shader=vertex, fragment_shader=fragment)
        self.flat_progs = (self.programs["static", "flat"], self.programs["dynamic", "flat"])
        self.overlay_prog = ctx.program(vertex_shader=OVERLAY_VERTEX, fragment_shader=OVERLAY_FRAGMENT)
        self._programs = tuple(self.programs.values())
        # Bones and camera go in one uniform block that every program reads: one write per frame.
        self._frame = np.zeros((N_BONES + 1, 4, 4), dtype=np.float32)
        self.frame_ubo = ctx.buffer(reserve=self._frame.nbytes, dynamic=True)
        # The points from which the vertex shader builds the brows and the mouth (curves.curve_block).
        self._curves = np.zeros((CURVE_POINTS + TUBE_POINTS, 4), dtype=np.float32)
        self.curve_ubo = ctx.buffer(reserve=self._curves.nbytes, dynamic=True)
        for prog in self._programs:
            prog["Frame"].binding = _FRAME_BLOCK
            if "Curves" in prog:
                prog["Curves"].binding = _CURVES_BLOCK

        static = build_static_mesh(self.config.mesh_detail)
        self.static = static
        self.static_facing = RigidFacing(static.vertices, static.indices.reshape(-1, 3))
        self.static_vbo = ctx.buffer(extruded_copy(static.vertices).tobytes())
        sample = self.poser.pose(np.zeros(N_FLEXORS))
        dyn_indices, dyn_ranges = self.poser.layout.indices(sample.dynamic)
        # The vertex shader builds the brows, lips and the mouth's strips on the head from the Curves
        # block, so the dynamic vertices only say which point and which place around a tube they are,
        # and never change (the strips' outline copies are never drawn).
        self.dynamic_vbo = ctx.buffer(extruded_copy(shader_template(self.poser.layout)).tobytes())
        # The static outline quads are chosen each frame; the dynamic parts keep an inverted hull. Face and
        # lids side by side in the outline buffer: the outline pass draws both with one call.
        self.meshes: dict[str, FrameIndices | HullIndices] = {
            "static": FrameIndices(
                ctx, static.indices, static.ranges, static.vertices, ("face", "lids", "eyes"), self.static_facing
            ),
            "dynamic": HullIndices(ctx, dyn_indices, dyn_ranges, sample.dynamic.shape[0], ("brows", "lips")),
        }
        self._vaos: dict[tuple[str, str, str], moderngl.VertexArray] = {}  # (mesh, program, index set)
        for (mesh_name, prog_name), prog in self.programs.items():
            vbo = self.static_vbo if mesh_name == "static" else self.dynamic_vbo
            for kind in (SURFACE, OUTLINE) if prog_name == "flat" else (SURFACE,):
                self._vaos[mesh_name, prog_name, kind] = ctx.vertex_array(
                    prog,
                    [(vbo, *VERTEX_FORMAT)],
                    index_buffer=self.meshes[mesh_name].ibos[kind],
                    index_element_size=4,
                    skip_errors=True,
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
            "u_glint": tuple(_unit(light / np.linalg.norm(light) + np.array([0.0, 0.0, 1.6]))),
        }
        for prog in self._programs:
            for name, value in constants.items():
                if name in prog:
                    if isinstance(value, bytes):
                        prog[name].write(value)
                    else:
                        prog[name].value = value
        self.last_pose: Pose | None = None
        self._camera_key: tuple[Framing, float, float, float] | None = None
        self._camera_value: tuple[np.ndarray, np.ndarray] = (np.eye(4), np.eye(4))

    def release(self) -> None:
        """Free every GL object this renderer made (the context itself stays the caller's)."""
        for vao in self._vaos.values():
            vao.release()
        self.overlay_vao.release()
        for obj in (
            *self._programs,
            self.overlay_prog,
            self.frame_ubo,
            self.curve_ubo,
            self.static_vbo,
            self.dynamic_vbo,
            *{id(ibo): ibo for mesh in self.meshes.values() for ibo in mesh.ibos.values()}.values(),
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
        target = np.array([0.0, framing.center_y, 0.0])
        if view == "upper" and model is not None:
            eyes_rest = np.array([0.0, EYE_Y, float(eye_centre(1)[2]), 1.0])
            target[:2] += (model @ eyes_rest)[:2] - eyes_rest[:2]
        key = (framing, aspect, float(target[0]), float(target[1]))
        if self._camera_key != key:  # the full view's camera stays put from frame to frame
            self._camera_key, self._camera_value = key, self._camera(framing, aspect, target)
        return self._camera_value

    @staticmethod
    def _camera(framing: Framing, aspect: float, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        # Keep the framed width of a 4:3 image on narrower targets, so the face is never cropped.
        height = framing.height * max(1.0, (4.0 / 3.0) / aspect)
        distance = (height / 2.0) / math.tan(math.radians(framing.fov_deg) / 2.0)
        view_m = np.eye(4)
        view_m[0, 3] = -target[0]
        view_m[1, 3] = -target[1]
        view_m[2, 3] = -(distance + framing.depth_z)
        fov = 2.0 * math.degrees(math.atan((height / 2.0) / distance))
        depth = distance + framing.depth_z
        proj = perspective(fov, aspect, max(0.05, depth - 3.0), depth + 3.0)
        view_m.flags.writeable = False  # shared by the frames that reuse them
        proj.flags.writeable = False
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
        pose = self.poser.pose(flexors, dynamic=False)
        self.last_pose = pose
        ctx = self.ctx
        fbo.use()
        _, _, width, height = fbo.viewport
        view_m, proj = self.camera(view, width / max(height, 1), pose.model)
        bg = self.config.colors["background"]
        fbo.clear(bg[0], bg[1], bg[2], 1.0, depth=1.0)

        modelview = view_m @ pose.model
        matrices = self._frame  # column-major, as GLSL reads them
        matrices[:N_BONES] = (modelview @ pose.bones).swapaxes(-1, -2)
        matrices[N_BONES] = proj.T
        self.frame_ubo.write(matrices)
        self.frame_ubo.bind_to_uniform_block(_FRAME_BLOCK)
        # The brows and mouth: the points the vertex shader builds them from.
        self.poser.build_dynamic(pose, self._curves)
        self.curve_ubo.write(self._curves)
        self.curve_ubo.bind_to_uniform_block(_CURVES_BLOCK)
        # The eye in the head frame (modelview is a rigid motion): where every facing test looks from.
        eye = -modelview[:3, :3].T @ modelview[:3, 3]
        self.meshes["static"].update_for(pose.bones, eye)
        suffix = "_3d" if toggles.surface_3d else ""
        self._set_flat("u_viewport", (float(width), float(height)))

        ctx.enable(moderngl.DEPTH_TEST | moderngl.CULL_FACE)
        ctx.wireframe = False
        ctx.cull_face = "back"
        dynamic_groups = (["brows"] if toggles.eyebrows else []) + ["lips", "inner"]
        # Front to back, so that hidden pixels fail the depth test before they are shaded: what lies on
        # the face, then the lids (in front of the eyes, whose shader is the costliest), the eyes, the head.
        self._draw("dynamic", "surface" + suffix, dynamic_groups)
        if toggles.eye_cover:
            self._draw("static", "surface" + suffix, ["lids"])
        self._draw("static", "eye" + suffix, ["eyes"])
        self._draw("static", "surface" + suffix, ["decals", "nose", "face"])

        # Outlines, a fixed number of pixels wide; the depth test hides what lies behind nearer surfaces.
        outline_px = self.config.outline_px * height / REFERENCE_HEIGHT
        if outline_px > 0:
            self._set_flat("u_outline", outline_px)
            self._set_flat("u_flat", self.config.colors["outline"])
            # The static parts: a quad along each silhouette edge, pushed outward; they wind either way,
            # so nothing is culled. Closed lids hide the eyeballs' silhouettes: outline the eyes only
            # when the lids are off.
            ctx.disable(moderngl.CULL_FACE)
            self._draw("static", "flat", ["face"] + (["lids"] if toggles.eye_cover else ["eyes"]), OUTLINE)
            ctx.enable(moderngl.CULL_FACE)
            # The small dynamic parts: an inverted hull, their back faces pushed outward, which show only
            # around the silhouettes.
            ctx.cull_face = "front"
            self._draw("dynamic", "flat", [g for g in dynamic_groups if g != "inner"], OUTLINE)
            ctx.cull_face = "back"
            self._set_flat("u_outline", 0.0)

        if toggles.wireframe:
            ctx.wireframe = True
            self._set_flat("u_flat", self.config.colors["wireframe"])
            self._set_flat("u_depth_bias", 0.002)
            self._draw("static", "flat", ["decals", "nose", "face", "eyes"] + (["lids"] if toggles.eye_cover else []))
            self._draw("dynamic", "flat", dynamic_groups)
            ctx.wireframe = False
            self._set_flat("u_depth_bias", 0.0)

        overlay = self._overlay(pose, proj @ view_m, toggles, overlay_points, height)
        if overlay is not None:
            ctx.disable(moderngl.DEPTH_TEST | moderngl.CULL_FACE)
            self.overlay_vbo.write(overlay)
            self.overlay_vao.render(moderngl.TRIANGLES, vertices=overlay.shape[0])
        ctx.disable(moderngl.DEPTH_TEST | moderngl.CULL_FACE)
        return fbo

    def _set_flat(self, name: str, value: object) -> None:
        """Set a uniform of the flat programs (outlines, wireframe) of both meshes."""
        for prog in self.flat_progs:
            prog[name].value = value

    def _draw(self, mesh_name: str, prog_name: str, groups: list[str], kind: str = SURFACE) -> None:
        vao = self._vaos[mesh_name, prog_name, kind]
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
        want_trail = toggles.trajectory and overlay_points is not None
        if not (want_trail or toggles.eye_centre):
            return None
        pieces: list[np.ndarray] = []
        px = 2.0 / max(height, 1)  # one pixel in NDC, vertically
        aspect = view_proj[1, 1] / view_proj[0, 0]
        scale = height / REFERENCE_HEIGHT
        if want_trail:
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
    """The static mesh's index buffers, rewritten each frame from which way its triangles face: for the
    surface, each named group's triangles that may face the camera; for the outline, the quads of the
    silhouette edges (outline.Silhouette).

    Software GL shades the vertices of every triangle it is given and sets each up before it culls the
    back faces, and about half of the static triangles face away in any frame, so they are left out of
    the surface buffer. A triangle within EDGE_ON_SLACK of edge-on stays in (GL culls it by its
    projected area in single precision, the test here is in double), so the picture is the same as
    drawing them all.

    update_for(bones, eye) does it per frame in one compiled pass (kernels.py); update(distances) is
    the same in numpy, from RigidFacing.distances: the reference the compiled pass is tested against."""

    EDGE_ON_SLACK = 1e-4  # head-frame units of the eye's distance from a triangle's plane (the head is ~2 wide)

    def __init__(
        self,
        ctx: moderngl.Context,
        indices: np.ndarray,
        ranges: dict[str, tuple[int, int]],
        vertices: np.ndarray,
        outlined: tuple[str, ...],
        facing: RigidFacing,
    ) -> None:
        indices = np.ascontiguousarray(indices, dtype=np.uint32)
        triangles = indices.reshape(-1, 3)
        self.ranges: dict[tuple[str, str], tuple[int, int]] = {(SURFACE, name): r for name, r in ranges.items()}
        # The surface groups in index order, each a run of whole triangles.
        by_start = sorted(ranges.items(), key=lambda item: item[1][0])
        self._groups = [name for name, _ in by_start]
        self._group_starts = np.array([first // 3 for _, (first, _) in by_start], dtype=np.int64)
        bounds = [0]
        for name, (first, count) in by_start:
            if first != bounds[-1] or count <= 0 or count % 3:
                raise ValueError(f"surface group {name!r} is not the next run of whole triangles")
            bounds.append(first + count)
        if bounds[-1] != indices.size:
            raise ValueError("the surface groups must cover the whole index buffer")
        self._triangles = triangles.copy()
        # One table of the outlined groups' edges, group after group, with the triangles on each side
        # numbered across the whole mesh (len(triangles) where the mesh ends: never facing).
        t0, t1, quads, self._names, bounds = [], [], [], [], [0]
        for name in outlined:
            first, count = ranges[name]
            start = first // 3
            sil = Silhouette(vertices[:, 0:3], triangles[start : start + count // 3], vertices.shape[0])
            t0.append(sil.t0 + start)
            t1.append(np.where(sil.t1 == sil.n_triangles, len(triangles), sil.t1 + start))
            quads.append(sil.quads)
            self._names.append(name)
            bounds.append(bounds[-1] + len(sil.quads))
        self._t0, self._t1 = np.concatenate(t0).astype(np.int64), np.concatenate(t1).astype(np.int64)
        self._quads = np.ascontiguousarray(np.concatenate(quads), dtype=np.uint32)
        self._starts = np.array(bounds[:-1], dtype=np.int64)  # each group's first edge
        self._front = np.zeros(len(triangles) + 1, dtype=bool)
        self._facing = facing
        # What a frame selects, written in place by update or update_for and then uploaded.
        self._surface = np.empty_like(self._triangles)
        self._surface_counts = np.zeros(len(self._groups), dtype=np.int64)
        self._quads_on = np.empty_like(self._quads)
        self._quad_counts = np.zeros(len(self._names), dtype=np.int64)
        # The outline quads, rewritten each frame, have a buffer of their own.
        self.ibos = {
            SURFACE: ctx.buffer(indices.tobytes(), dynamic=True),
            OUTLINE: ctx.buffer(reserve=self._quads.nbytes, dynamic=True),
        }
        # Compiled (or loaded from numba's cache) now, not in the middle of the first frame.
        self.update_for(np.tile(np.eye(4), (N_BONES, 1, 1)), np.array([0.0, 0.0, 10.0]))

    def update_for(self, bones: np.ndarray, eye: np.ndarray) -> None:
        """Upload the triangles that may face `eye` (the camera's position in the posed head frame) under
        `bones`, and the outline quads: update(facing.distances(bones, eye)), compiled."""
        static_frame_indices(
            np.ascontiguousarray(bones, dtype=np.float64),
            np.ascontiguousarray(eye, dtype=np.float64),
            *self._facing.compiled_inputs(),
            self.EDGE_ON_SLACK,
            self._triangles,
            self._group_starts,
            self._t0,
            self._t1,
            self._quads,
            self._starts,
            self._surface,
            self._surface_counts,
            self._quads_on,
            self._quad_counts,
            self._front,
        )
        self._upload()

    def update(self, distances: np.ndarray) -> None:
        """Upload the triangles that may face the camera and the outline quads of the edges between a
        triangle facing it and one not, from the eye's signed distance to each triangle's plane
        (RigidFacing.distances)."""
        maybe = distances > -self.EDGE_ON_SLACK
        self._surface_counts[:] = np.add.reduceat(maybe.view(np.uint8), self._group_starts, dtype=np.intp)
        rows = np.dtype((np.void, self._triangles.itemsize * 3))
        kept = int(self._surface_counts.sum())
        np.compress(maybe, self._triangles.view(rows).reshape(-1), out=self._surface[:kept].view(rows).reshape(-1))
        f = self._front
        np.greater(distances, 0.0, out=f[:-1])
        on = f[self._t0] != f[self._t1]
        self._quad_counts[:] = np.add.reduceat(on.view(np.uint8), self._starts, dtype=np.intp)
        self._quads_on[: int(self._quad_counts.sum())] = self._quads[on]
        self._upload()

    def _upload(self) -> None:
        self._upload_kind(SURFACE, self._groups, self._surface_counts, self._surface)
        self._upload_kind(OUTLINE, self._names, self._quad_counts, self._quads_on)

    def _upload_kind(self, kind: str, names: list[str], counts: np.ndarray, rows: np.ndarray) -> None:
        """Name each group's run of the selected rows (triangles or quads) and upload them."""
        per_row = rows.shape[1]  # indices per row: 3 for a triangle, 6 for a quad
        offset = 0
        for name, count in zip(names, counts.tolist(), strict=True):
            self.ranges[kind, name] = (offset, per_row * count)
            offset += per_row * count
        if offset:
            self.ibos[kind].write(rows[: offset // per_row])


class HullIndices:
    """A mesh whose index buffer never changes: every triangle for the surface pass (the GPU culls the
    back faces), and for the outline the outlined groups' triangles on the EXTRUDED copies of their
    vertices, an inverted hull."""

    def __init__(
        self,
        ctx: moderngl.Context,
        indices: np.ndarray,
        ranges: dict[str, tuple[int, int]],
        n_vertices: int,
        outlined: tuple[str, ...],
    ) -> None:
        indices = np.ascontiguousarray(indices, dtype=np.uint32)
        self.ranges: dict[tuple[str, str], tuple[int, int]] = {(SURFACE, name): r for name, r in ranges.items()}
        parts, offset = [indices], indices.size
        for name in outlined:
            first, count = ranges[name]
            parts.append(indices[first : first + count] + np.uint32(n_vertices))
            self.ranges[OUTLINE, name] = (offset, count)
            offset += count
        ibo = ctx.buffer(np.concatenate(parts).tobytes())
        self.ibos = {SURFACE: ibo, OUTLINE: ibo}


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


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
