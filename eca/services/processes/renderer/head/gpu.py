"""An avatar uploaded once: per primitive its vertices, indices, morph-target deltas and programs; per material
its texture. Nothing here changes per frame; the drawer (drawer.py) writes uniforms, deforms and draws.

Per primitive: `base` holds rest positions and normals, `uvs` the texture coordinates, `skin` the joints and
weights. A primitive that is morphed or skinned is deformed each frame (shaders.DEFORM, transform feedback) from
`base` (and `skin`) into `deformed`, which its drawing reads in place of `base`. Morph deltas lie in one RGBA32F
texture per primitive, only of the targets that move it (shaders.py says how: one texel per target and vertex,
the normal's delta packed into the alpha channel's bits, so a target costs one fetch per vertex). Base colour
textures are plain RGBA8 with mipmaps: the drawer multiplies their stored (encoded) colour by encoded light
(shaders.py says why that is gamma-correct).
"""

from __future__ import annotations

from dataclasses import dataclass

import moderngl
import numpy as np

from eca.services.processes.avatar.model import AlphaMode, Avatar, Material, Primitive
from eca.services.processes.renderer.head.lighting import is_glossy, material_uniforms
from eca.services.processes.renderer.head.shaders import deform_source, draw_sources

DELTA_SHIFT = 11
DELTA_WIDTH = 1 << DELTA_SHIFT  # texels per row of a morph texture (llvmpipe allows 16384)
NORMAL_LEVELS = 511  # a packed normal delta's steps across its range (9 bits)
MAX_MORPHS_PER_DRAW = 256  # (target, weight) pairs one frame passes a primitive at most: the uniform array
JOINTS_BINDING = 0  # the uniform-block binding point of the skin palette


@dataclass(eq=False)
class GpuPrimitive:
    """One primitive on the GPU, with what the drawer needs to deform and draw it."""

    index: int  # in Avatar.primitives
    material: Material
    program: moderngl.Program  # draws it
    vao: moderngl.VertexArray  # draws it (from `deformed` when deformed, else from the rest vertices)
    deform: moderngl.Program | None  # morphs and skins it, once per vertex (None: rigid and unmorphed)
    deform_vao: moderngl.VertexArray | None
    deformed: moderngl.Buffer | None  # the deformed vertices (model frame if skinned, else the node's)
    buffers: tuple[moderngl.Buffer, ...]
    deltas: moderngl.Texture | None
    texture: moderngl.Texture | None
    n_targets: int  # the targets it has that move something: uploaded, in `targets` order
    targets: np.ndarray  # their indices among the primitive's targets
    normal_scale: float  # the packed normal deltas' range (0: none)
    n_vertices: int
    skinned: bool
    node: int
    centre: np.ndarray  # the rest pose's centre of its vertices (model frame if skinned, else the node's)
    extent: float  # the diagonal of its vertices' bounding box: how much it may hide
    joints: frozenset[int]  # the joints its skin follows (empty when rigid)
    nbytes: int  # GPU memory it holds (vertices, indices, deltas, the deformed copy)

    @property
    def blended(self) -> bool:
        return self.material.alpha_mode is AlphaMode.BLEND


def _f32(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float32)


def moving_targets(prim: Primitive) -> np.ndarray:
    """The indices of the primitive's targets that move something (a sparse target of a glTF mesh is often all
    zeros on most of its primitives: a teeth primitive carries the 52 face shapes, of which one moves it)."""
    return np.array([k for k, t in enumerate(prim.targets)
                     if np.any(t.positions) or (t.normals is not None and np.any(t.normals))], dtype=np.intp)


def pack_normals(normals: np.ndarray, scale: float) -> np.ndarray:
    """(N, 3) normal deltas within +-scale as float32s whose bits hold them: 9 bits each (bits 0-26), bit 30 set so
    the float is an ordinary number (never NaN, infinite or denormal, which a float path might change)."""
    q = np.clip(np.round((normals / scale * 0.5 + 0.5) * NORMAL_LEVELS), 0, NORMAL_LEVELS).astype(np.uint32)
    bits = (1 << 30) | q[:, 0] | (q[:, 1] << 9) | (q[:, 2] << 18)
    return bits.astype(np.uint32).view(np.float32)


def delta_texels(prim: Primitive, targets: np.ndarray) -> tuple[np.ndarray, float]:
    """The deltas of `targets` (indices into prim.targets) as RGBA float texels, target after target, vertex after
    vertex: the position's delta in RGB, the normal's packed into A (pack_normals), in rows of DELTA_WIDTH; and
    the normals' scale (0: no target has normal deltas)."""
    n = len(prim.positions)
    chosen = [prim.targets[int(k)] for k in targets]
    scale = max((float(np.abs(t.normals).max()) for t in chosen if t.normals is not None), default=0.0)
    texels = np.zeros((len(chosen), n, 4), dtype=np.float32)
    for k, target in enumerate(chosen):
        texels[k, :, :3] = target.positions
        normals = target.normals if target.normals is not None and scale > 0 else np.zeros((n, 3))
        texels[k, :, 3] = pack_normals(np.asarray(normals, dtype=np.float64), max(scale, 1e-6))
    flat = texels.reshape(-1, 4)
    rows = -(-len(flat) // DELTA_WIDTH)
    padded = np.zeros((rows * DELTA_WIDTH, 4), dtype=np.float32)
    padded[: len(flat)] = flat
    return padded.reshape(rows, DELTA_WIDTH, 4), scale


def fine_detail(rgba: np.ndarray, threshold: float = 0.75) -> bool:
    """Whether an image has detail finer than half its resolution: its mean difference (0-255, colour and alpha)
    from itself halved and doubled again exceeds `threshold`. Brow strands, lashes and an iris have; a skin's
    tints and shading have not, and are drawn without mipmaps (minified a few times, nothing of them aliases)."""
    x = np.asarray(rgba, dtype=np.float32)
    h, w = x.shape[0] // 2 * 2, x.shape[1] // 2 * 2
    if h == 0 or w == 0:
        return False
    x = x[:h, :w]
    half = x.reshape(h // 2, 2, w // 2, 2, -1).mean(axis=(1, 3))
    return float(np.abs(x - np.repeat(np.repeat(half, 2, axis=0), 2, axis=1)).mean(axis=(0, 1)).max()) > threshold


def _skin_joints(prim: Primitive) -> frozenset[int]:
    if prim.joints is None or prim.weights is None:
        return frozenset()
    used = np.asarray(prim.joints)[np.asarray(prim.weights) > 0.0]
    return frozenset(int(j) for j in np.unique(used))


class AvatarGpu:
    """The avatar's GPU objects; see the module docstring. `release()` frees them."""

    def __init__(self, ctx: moderngl.Context, avatar: Avatar) -> None:
        self.ctx = ctx
        self.avatar = avatar
        n_joints = len(avatar.skeleton.names)
        self.n_joints = n_joints
        self.joints_ubo = ctx.buffer(reserve=max(1, n_joints) * 64, dynamic=True)
        self._programs: dict[tuple[object, ...], moderngl.Program] = {}
        self._textures: dict[int, moderngl.Texture] = {}
        self.primitives: list[GpuPrimitive] = []
        try:
            for i, prim in enumerate(avatar.primitives):
                self.primitives.append(self._upload(i, prim))
        except Exception:
            self.release()
            raise

    def _texture(self, material_index: int) -> moderngl.Texture | None:
        material = self.avatar.materials[material_index]
        if material.texture is None:
            return None
        if material_index not in self._textures:
            rgba = np.ascontiguousarray(material.texture.rgba, dtype=np.uint8)
            height, width = rgba.shape[:2]
            # glTF's uv (0, 0) is the image's top-left texel; GL's t = 0 is the first row uploaded: the top row.
            tex = self.ctx.texture((width, height), 4, rgba.tobytes())
            if fine_detail(rgba):
                # Bilinear from the nearest mipmap, without anisotropy: on llvmpipe a trilinear fetch costs a
                # face's skin a fifth more, and an anisotropic one more than the rest of the pixel; on a head seen
                # from the front, neither shows.
                tex.build_mipmaps()
                tex.filter = (moderngl.LINEAR_MIPMAP_NEAREST, moderngl.LINEAR)
            else:
                # Smooth (a skin's tints and shading): its mipmaps would look like it, and cost a level of detail
                # per pixel to choose.
                tex.filter = (moderngl.LINEAR, moderngl.LINEAR)
            self._textures[material_index] = tex
        return self._textures[material_index]

    def _program(self, key: tuple[object, ...], vertex: str, fragment: str | None = None,
                 varyings: tuple[str, ...] = ()) -> moderngl.Program:
        if key not in self._programs:
            prog = self.ctx.program(vertex_shader=vertex, fragment_shader=fragment, varyings=varyings)
            if "Joints" in prog:
                prog["Joints"].binding = JOINTS_BINDING
            self._programs[key] = prog
        return self._programs[key]

    def _upload(self, index: int, prim: Primitive) -> GpuPrimitive:
        ctx = self.ctx
        material = self.avatar.materials[prim.material]
        n = len(prim.positions)
        made: list[moderngl.Buffer] = []
        base = ctx.buffer(np.concatenate([_f32(prim.positions), _f32(prim.normals)], axis=1).tobytes())
        uvs = ctx.buffer(_f32(prim.uvs if prim.uvs is not None else np.zeros((n, 2))).tobytes())
        ibo = ctx.buffer(np.ascontiguousarray(prim.indices, dtype=np.uint32).tobytes())
        made += [base, uvs, ibo]
        skinned = prim.joints is not None and prim.weights is not None
        targets = moving_targets(prim)
        n_targets = len(targets)
        normal_scale = 0.0
        deltas: moderngl.Texture | None = None
        deform: moderngl.Program | None = None
        deform_vao: moderngl.VertexArray | None = None
        deformed: moderngl.Buffer | None = None
        nbytes = base.size + uvs.size + ibo.size
        if skinned or n_targets:
            if n_targets:
                texels, normal_scale = delta_texels(prim, targets)
                deltas = ctx.texture((texels.shape[1], texels.shape[0]), 4, texels.tobytes(), dtype="f4")
                deltas.filter = (moderngl.NEAREST, moderngl.NEAREST)
                deltas.repeat_x = deltas.repeat_y = False
                nbytes += texels.nbytes
            with_normals = normal_scale > 0
            morphs = min(n_targets, MAX_MORPHS_PER_DRAW)
            deform = self._program(("deform", morphs, with_normals, skinned),
                                   deform_source(morphs, with_normals, skinned, self.n_joints, DELTA_SHIFT),
                                   varyings=("out_pos", "out_normal"))
            sources = [(base, "3f 3f", "in_pos", "in_normal")]
            if prim.joints is not None and prim.weights is not None:
                w = np.asarray(prim.weights, dtype=np.float64)
                w = w / np.maximum(w.sum(axis=1, keepdims=True), 1e-12)  # glTF asks for sums of 1; files round
                skin = ctx.buffer(np.concatenate([_f32(prim.joints), _f32(w)], axis=1).tobytes())
                made.append(skin)
                nbytes += skin.size
                sources.append((skin, "4f 4f", "in_joints", "in_weights"))
            deform_vao = ctx.vertex_array(deform, sources, skip_errors=True)
            deformed = ctx.buffer(reserve=n * 24)
            made.append(deformed)
            nbytes += deformed.size
        texture = self._texture(prim.material)
        flags = (texture is not None, material.alpha_mode is AlphaMode.MASK, material.alpha_mode is AlphaMode.BLEND,
                 material.toon, material.double_sided,
                 is_glossy(material))
        program = self._program(("draw", *flags), *draw_sources(*flags))
        vao = ctx.vertex_array(
            program,
            [(deformed if deformed is not None else base, "3f 3f", "in_pos", "in_normal"), (uvs, "2f", "in_uv")],
            index_buffer=ibo,
            index_element_size=4,
            skip_errors=True,
        )
        return GpuPrimitive(
            index=index,
            material=material,
            program=program,
            vao=vao,
            deform=deform,
            deform_vao=deform_vao,
            deformed=deformed,
            buffers=tuple(made),
            deltas=deltas,
            texture=texture,
            n_targets=n_targets,
            targets=targets,
            normal_scale=normal_scale,
            n_vertices=n,
            skinned=skinned,
            node=prim.node,
            centre=np.asarray(prim.positions, dtype=np.float64).mean(axis=0),
            extent=float(np.linalg.norm(np.ptp(np.asarray(prim.positions, dtype=np.float64), axis=0))),
            joints=_skin_joints(prim),
            nbytes=nbytes,
        )

    def material_uniforms(self, gp: GpuPrimitive) -> dict[str, object]:
        return material_uniforms(gp.material)

    @property
    def programs(self) -> tuple[moderngl.Program, ...]:
        return tuple(self._programs.values())

    @property
    def draw_programs(self) -> tuple[moderngl.Program, ...]:
        return tuple(p for k, p in self._programs.items() if k[0] == "draw")

    @property
    def nbytes(self) -> int:
        """GPU memory the avatar holds: vertices, indices, morph deltas, deformed copies, textures (with their
        mipmaps), the skin palette."""
        textures = sum(int(t.width * t.height * 4 * (4 / 3 if t.filter[0] != moderngl.LINEAR else 1))
                       for t in self._textures.values())
        return sum(p.nbytes for p in self.primitives) + textures + self.joints_ubo.size

    def release(self) -> None:
        for gp in self.primitives:
            gp.vao.release()
            if gp.deform_vao is not None:
                gp.deform_vao.release()
            for b in gp.buffers:
                b.release()
            if gp.deltas is not None:
                gp.deltas.release()
        for tex in self._textures.values():
            tex.release()
        for prog in self._programs.values():
            prog.release()
        self.joints_ubo.release()
        self.primitives.clear()
        self._textures.clear()
        self._programs.clear()
