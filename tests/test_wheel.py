"""The wheel ships what users run (code, shaders, the model, its recipe, the demo scenes) and nothing else."""

from __future__ import annotations

import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MAX_BYTES = 10 * 1024 * 1024
# Not source: build outputs, caches, environments and local data. Copying the tree without them keeps a stale
# build/ folder from leaking files into the wheel under test.
_ANYWHERE = shutil.ignore_patterns("__pycache__", ".pytest_cache", ".ruff_cache", "*.egg-info", "*.tmp")
_TOP = {".git", ".venv", "build", "dist", "runs", "data"}


def _ignore(folder: str, names: list[str]) -> set[str]:
    top = _TOP if Path(folder) == ROOT else set()
    return set(_ANYWHERE(folder, names)) | (top & set(names))


@pytest.fixture(scope="module")
def wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Build the wheel from a clean copy of the source tree with the installed setuptools: (path to the .whl)."""
    tmp = tmp_path_factory.mktemp("wheel")
    src = tmp / "src"
    shutil.copytree(ROOT, src, ignore=_ignore)
    out = tmp / "out"
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "wheel",
            str(src),
            "--no-deps",
            "--no-build-isolation",
            "--no-index",
            "-q",
            "-w",
            str(out),
        ],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-4000:]
    wheels = list(out.glob("particlesplat-*.whl"))
    assert len(wheels) == 1, wheels
    return wheels[0]


def _names(wheel: Path) -> list[str]:
    with zipfile.ZipFile(wheel) as z:
        return z.namelist()


def test_wheel_is_small(wheel: Path) -> None:
    assert wheel.stat().st_size <= MAX_BYTES, f"{wheel.name}: {wheel.stat().st_size / 1e6:.1f} MB"


def test_wheel_holds_the_model_the_scenes_and_the_shaders(wheel: Path) -> None:
    names = set(_names(wheel))
    for family in ("", "robot/"):  # each family's shipped model and its recipe
        assert f"particlesplat/assets/{family}model.pt" in names
        assert f"particlesplat/assets/{family}recipe.yaml" in names
    # every shader of the source tree
    shaders = {p.name for p in (ROOT / "shaders").iterdir() if p.suffix in (".vert", ".frag", ".glsl", ".geom")}
    assert shaders and {f"viewer/shaders/{s}" for s in shaders} <= names
    # every file of every demo scene, byte for byte the ones in the repository
    scenes = sorted(
        p
        for folder in (ROOT / "assets" / "scenes", ROOT / "assets" / "robot" / "scenes")
        for p in folder.rglob("*")
        if p.is_file() and "__pycache__" not in p.parts
    )
    assert scenes
    with zipfile.ZipFile(wheel) as z:
        for p in scenes:
            name = "particlesplat/assets/" + p.relative_to(ROOT / "assets").as_posix()
            assert name in names, f"{name} missing from the wheel"
            assert z.read(name) == p.read_bytes(), name
    # the code: every module of the two packages
    for pkg in ("particlesplat", "viewer"):
        for p in (ROOT / pkg).rglob("*.py"):
            assert f"{pkg}/{p.relative_to(ROOT / pkg).as_posix()}" in names, p
    entry_points = next(n for n in names if n.endswith(".dist-info/entry_points.txt"))
    with zipfile.ZipFile(wheel) as z:
        text = z.read(entry_points).decode()
    assert "particlesplat = " in text and "particlesplat-viewer = " in text


def test_wheel_holds_no_training_runs(wheel: Path) -> None:
    names = _names(wheel)
    checkpoints = [n for n in names if n.endswith((".pt", ".pth", ".ckpt"))]
    assert sorted(checkpoints) == ["particlesplat/assets/model.pt", "particlesplat/assets/robot/model.pt"], checkpoints
    assets = [n for n in names if n.startswith("particlesplat/assets/")]
    runs = [n for n in assets if "/training/" in n or "model-training" in n]
    runs += [n for n in names if n.endswith(".jsonl")]
    assert runs == [], runs
    assert not [n for n in names if n.startswith(("tests/", "docs/"))]
