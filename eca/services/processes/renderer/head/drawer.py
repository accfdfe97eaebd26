"""`HeadDrawer`: a 3D avatar (a glTF/VRM head, or any `Avatar`) as a `FaceDrawer` (renderer/drawer.py).

Per frame: the composed face is retargeted onto the rig (eca.agent.rig.Retargeter: ARKit weights, visemes, VRM
presets, head and eye angles); the rig frame becomes the avatar's pose (eca/services/processes/avatar/drive.py:
morph weights per primitive, local transforms of the neck, head, jaw and eye joints); the joints are posed
(skeleton.py); every morphed or skinned primitive is deformed once per vertex on the GPU (shaders.DEFORM); then
the opaque and alpha-masked primitives are drawn, and the blended ones after them, back to front, without writing
depth; lit for a face (lighting.py), framed as the 2D face's views are (camera.py).

Multisampling: with `samples` > 1 the picture is drawn into a multisampled framebuffer of the target's viewport
size, resolved, and copied into the target's viewport (so a stage's side-by-side panels work as with the 2D
face). llvmpipe's 4x multisampling costs more than the rest of a 640x480 frame (clearing and resolving four
samples a pixel on the CPU: 7-8 ms a frame measured, against about 5 for the whole head), so by default it is
on (4x) where GL runs on a GPU and off on software GL; stills may ask for it.
"""

from __future__ import annotations

from pathlib import Path

import moderngl
import numpy as np

from eca.agent.face.composed import ComposedFace
from eca.agent.rig import Retargeter, RigFrame
from eca.services.processes.avatar.drive import AvatarDriver, AvatarPose
from eca.services.processes.avatar.loader import DEFAULT_HEAD, load_avatar
from eca.services.processes.avatar.model import AlphaMode, Avatar
from eca.services.processes.renderer.common import RenderToggles
from eca.services.processes.renderer.config import RenderConfig, load_render_config
from eca.services.processes.renderer.context import check_size, create_offscreen_target
from eca.services.processes.renderer.head import order, overlay
from eca.services.processes.renderer.head.camera import HeadCamera, measure
from eca.services.processes.renderer.head.gpu import JOINTS_BINDING, AvatarGpu, GpuPrimitive
from eca.services.processes.renderer.head.lighting import Lights
from eca.services.processes.renderer.head.shaders import (
    COMPOSITE_FRAGMENT,
    COMPOSITE_VERTEX,
    OVERLAY_FRAGMENT,
    OVERLAY_VERTEX,
    WIRE_FRAGMENT,
    WIRE_VERTEX,
)
from eca.services.processes.renderer.head.skeleton import Posed

TEX_UNIT, DELTA_UNIT, PICTURE_UNIT = 0, 1, 2
MAX_TRAIL = 600  # points of a gaze trail drawn at most (the most recent)
_IDENTITY = np.eye(4, dtype=np.float32).tobytes()


def is_software(ctx: moderngl.Context) -> bool:
    """Whether the context draws on the CPU (Mesa's llvmpipe, softpipe, swrast)."""
    renderer = str(ctx.info.get("GL_RENDERER", "")).lower()
    return any(name in renderer for name in ("llvmpipe", "softpipe", "swrast", "software"))


class _Multisampled:
    """A multisampled colour + depth framebuffer of one size and the texture it resolves into."""

    def __init__(self, ctx: moderngl.Context, size: tuple[int, int], samples: int) -> None:
        self.size = size
        self.color = ctx.renderbuffer(size, 4, samples=samples)
        self.depth = ctx.depth_renderbuffer(size, samples=samples)
        self.fbo = ctx.framebuffer(color_attachments=[self.color], depth_attachment=self.depth)
        self.picture = ctx.texture(size, 4)
        self.picture.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self.resolved = ctx.framebuffer(color_attachments=[self.picture])

    def release(self) -> None:
        for obj in (self.fbo, self.resolved, self.color, self.depth, self.picture):
            obj.release()


class HeadDrawer:
    """Draws composed faces on a 3D avatar; see the module docstring. Of the window's toggles it honours those
    that mean something on any model: the wireframe, the pupils' marks and the gaze trail (the lids, brows and
    3D-surface toggles are the 2D face's parts and shading).

    avatar: an `Avatar`, or the path of a .glb/.gltf/.vrm file (avatar/loader.py loads it; AvatarError if it
    cannot be a face). samples: multisampling (None: 4 on a GPU, none on software GL; 0 or 1: none; at most
    what the context allows). config: the 2D face's render config, whose background and overlay colours and
    flexor units this drawer shares (so the two kinds sit side by side alike)."""

    def __init__(self, ctx: moderngl.Context, size: tuple[int, int], avatar: Avatar | str | Path, *,
                 samples: int | None = None, lights: Lights | None = None, config: RenderConfig | None = None,
                 retargeter: Retargeter | None = None) -> None:
        self.ctx = ctx
        self.size = check_size(size)
        self.avatar = avatar if isinstance(avatar, Avatar) else load_avatar(avatar)
        self.config = config or load_render_config()
        self.retargeter = retargeter or Retargeter.load(units=self.config.units)
        self.driver = AvatarDriver(self.avatar)
        self.posed = Posed(self.avatar.skeleton)
        self.camera = HeadCamera(measure(self.avatar, self.posed))
        self.eye_radius = self._eye_radius()
        self.lights = lights or Lights()
        if samples is None:
            samples = 0 if is_software(ctx) else 4
        self.samples = min(int(samples), ctx.max_samples) if samples > 1 else 0
        self.gpu = AvatarGpu(ctx, self.avatar)
        self._release: list[moderngl.Program | moderngl.VertexArray | moderngl.Buffer] = []
        try:
            self.target = create_offscreen_target(ctx, self.size)
            self.composite = ctx.program(vertex_shader=COMPOSITE_VERTEX, fragment_shader=COMPOSITE_FRAGMENT)
            self.composite["u_picture"].value = PICTURE_UNIT
            self.composite_vao = ctx.vertex_array(self.composite, [])
            self.overlay_prog = ctx.program(vertex_shader=OVERLAY_VERTEX, fragment_shader=OVERLAY_FRAGMENT)
            self.overlay_vbo = ctx.buffer(reserve=(2 * MAX_TRAIL + 4) * 6 * overlay.FLOATS * 4, dynamic=True)
            self.overlay_vao = ctx.vertex_array(self.overlay_prog, [(self.overlay_vbo, "2f 3f", "in_pos", "in_color")])
            self._release += [self.composite_vao, self.composite, self.overlay_vao, self.overlay_prog,
                              self.overlay_vbo]
        except Exception:
            self.gpu.release()
            raise
        self._multisampled: _Multisampled | None = None
        constants = self.lights.uniforms()
        for prog in self.gpu.programs:
            for name, value in (*constants.items(), ("u_tex", TEX_UNIT), ("u_deltas", DELTA_UNIT)):
                if name in prog:
                    prog[name].value = value
        # Per morphed primitive: its (target, weight) pairs, written whole each frame (the uniform's length).
        self._morphs = {gp.index: np.zeros((gp.deform["u_morph"].array_length, 2), dtype=np.float32)
                        for gp in self.gpu.primitives if gp.n_targets and gp.deform is not None}
        # Each primitive's material uniforms that its program has (asking a program for a name walks its members).
        self._materials = {gp.index: {k: v for k, v in self.gpu.material_uniforms(gp).items() if k in gp.program}
                           for gp in self.gpu.primitives}
        self._program_material: dict[int, int] = {}  # program glo -> the primitive whose material it holds
        self._deformed: set[int] = set()  # primitives whose deformed buffer holds a pose
        self._wire: tuple[moderngl.Program, dict[int, moderngl.VertexArray]] | None = None
        # Opaque and masked primitives, what lies in front first (order.py): what they hide then fails the depth
        # test before it is shaded, which is most of a software GL's cost.
        self._opaque = [gp for gp in self.gpu.primitives if not gp.blended]
        self._opaque = [self._opaque[k] for k in order.front_to_back(self._rest_depths(),
                                                                     [gp.extent for gp in self._opaque])]
        self.last_frame: RigFrame | None = None
        self.last_pose: AvatarPose | None = None
        self._view_m = self._view_proj = np.eye(4)

    @classmethod
    def default(cls, ctx: moderngl.Context, size: tuple[int, int]) -> HeadDrawer:
        """The default head (eca/assets/default_head.glb)."""
        if not DEFAULT_HEAD.exists():
            raise FileNotFoundError(f"the default head {DEFAULT_HEAD} is missing (eca/services/tools/head_bake/ "
                                    "bakes it)")
        return cls(ctx, size, DEFAULT_HEAD)

    @property
    def fbo(self) -> moderngl.Framebuffer:
        """The drawer's own offscreen target, drawn into when draw() is given no target."""
        return self.target

    # -- per frame -------------------------------------------------------------------------------------------

    def draw(self, face: ComposedFace, target: moderngl.Framebuffer | None = None, *, view: str = "full",
             toggles: RenderToggles | None = None, trail: np.ndarray | None = None) -> moderngl.Framebuffer:
        """Draw `face` into `target`'s viewport (None: the drawer's own target); the framebuffer drawn into."""
        frame = self.retargeter.retarget(face)
        return self.draw_frame(frame, target, view=view, toggles=toggles, trail=trail)

    def draw_frame(self, frame: RigFrame, target: moderngl.Framebuffer | None = None, *, view: str = "full",
                   toggles: RenderToggles | None = None, trail: np.ndarray | None = None) -> moderngl.Framebuffer:
        """Draw a rig frame (what draw() does after retargeting)."""
        self.last_frame = frame
        return self.draw_pose(self.driver.drive(frame), target, view=view, toggles=toggles, trail=trail)

    def draw_pose(self, pose: AvatarPose, target: moderngl.Framebuffer | None = None, *, view: str = "full",
                  toggles: RenderToggles | None = None, trail: np.ndarray | None = None) -> moderngl.Framebuffer:
        """Draw the avatar in `pose`."""
        toggles = toggles or RenderToggles()
        fbo = target if target is not None else self.target
        ctx = self.ctx
        self.last_pose = pose
        globals_ = self.posed.pose(pose.local)
        self.gpu.joints_ubo.write(np.ascontiguousarray(self.posed.palette.transpose(0, 2, 1)))
        self.gpu.joints_ubo.bind_to_uniform_block(JOINTS_BINDING)

        x0, y0, width, height = fbo.viewport
        view_m, proj = self.camera.matrices(view, width / max(height, 1), globals_)
        self._view_m, self._view_proj = view_m, proj @ view_m
        view_bytes = view_m.T.astype(np.float32).tobytes()
        proj_bytes = proj.T.astype(np.float32).tobytes()
        for prog in self.gpu.draw_programs:
            prog["u_proj"].write(proj_bytes)

        bg = self.config.colors["background"]
        ms = self._canvas((width, height)) if self.samples else None
        if ms is not None:
            ms.fbo.use()
            ms.fbo.viewport = (0, 0, width, height)
            ms.fbo.clear(bg[0], bg[1], bg[2], 1.0, depth=1.0)
        else:
            fbo.use()
            fbo.clear(bg[0], bg[1], bg[2], 1.0, depth=1.0)

        # Morph and skin every deformed primitive once per vertex (transform feedback draws no pixels, but GL
        # wants a framebuffer bound, which it now is), unless neither its weights nor its joints changed.
        changed = self.posed.changed
        for gp in self.gpu.primitives:
            if gp.deform is not None:
                self._deform(gp, pose, not changed.isdisjoint(gp.joints))
        ctx.enable(moderngl.DEPTH_TEST)
        for gp in self._opaque:
            self._draw_primitive(gp, globals_)
        blended = [gp for gp in self.gpu.primitives if gp.blended]
        if blended:
            # Back to front by each primitive's centre, in front of what is opaque, without writing depth.
            depth = [self._view_depth(gp, globals_, view_m) for gp in blended]
            ctx.enable(moderngl.BLEND)
            ctx.blend_func = moderngl.ONE, moderngl.ONE_MINUS_SRC_ALPHA  # premultiplied (shaders.FRAGMENT)
            target_now = ms.fbo if ms is not None else fbo
            target_now.depth_mask = False
            for _, gp in sorted(zip(depth, blended, strict=True), key=lambda item: item[0]):
                self._draw_primitive(gp, globals_)
            target_now.depth_mask = True
            ctx.disable(moderngl.BLEND)
        if toggles.wireframe:
            self._wireframe(globals_, view_bytes, proj_bytes)
        ctx.disable(moderngl.DEPTH_TEST | moderngl.CULL_FACE)

        if ms is not None:
            ctx.copy_framebuffer(ms.resolved, ms.fbo)
            fbo.use()
            fbo.viewport = (x0, y0, width, height)
            ms.picture.use(PICTURE_UNIT)
            self.composite["u_origin"].value = (x0, y0)
            self.composite_vao.render(moderngl.TRIANGLES, vertices=3)
        self._overlay(globals_, toggles, trail, height)
        return fbo

    def _rest_depths(self) -> np.ndarray:
        """(P, H, W) each opaque primitive's depth drawn alone at rest in the full view (order.SIZE; 1.0 where it
        is not), for order.front_to_back."""
        ctx = self.ctx
        depth = ctx.depth_texture(order.SIZE)
        fbo = ctx.framebuffer(depth_attachment=depth)
        prog = ctx.program(vertex_shader=WIRE_VERTEX, fragment_shader=WIRE_FRAGMENT)
        try:
            fbo.use()
            rest = AvatarPose(tuple(np.zeros(len(p.targets), dtype=np.float32) for p in self.avatar.primitives),
                              {}, {}, np.zeros(0, dtype=np.float32))
            globals_ = self.posed.pose({})
            self.gpu.joints_ubo.write(np.ascontiguousarray(self.posed.palette.transpose(0, 2, 1)))
            self.gpu.joints_ubo.bind_to_uniform_block(JOINTS_BINDING)
            for gp in self._opaque:
                if gp.deform is not None:
                    self._deform(gp, rest, True)
            view_m, proj = self.camera.matrices("full", order.SIZE[0] / order.SIZE[1])
            prog["u_view"].write(view_m.T.astype(np.float32).tobytes())
            prog["u_proj"].write(proj.T.astype(np.float32).tobytes())
            prog["u_depth_bias"].value = 0.0
            ctx.enable(moderngl.DEPTH_TEST)
            ctx.cull_face = "back"
            pictures = []
            for gp in self._opaque:
                fbo.clear(depth=1.0)
                if gp.material.double_sided:  # culled as the frame culls it: only what may be seen counts
                    ctx.disable(moderngl.CULL_FACE)
                else:
                    ctx.enable(moderngl.CULL_FACE)
                rigid = not gp.skinned and gp.node >= 0
                prog["u_model"].write(globals_[gp.node].T.astype(np.float32).tobytes() if rigid else _IDENTITY)
                source = gp.deformed if gp.deformed is not None else gp.buffers[0]
                vao = ctx.vertex_array(prog, [(source, "3f 12x", "in_pos")], index_buffer=gp.vao.index_buffer,
                                       index_element_size=4)
                vao.render(moderngl.TRIANGLES)
                vao.release()
                pictures.append(np.frombuffer(depth.read(), dtype=np.float32).reshape(order.SIZE[1], order.SIZE[0]))
            ctx.disable(moderngl.DEPTH_TEST | moderngl.CULL_FACE)
            return np.stack(pictures) if pictures else np.zeros((0, order.SIZE[1], order.SIZE[0]))
        finally:
            for obj in (prog, fbo, depth):
                obj.release()

    def _wireframe(self, globals_: np.ndarray, view_bytes: bytes, proj_bytes: bytes) -> None:
        """The opaque primitives' triangle edges over the surface (the 2D face's wireframe toggle); the program and
        its vertex arrays are made the first time it is asked for."""
        if self._wire is None:
            prog = self.ctx.program(vertex_shader=WIRE_VERTEX, fragment_shader=WIRE_FRAGMENT)
            prog["u_depth_bias"].value = 0.0005
            vaos = {}
            for gp in self._opaque:
                source = gp.deformed if gp.deformed is not None else gp.buffers[0]
                vaos[gp.index] = self.ctx.vertex_array(prog, [(source, "3f 12x", "in_pos")],
                                                       index_buffer=gp.vao.index_buffer, index_element_size=4)
            self._release += [*vaos.values(), prog]
            self._wire = (prog, vaos)
        prog, vaos = self._wire
        prog["u_view"].write(view_bytes)
        prog["u_proj"].write(proj_bytes)
        prog["u_color"].value = self.config.colors["wireframe"]
        self.ctx.disable(moderngl.CULL_FACE)
        self.ctx.wireframe = True
        for gp in self._opaque:
            rigid = not gp.skinned and gp.node >= 0
            prog["u_model"].write(globals_[gp.node].T.astype(np.float32).tobytes() if rigid else _IDENTITY)
            vaos[gp.index].render(moderngl.TRIANGLES)
        self.ctx.wireframe = False

    def _canvas(self, size: tuple[int, int]) -> _Multisampled:
        if self._multisampled is None or self._multisampled.size != size:
            if self._multisampled is not None:
                self._multisampled.release()
            self._multisampled = _Multisampled(self.ctx, size, self.samples)
        return self._multisampled

    def _view_depth(self, gp: GpuPrimitive, globals_: np.ndarray, view_m: np.ndarray) -> float:
        """How far in front of the camera a primitive's centre is (more negative: further)."""
        c = np.append(gp.centre, 1.0)
        if not gp.skinned and gp.node >= 0:
            c = globals_[gp.node] @ c
        return float((view_m @ c)[2])

    def _deform(self, gp: GpuPrimitive, pose: AvatarPose, joints_moved: bool) -> None:
        prog = gp.deform
        assert prog is not None and gp.deform_vao is not None and gp.deformed is not None
        pairs = self._morphs.get(gp.index)
        if pairs is not None:
            weights = pose.weights[gp.index][gp.targets]  # the targets that move it, in its texture's order
            active = np.flatnonzero(weights > 1e-4)
            if len(active) > len(pairs):  # more shapes on than the program takes: the strongest
                active = active[np.argsort(weights[active])[::-1][: len(pairs)]]
            new = np.zeros_like(pairs)
            new[: len(active), 0] = active
            new[: len(active), 1] = weights[active]
            if not joints_moved and gp.index in self._deformed and np.array_equal(new, pairs):
                return
            pairs[:] = new
            prog["u_morph"].write(pairs)
            prog["u_active"].value = len(active)
            prog["u_vertices"].value = gp.n_vertices
            if gp.normal_scale:
                prog["u_normal_scale"].value = gp.normal_scale
            gp.deltas.use(DELTA_UNIT)  # type: ignore[union-attr]
        elif not joints_moved and gp.index in self._deformed:
            return
        gp.deform_vao.transform(gp.deformed, moderngl.POINTS, vertices=gp.n_vertices)
        self._deformed.add(gp.index)

    def _draw_primitive(self, gp: GpuPrimitive, globals_: np.ndarray) -> None:
        prog = gp.program
        if self._program_material.get(prog.glo) != gp.index:
            for name, value in self._materials[gp.index].items():
                prog[name].value = value
            self._program_material[prog.glo] = gp.index
        rigid = not gp.skinned and gp.node >= 0
        modelview = self._view_m @ globals_[gp.node] if rigid else self._view_m
        prog["u_modelview"].write(modelview.T.astype(np.float32).tobytes())
        if gp.texture is not None:
            gp.texture.use(TEX_UNIT)
        if gp.material.double_sided:
            self.ctx.disable(moderngl.CULL_FACE)
        else:
            self.ctx.enable(moderngl.CULL_FACE)
            self.ctx.cull_face = "back"
        gp.vao.render(moderngl.TRIANGLES)

    # -- what the tests and overlays ask -----------------------------------------------------------------------

    def _eye_radius(self) -> float:
        """The eyeballs' radius: how far the furthest opaque vertex moving with an eye joint is from it (a
        see-through cornea over it left out; 12 mm when the eyes have no joints or no geometry of their own)."""
        eyes = [j for j in self.camera.measure.eye_joints if j >= 0]
        radius = 0.0
        for prim in self.avatar.primitives:
            if self.avatar.materials[prim.material].alpha_mode is AlphaMode.BLEND:
                continue
            positions = np.asarray(prim.positions, dtype=np.float64)
            if prim.joints is None or prim.weights is None:
                if prim.node in eyes:
                    radius = max(radius, float(np.linalg.norm(positions, axis=1).max()))
                continue
            for j in eyes:  # skinned eyes (a VRM's body mesh): the vertices mostly on the eye joint, at rest
                on = (np.asarray(prim.weights) * (np.asarray(prim.joints) == j)).sum(axis=1) >= 0.5
                if on.any():
                    rest = (self.posed.rest_global[j] @ self.posed.inverse_bind[j])
                    p = positions[on] @ rest[:3, :3].T + rest[:3, 3]
                    radius = max(radius, float(np.linalg.norm(p - self.posed.rest_global[j, :3, 3], axis=1).max()))
        return radius or 0.012

    def pupils(self) -> np.ndarray:
        """(2, 3) model-frame centres of the pupils (left eye first) in the last drawn pose."""
        m = self.camera.measure
        g = self.posed.globals
        out = []
        for joint in m.eye_joints:
            if joint < 0:
                return m.eyes.copy()
            turn = g[joint, :3, :3] @ np.linalg.inv(self.posed.rest_global[joint, :3, :3])
            out.append(g[joint, :3, 3] + turn @ np.array([0.0, 0.0, self.eye_radius]))
        return np.stack(out)

    def to_pixels(self, points: np.ndarray, size: tuple[int, int] | None = None) -> np.ndarray:
        """Pixel coordinates (x right, y down, top-left origin) of model points (N, 3) in the last frame's
        picture of `size` (the drawer's size by default)."""
        width, height = size or self.size
        ndc = overlay.project(np.asarray(points, dtype=np.float64).reshape(-1, 3), self._view_proj)
        return np.stack([(ndc[:, 0] + 1) * 0.5 * width, (1 - ndc[:, 1]) * 0.5 * height], 1)

    def _overlay(self, globals_: np.ndarray, toggles: RenderToggles, trail: np.ndarray | None, height: int) -> None:
        want_trail = toggles.trajectory and trail is not None and len(trail) >= 2
        if not (want_trail or toggles.eye_centre) or any(j < 0 for j in self.camera.measure.eye_joints):
            return
        px = 2.0 / max(height, 1)
        aspect = self._view_proj[1, 1] / self._view_proj[0, 0]
        scale = height / overlay.REFERENCE_HEIGHT
        colors = self.config.colors
        pieces = []
        if want_trail:
            units = self.config.units
            rows = np.nan_to_num(np.asarray(trail, dtype=np.float64)[-MAX_TRAIL:])
            angles = rows * (units.look_x_deg, units.look_y_deg)
            head = self.camera.measure.head_joint
            turn = (globals_[head, :3, :3] @ self.camera.measure.head_rest_inverse[:3, :3]) if head >= 0 else np.eye(3)
            centres = np.stack([globals_[j, :3, 3] for j in self.camera.measure.eye_joints])
            for path in overlay.pupil_paths(centres, turn, self.eye_radius, angles):
                pieces.append(overlay.polyline(overlay.project(path, self._view_proj), max(1.0, 1.2 * scale) * px,
                                               aspect, colors["trajectory"]))
        if toggles.eye_centre:
            for p in overlay.project(self.pupils(), self._view_proj):
                pieces.append(overlay.cross(p, max(4.0, 7.0 * scale) * px, max(1.0, 1.3 * scale) * px, aspect,
                                            colors["eye_centre"]))
        data = np.ascontiguousarray(np.concatenate(pieces).astype(np.float32))
        self.overlay_vbo.write(data)
        self.overlay_vao.render(moderngl.TRIANGLES, vertices=len(data))

    def release(self) -> None:
        """Free every GL object this drawer made (the context stays the caller's)."""
        self.gpu.release()
        for obj in self._release:
            obj.release()
        self._release.clear()
        if self._multisampled is not None:
            self._multisampled.release()
            self._multisampled = None
        for attachment in (*self.target.color_attachments, self.target.depth_attachment):
            attachment.release()
        self.target.release()
