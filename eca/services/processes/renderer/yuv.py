"""The drawn face as yuv420p, converted on the GPU: what a video encoder takes, read back in one go.

Converting on the CPU (swscale from the RGB read-back) costs about as much as drawing the face, and
reading RGB moves twice the bytes that yuv420p does. Here the face is drawn into a colour texture and a
second pass writes the planes, in the layout av.VideoFrame.from_ndarray(format="yuv420p") takes: a
(height * 3 / 2, width) array of the Y plane, then the U and V planes, each packed two rows to a row.
Colours are ITU-R BT.601 in limited range (swscale's default, and what a browser assumes of VP8); each
chroma sample is the mean of its 2x2 block of pixels (one bilinear fetch at the block's centre).
"""

from __future__ import annotations

import moderngl
import numpy as np

from eca.services.processes.renderer.context import check_size

_VERTEX = """
#version 330
void main() {  // one triangle that covers the viewport
    vec2 corner = vec2(float((gl_VertexID & 1) << 2) - 1.0, float((gl_VertexID & 2) << 1) - 1.0);
    gl_Position = vec4(corner, 0.0, 1.0);
}
"""

# Two small programs rather than one that branches: software GL (llvmpipe) runs every branch.
_LUMA = """
#version 330
uniform sampler2D u_rgb;
out float luma;
const vec3 TO_Y = vec3(65.481, 128.553, 24.966) / 255.0;  // BT.601, limited range: Y in 16..235
void main() {  // the array's row 0 is its top, read back first; the texture's row 0 is the bottom
    ivec2 size = textureSize(u_rgb, 0);
    ivec2 at = ivec2(gl_FragCoord.xy);
    luma = 16.0 / 255.0 + dot(TO_Y, texelFetch(u_rgb, ivec2(at.x, size.y - 1 - at.y), 0).rgb);
}
"""

_CHROMA = """
#version 330
uniform sampler2D u_rgb;
uniform vec3 u_weights;  // the U or the V row of BT.601, limited range: 16..240
out float chroma;
void main() {  // the mean of the 2x2 block: one bilinear fetch at its centre
    vec2 size = vec2(textureSize(u_rgb, 0));
    vec2 at = vec2(2.0 * floor(gl_FragCoord.x) + 1.0, size.y - 2.0 * floor(gl_FragCoord.y) - 1.0);
    chroma = 128.0 / 255.0 + dot(u_weights, texture(u_rgb, at / size).rgb);
}
"""
_TO_U = (-37.797 / 255, -74.203 / 255, 112.0 / 255)
_TO_V = (112.0 / 255, -93.786 / 255, -18.214 / 255)


class YuvTarget:
    """A framebuffer of `size` to draw the face into (`fbo`), and its picture as yuv420p (`read`)."""

    def __init__(self, ctx: moderngl.Context, size: tuple[int, int]) -> None:
        width, height = check_size(size)
        if width % 2 or height % 2:
            raise ValueError(f"a yuv420p picture has an even width and height, got {width}x{height}")
        self.ctx = ctx
        self.size = (width, height)
        self.color = ctx.texture((width, height), 4)
        self.color.filter = (moderngl.LINEAR, moderngl.LINEAR)  # a chroma fetch is the mean of 2x2 pixels
        self.color.repeat_x = self.color.repeat_y = False
        self._depth = ctx.depth_renderbuffer((width, height))
        self.fbo = ctx.framebuffer(color_attachments=[self.color], depth_attachment=self._depth)
        self._luma = _Plane(ctx, (width, height), _LUMA)
        self._u = _Plane(ctx, (width // 2, height // 2), _CHROMA, _TO_U)
        self._v = _Plane(ctx, (width // 2, height // 2), _CHROMA, _TO_V)
        self._out = np.empty((height * 3 // 2, width), dtype=np.uint8)

    def read(self) -> np.ndarray:
        """What was drawn into `fbo`, as a fresh (height * 3 / 2, width) yuv420p array."""
        self.ctx.disable(moderngl.DEPTH_TEST | moderngl.CULL_FACE | moderngl.BLEND)
        self.color.use(location=0)
        flat = self._out.reshape(-1)
        y_end = self.size[0] * self.size[1]
        c_end = y_end + y_end // 4
        self._luma.convert_into(flat[:y_end])
        self._u.convert_into(flat[y_end:c_end])
        self._v.convert_into(flat[c_end:])
        return self._out.copy()

    def release(self) -> None:
        for plane in (self._luma, self._u, self._v):
            plane.release()
        for obj in (self.fbo, self._depth, self.color):
            obj.release()


class _Plane:
    """One plane's pass: a one-channel target of `size` that `fragment` fills from the colour texture."""

    def __init__(self, ctx: moderngl.Context, size: tuple[int, int], fragment: str,
                 weights: tuple[float, float, float] | None = None) -> None:
        self.texture = ctx.texture(size, 1)
        self.fbo = ctx.framebuffer(color_attachments=[self.texture])
        self.program = ctx.program(vertex_shader=_VERTEX, fragment_shader=fragment)
        self.program["u_rgb"].value = 0
        if weights is not None:
            self.program["u_weights"].value = weights
        self.triangle = ctx.vertex_array(self.program, [])

    def convert_into(self, out: np.ndarray) -> None:
        self.fbo.use()
        self.triangle.render(moderngl.TRIANGLES, vertices=3)
        self.fbo.read_into(out, components=1, alignment=1)

    def release(self) -> None:
        for obj in (self.triangle, self.program, self.fbo, self.texture):
            obj.release()
