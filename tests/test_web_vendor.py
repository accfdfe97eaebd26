"""The vendored browser libraries are the npm releases the vendor README names, whole, with their licences, and
everything their imports name is there (the page loads them without a build step)."""

from __future__ import annotations

import hashlib
import re
from pathlib import Path

import pytest

from eca.services.processes.web.server import page_files

VENDOR = Path(__file__).resolve().parents[1] / "eca" / "services" / "processes" / "web" / "static" / "vendor"
SHA256 = {
    "three/three.module.js": "104f56145899722094556490d787aae0617cc2fc3382f31df02d724ea1aee341",
    "three/three.core.js": "613e370f76638fdef83926642bf256dc9615684922de1ce1f63a8583e5d78578",
    "three/addons/loaders/GLTFLoader.js": "532ac726e120039acbcd6cf54328c57acbf7b438176afaa6951257126d11bff1",
    "three/addons/utils/BufferGeometryUtils.js": "7bda2a8ba836b2bcf67cb938d4b9e1bb5d1b1bc616817103ed858c0b58296ce7",
    "three/addons/utils/SkeletonUtils.js": "b1632a703206c3d830de9fcbe515696770d04b71a15ee6b50afa6d2c3298c86f",
    "three-vrm/three-vrm.module.min.js": "99f943e956e52dbf52bbe418899e8a8ae5e35f5c79a94ab8e404926afc620bf2",
    "three/LICENSE": "8b378ebe60e2fe500158cb0ac71cb5e8b7d92953c2abcc63a0eb90499653b5bc",
    "three-vrm/LICENSE": "279ec82987aec7e72ecb9850bb704a87e352d577bc7581454c30f3551a88ea92",
}
IMPORT = re.compile(r"""^\s*(?:import|export)\b[^'"]*?\bfrom\s*['"]([^'"]+)['"]""", re.MULTILINE)


@pytest.mark.parametrize("name", sorted(SHA256))
def test_each_vendored_file_is_the_release(name: str) -> None:
    assert hashlib.sha256((VENDOR / name).read_bytes()).hexdigest() == SHA256[name]


def test_the_licences_are_mit_and_the_readme_names_the_versions() -> None:
    for name in ("three/LICENSE", "three-vrm/LICENSE"):
        assert "MIT License" in (VENDOR / name).read_text() or "The MIT License" in (VENDOR / name).read_text()
    readme = (VENDOR / "README.md").read_text()
    assert "0.187.0" in readme and "3.5.5" in readme
    assert "REVISION = '187'" in (VENDOR / "three/three.core.js").read_text()


def test_every_relative_import_of_the_page_and_the_libraries_is_served() -> None:
    served = page_files()
    for name, path in served.items():
        if path.suffix != ".js":
            continue
        for target in IMPORT.findall(path.read_text()):
            if target.startswith("."):
                resolved = (path.parent / target).resolve()
                assert resolved.relative_to(VENDOR.parent).as_posix() in served, (name, target)
            else:
                assert target in ("three", "@pixiv/three-vrm") or target.startswith("three/addons/"), (name, target)
