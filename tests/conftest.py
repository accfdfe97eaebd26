"""Suite-wide set-up."""

from __future__ import annotations

import pytest

from services.renderer.kernels import warm_up


@pytest.fixture(scope="session", autouse=True)
def compiled_renderer_code() -> None:
    """The renderer's compiled per-frame code, loaded (or compiled, on a machine that never ran setup)
    before any test, so that no test measuring time pays for it inside its measurement."""
    warm_up()
