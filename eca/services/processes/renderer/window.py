"""The interactive window (glfw): the paper's interactive mode.

Keys that change what the agent does are published on the bus as ordinary commands (the same path an
external dialogue manager's commands take), never applied here; the face changes when the dialogue
service's new state comes back. Keys that change only how the face is drawn (view, toggles) act locally.

    1-9      emotion: natural, happy, surprised, arrogant, angry, half-angry, disappointed, annoyed,
             frightened                    +/-  intensity of the current emotion
    t        talking <-> listening         e    eye mode: the next of agent.vocabulary.EYE_MODES
    arrows   head turn / nod               0    head back to centre
    v        full face / upper face        b    eyebrows       c  eye cover (lids)
    w        wireframe                     s    3D surface     x  eye centre    r  saccade trajectory
    tab      next agent (several agents)   q, esc  close
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass

import glfw
import moderngl
import numpy as np

from eca.agent.face.emotions import PAPER_EMOTIONS
from eca.agent.gaze.params import default_eye_mode
from eca.agent.vocabulary import EYE_MODES
from eca.protocol.messages import Message, MoveHead, SetEmotion, SetEyes, SetRole
from eca.services.processes.renderer.display import display_available

EMOTION_KEYS: tuple[str, ...] = PAPER_EMOTIONS  # keys 1-9, in the paper's order
EYE_MODE_CYCLE: tuple[str, ...] = EYE_MODES
TOGGLE_KEYS: dict[str, str] = {
    "b": "eyebrows",
    "c": "eye_cover",
    "w": "wireframe",
    "s": "surface_3d",
    "x": "eye_centre",
    "r": "trajectory",
}
HELP_LINE = (
    "1-9 emotion  +/- intensity  t talk/listen  e eyes  arrows head  0 centre  v view  "
    "b brows  c lids  w wire  s 3D  x centre  r trail  tab agent  q quit"
)
INTENSITY_STEP = 0.1
TURN_STEP = 0.25
NOD_STEP = 0.2
HEAD_MOVE_S = 0.6


@dataclass(frozen=True)
class AgentStatus:
    """What a key needs to know of the agent it acts on (the renderer's current view of its state)."""

    agent: str
    emotion: str = "natural"
    intensity: float = 1.0
    role: str = "listening"
    eye_mode: str = dataclasses.field(default_factory=default_eye_mode)
    head: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class LocalAction:
    """A key that changes only the drawing: 'view', 'next_agent', 'close' or a toggle name."""

    name: str


def _key_names() -> dict[int, str]:
    names = {getattr(glfw, f"KEY_{d}"): d for d in "0123456789"}
    names.update({getattr(glfw, f"KEY_KP_{d}"): d for d in "0123456789"})
    names.update({getattr(glfw, f"KEY_{c.upper()}"): c for c in "tevbcwsxrq"})
    names.update(
        {
            glfw.KEY_EQUAL: "+",
            glfw.KEY_KP_ADD: "+",
            glfw.KEY_MINUS: "-",
            glfw.KEY_KP_SUBTRACT: "-",
            glfw.KEY_LEFT: "left",
            glfw.KEY_RIGHT: "right",
            glfw.KEY_UP: "up",
            glfw.KEY_DOWN: "down",
            glfw.KEY_TAB: "tab",
            glfw.KEY_ESCAPE: "q",
        }
    )
    return names


KEY_NAMES = _key_names()


def action_for_key(key: str, status: AgentStatus) -> Message | LocalAction | None:
    """The bus command (or local action) a key press stands for, given the agent's current state."""
    a = status.agent
    if key in "123456789" and len(key) == 1:
        return SetEmotion(
            agent=a,
            name=EMOTION_KEYS[int(key) - 1],
            intensity=status.intensity if status.intensity > 0 else 1.0,
            transition_s=0.5,
        )
    if key in ("+", "-"):
        step = INTENSITY_STEP if key == "+" else -INTENSITY_STEP
        value = round(min(1.0, max(0.0, status.intensity + step)), 3)
        return SetEmotion(agent=a, name=status.emotion, intensity=value, transition_s=0.3)
    if key == "t":
        return SetRole(
            agent=a,
            role="listening" if status.role == "talking" else "talking",
            speaker="user" if status.role == "talking" else a,
        )
    if key == "e":
        i = EYE_MODE_CYCLE.index(status.eye_mode) if status.eye_mode in EYE_MODE_CYCLE else -1
        return SetEyes(agent=a, mode=EYE_MODE_CYCLE[(i + 1) % len(EYE_MODE_CYCLE)])  # type: ignore[arg-type]
    if key in ("left", "right", "up", "down", "0"):
        turn, nod, tilt = status.head
        if key == "0":
            turn = nod = tilt = 0.0
        # The face looks at the viewer, so the agent's right (+turn) is the screen's left.
        turn += {"left": TURN_STEP, "right": -TURN_STEP}.get(key, 0.0)
        nod += {"up": NOD_STEP, "down": -NOD_STEP}.get(key, 0.0)
        clip = lambda v: round(min(1.0, max(-1.0, v)), 3)  # noqa: E731
        return MoveHead(agent=a, turn=clip(turn), nod=clip(nod), tilt=clip(tilt), duration_s=HEAD_MOVE_S)
    if key == "v":
        return LocalAction("view")
    if key in TOGGLE_KEYS:
        return LocalAction(TOGGLE_KEYS[key])
    if key == "tab":
        return LocalAction("next_agent")
    if key == "q":
        return LocalAction("close")
    return None


class WindowError(RuntimeError):
    """No window could be opened (no display, or glfw failed)."""


_TEXT_VERTEX = """
#version 330
in vec2 in_pos;
in vec2 in_uv;
out vec2 v_uv;
void main() { v_uv = in_uv; gl_Position = vec4(in_pos, 0.0, 1.0); }
"""
_TEXT_FRAGMENT = """
#version 330
uniform sampler2D u_tex;
in vec2 v_uv;
out vec4 f_color;
void main() { f_color = texture(u_tex, v_uv); }
"""


class Window:
    """A resizable glfw window with an OpenGL 3.3 core context, vsync, and a help line at the bottom."""

    def __init__(
        self, size: tuple[int, int], title: str = "eca", vsync: bool = True, on_key: Callable[[str], None] | None = None
    ) -> None:
        if not display_available():
            raise WindowError("no display (DISPLAY / WAYLAND_DISPLAY is not set)")
        if not glfw.init():
            raise WindowError("glfw could not initialise (is the display reachable?)")
        glfw.window_hint(glfw.CONTEXT_VERSION_MAJOR, 3)
        glfw.window_hint(glfw.CONTEXT_VERSION_MINOR, 3)
        glfw.window_hint(glfw.OPENGL_PROFILE, glfw.OPENGL_CORE_PROFILE)
        glfw.window_hint(glfw.OPENGL_FORWARD_COMPAT, True)
        glfw.window_hint(glfw.RESIZABLE, True)
        self.handle = glfw.create_window(int(size[0]), int(size[1]), title, None, None)
        if not self.handle:
            glfw.terminate()
            raise WindowError("glfw could not create a window with an OpenGL 3.3 context")
        self._text_tex: moderngl.Texture | None = None
        ctx: moderngl.Context | None = None
        try:
            glfw.make_context_current(self.handle)
            glfw.swap_interval(1 if vsync else 0)
            ctx = moderngl.create_context()
            self._text_prog = ctx.program(vertex_shader=_TEXT_VERTEX, fragment_shader=_TEXT_FRAGMENT)
            self._text_vbo = ctx.buffer(reserve=6 * 4 * 4, dynamic=True)
            self._text_vao = ctx.vertex_array(self._text_prog, [(self._text_vbo, "2f 2f", "in_pos", "in_uv")])
        except Exception as exc:  # the window is already open: close it rather than leak it
            if ctx is not None:
                ctx.release()
            glfw.destroy_window(self.handle)
            glfw.terminate()
            raise WindowError(f"OpenGL set-up in the window failed: {exc}") from exc
        self.ctx = ctx
        self.on_key = on_key
        glfw.set_key_callback(self.handle, self._key_callback)
        self._text = ""
        self.frames = 0

    # --- events ------------------------------------------------------------------------------

    def _key_callback(self, window: object, key: int, scancode: int, action: int, mods: int) -> None:
        if action not in (glfw.PRESS, glfw.REPEAT):
            return
        name = KEY_NAMES.get(key)  # '=' maps to '+' there: they share a key on most layouts
        if name is not None and self.on_key is not None:
            self.on_key(name)

    def poll(self) -> None:
        glfw.poll_events()

    @property
    def should_close(self) -> bool:
        return bool(glfw.window_should_close(self.handle))

    def request_close(self) -> None:
        glfw.set_window_should_close(self.handle, True)

    def framebuffer_size(self) -> tuple[int, int]:
        width, height = glfw.get_framebuffer_size(self.handle)
        return max(1, int(width)), max(1, int(height))

    @property
    def screen(self) -> moderngl.Framebuffer:
        fbo = self.ctx.detect_framebuffer()
        fbo.viewport = (0, 0, *self.framebuffer_size())
        return fbo

    # --- drawing -----------------------------------------------------------------------------

    def set_title(self, title: str) -> None:
        glfw.set_window_title(self.handle, title)

    def draw_text_line(self, target: moderngl.Framebuffer, text: str) -> None:
        """Draw one line of text on a translucent band along the bottom of the target."""
        if text != self._text or self._text_tex is None:
            self._text = text
            image = _text_image(text)
            if self._text_tex is not None:
                self._text_tex.release()
            self._text_tex = self.ctx.texture((image.shape[1], image.shape[0]), 4, image[::-1].tobytes())
            self._text_tex.filter = (moderngl.LINEAR, moderngl.LINEAR)
        tex = self._text_tex
        _, _, width, height = target.viewport
        w = min(2.0, 2.0 * tex.width / max(width, 1))
        h = 2.0 * tex.height / max(height, 1)
        x0, y0, x1, y1 = -1.0, -1.0, -1.0 + w, -1.0 + h
        quad = np.array(
            [[x0, y0, 0, 0], [x1, y0, 1, 0], [x1, y1, 1, 1], [x0, y0, 0, 0], [x1, y1, 1, 1], [x0, y1, 0, 1]],
            dtype=np.float32,
        )
        self._text_vbo.write(quad.tobytes())
        target.use()
        self.ctx.enable(moderngl.BLEND)
        self.ctx.blend_func = moderngl.SRC_ALPHA, moderngl.ONE_MINUS_SRC_ALPHA
        tex.use(0)
        self._text_prog["u_tex"].value = 0
        self._text_vao.render(moderngl.TRIANGLES, vertices=6)
        self.ctx.disable(moderngl.BLEND)

    def swap(self) -> None:
        glfw.swap_buffers(self.handle)
        self.frames += 1

    def close(self) -> None:
        if self.handle is None:
            return
        if self._text_tex is not None:
            self._text_tex.release()
        self.ctx.release()
        glfw.destroy_window(self.handle)
        self.handle = None
        glfw.terminate()


def _text_image(text: str) -> np.ndarray:
    """RGBA pixels of one line of white text on a translucent dark band (Pillow's built-in font)."""
    from PIL import Image, ImageDraw, ImageFont

    font = ImageFont.load_default()
    left, top, right, bottom = font.getbbox(text or " ")
    pad = 4
    image = Image.new("RGBA", (max(1, right - left + 2 * pad), bottom - top + 2 * pad), (20, 20, 28, 170))
    ImageDraw.Draw(image).text((pad - left, pad - top), text, fill=(255, 255, 255, 255), font=font)
    return np.asarray(image, dtype=np.uint8)
