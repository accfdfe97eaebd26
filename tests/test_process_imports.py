"""Each process imports only what it uses: an instance at rest holds every process's imports (bench/memory.py),
and numba with LLVM alone is some 80 MB. Each entry is imported in a fresh interpreter, as
`python -m eca.services.processes.run NAME` does, and must not have loaded the heavy packages it does not use."""

from __future__ import annotations

import subprocess
import sys

import pytest

from eca.services.tools.child_processes import subprocess_env

HEAVY = ("numpy", "numba", "llvmlite", "scipy", "moderngl", "glfw", "av", "aiortc", "aiohttp", "PIL", "matplotlib")
GL_AND_VIDEO = {"numba", "llvmlite", "scipy", "moderngl", "glfw", "av", "aiortc", "aiohttp", "PIL", "matplotlib"}

# The process's start, as run.py does it: run.py itself, then the service's module (the broker's function).
SERVICE_PROBE = """
import importlib, sys
from eca.services.processes.run import SERVICES
name = {name!r}
if name == "broker":
    from eca.services.processes.broker import run_broker
else:
    module_name, class_name = SERVICES[name].split(":")
    getattr(importlib.import_module(module_name), class_name)
print("HEAVY", ",".join(sorted(m for m in {heavy!r} if m in sys.modules)))
"""

# The supervisor as `eca up --web --headless --face flexor` runs it, up to starting its children: the options of
# the renderer, the web and the rig checked, the faces chosen (run_up itself is imported by then, not run).
SUPERVISOR_PROBE = """
import sys
from eca.services.tools import cli
from eca.services.tools.commands import up
up.run_up = lambda *args, **kwargs: 0
code = cli.main(["up", "--web", "--headless", "--face", "flexor", "--rig"])
assert code == 0, code
print("HEAVY", ",".join(sorted(m for m in {heavy!r} if m in sys.modules)))
"""

# What other processes name of the renderer package: the seam, the faces, a canvas and the stage.
RENDERER_NAMES_PROBE = """
import sys
from eca.services.processes.renderer import (
    DRAWERS, Drawers, FaceDrawer, HeadlessContextError, OffscreenCanvas, RenderToggles, Stage, YuvTarget, agent_faces,
    check_face, make_drawer,
)
print("HEAVY", ",".join(sorted(m for m in {heavy!r} if m in sys.modules)))
"""

# A renderer whose agents all have the 3D head (`--face head`) draws with GL alone.
HEAD_PROBE = """
import sys
from eca.services.processes.renderer.head import HeadDrawer
print("HEAVY", ",".join(sorted(m for m in {heavy!r} if m in sys.modules)))
"""


def heavy_loaded(program: str) -> set[str]:
    done = subprocess.run([sys.executable, "-c", program], capture_output=True, text=True, env=subprocess_env(),
                          timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    line = next(line for line in done.stdout.splitlines() if line.startswith("HEAVY"))
    return set(filter(None, line.removeprefix("HEAVY").strip().split(",")))


def test_the_supervisor_loads_no_numpy_gl_or_video_library() -> None:
    assert heavy_loaded(SUPERVISOR_PROBE.format(heavy=HEAVY)) == set()


@pytest.mark.parametrize(("name", "must_not"), [
    ("broker", set(HEAVY)),
    ("dialogue", GL_AND_VIDEO),
    ("gaze", GL_AND_VIDEO),
    ("audio", GL_AND_VIDEO),
    ("rig", GL_AND_VIDEO),
    # The renderer compiles its drawing code (numba) when it makes its first drawer, about to draw: not at import.
    ("renderer", GL_AND_VIDEO - {"moderngl"}),
    # The web service draws with the renderer's names; naming them loads no numba (it loads when it first draws).
    ("web", {"numba", "llvmlite", "scipy", "glfw", "matplotlib"}),
])
def test_a_process_imports_only_what_it_uses(name: str, must_not: set[str]) -> None:
    loaded = heavy_loaded(SERVICE_PROBE.format(name=name, heavy=HEAVY))
    assert not loaded & must_not, f"{name} loads {sorted(loaded & must_not)} at import"


def test_naming_the_renderers_exports_loads_no_compiled_drawing_code() -> None:
    loaded = heavy_loaded(RENDERER_NAMES_PROBE.format(heavy=HEAVY))
    assert not loaded & {"numba", "llvmlite", "scipy", "glfw", "av", "PIL"}, sorted(loaded)


def test_the_3d_head_needs_none_of_the_2d_faces_compiled_code() -> None:
    loaded = heavy_loaded(HEAD_PROBE.format(heavy=HEAVY))
    assert not loaded & {"numba", "llvmlite", "scipy", "glfw", "av"}, sorted(loaded)
