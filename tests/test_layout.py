"""The map of the tree (docs/architecture.md, "Folders") holds: which folder may import which.

Every `import` and `from ... import` is read from the source (the ones inside functions too), so a lazy
import that runs the wrong way is caught as well as one at the top of a module.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parent.parent

PACKAGE = REPO_ROOT / "eca"

# folder (under eca/) -> the packages its modules must never import
FORBIDDEN: dict[str, tuple[str, ...]] = {
    "agent": ("eca.protocol", "eca.services", "eca.pipecat"),  # pure models
    "protocol": ("eca.agent", "eca.services", "eca.pipecat"),  # the wire knows nothing of models
    "services/processes": ("eca.services.tools", "eca.services.pipecat", "eca.pipecat"),  # tools drive processes
    "services/tools": ("eca.services.pipecat", "eca.pipecat"),
}


def imported_modules(path: Path) -> set[str]:
    """Every absolute module `path` imports; `from services import broker` counts as `services.broker`."""
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), filename=str(path))):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found.add(node.module)
            found.update(f"{node.module}.{alias.name}" for alias in node.names)
    return found


def within(module: str, package: str) -> bool:
    return module == package or module.startswith(package + ".")


@pytest.mark.parametrize("folder", sorted(FORBIDDEN))
def test_no_import_runs_the_wrong_way(folder: str) -> None:
    modules = sorted((PACKAGE / folder).rglob("*.py"))
    assert modules, f"eca/{folder}/ holds no module"
    wrong = [f"{path.relative_to(REPO_ROOT)} imports {module}" for path in modules
             for module in sorted(imported_modules(path))
             if any(within(module, package) for package in FORBIDDEN[folder])]
    assert not wrong, "\n".join(wrong)


def test_the_checker_sees_a_lazy_import(tmp_path: Path) -> None:
    source = tmp_path / "lazy.py"
    source.write_text("def f():\n    from eca.services import tools\n    import eca.services.pipecat.face\n")
    assert {"eca.services.tools", "eca.services.pipecat.face"} <= imported_modules(source)


def test_services_holds_processes_tools_and_pipecat_only() -> None:
    """A newcomer's map: every module of services/ is in one of its three folders."""
    top = sorted(p.name for p in (PACKAGE / "services").iterdir() if p.name != "__pycache__")
    assert top == ["__init__.py", "pipecat", "processes", "tools"]


def test_every_process_run_starts_lives_in_processes() -> None:
    from eca.services.processes.run import SERVICES

    assert all(within(target.split(":")[0], "eca.services.processes") for target in SERVICES.values())


@pytest.mark.parametrize("folder", ["services/processes/web", "services/pipecat"])
def test_outputs_that_draw_use_the_drawing_seam_not_the_renderers_insides(folder: str) -> None:
    """The web service and the pipecat face draw through `eca.services.processes.renderer`'s exported names (the
    FaceDrawer seam, the stage, canvases); none of them reaches into a module of the 2D face."""
    inside = [f"{path.relative_to(REPO_ROOT)} imports {module}" for path in sorted((PACKAGE / folder).rglob("*.py"))
              for module in sorted(imported_modules(path))
              if module.startswith("eca.services.processes.renderer.")
              and module.removeprefix("eca.services.processes.renderer.") not in EXPORTED]
    assert not inside, "\n".join(inside)


EXPORTED = set(__import__("eca.services.processes.renderer", fromlist=["__all__"]).__all__)


def test_the_rig_service_composes_without_gl() -> None:
    """The rig service follows the scenes (scene/) and retargets them; it draws nothing, so it imports neither the
    renderer nor a GL or window library, and runs where no GPU or display is."""
    drawing = ("eca.services.processes.renderer", "moderngl", "glfw")
    wrong = [f"{path.relative_to(REPO_ROOT)} imports {module}"
             for path in sorted((PACKAGE / "services/processes/rig").rglob("*.py"))
             for module in sorted(imported_modules(path)) if any(within(module, d) for d in drawing)]
    assert not wrong, "\n".join(wrong)
