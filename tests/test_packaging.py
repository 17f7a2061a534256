"""Packaging and CLI: resources resolve without the source tree, the library stays display-free."""

from __future__ import annotations

import importlib.resources
import os
import pkgutil
import subprocess
import sys

import pytest

import particlesplat


def _run(code: str) -> subprocess.CompletedProcess:
    # run from / so nothing is found through the current directory
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd="/", timeout=300)


def test_shaders_and_assets_are_package_resources() -> None:
    shaders = {p.name for p in importlib.resources.files("viewer.shaders").iterdir()}
    assert any(name.endswith((".vert", ".frag")) for name in shaders)
    assets = {p.name for p in importlib.resources.files("particlesplat.assets").iterdir()}
    assert "scenes" in assets


def test_library_never_imports_the_viewer_or_gl() -> None:
    names = [m.name for m in pkgutil.walk_packages(particlesplat.__path__, "particlesplat.")]
    names = [n for n in names if not n.endswith(".__main__")]  # importing it runs the command
    code = (
        "import importlib, sys\n"
        f"for name in {names!r}:\n"
        "    importlib.import_module(name)\n"
        "gui = ('viewer', 'moderngl', 'glfw', 'imgui_bundle', 'OpenGL')\n"
        "bad = [m for m in sys.modules if m.split('.')[0] in gui]\n"
        "print(','.join(bad))\n"
    )
    proc = _run(code)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "", f"particlesplat imported: {proc.stdout.strip()}"


@pytest.mark.parametrize(
    "argv",
    [
        [],
        ["--help"],
        ["synth", "--help"],
        ["train", "--help"],
        ["eval", "--help"],
        ["render", "--help"],
        ["bench", "--help"],
        ["bench", "render", "--help"],
        ["bench", "viewer", "--help"],
    ],
)
def test_cli_help_everywhere(argv: list[str]) -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "particlesplat.cli", *argv],
        capture_output=True,
        text=True,
        cwd="/",
        timeout=300,
        env={**os.environ, "PYTHONWARNINGS": "ignore"},
    )
    assert proc.returncode == 0, proc.stderr
    assert "usage" in proc.stdout.lower()


def test_cli_unknown_command_fails_clearly() -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "particlesplat.cli", "frobnicate"],
        capture_output=True,
        text=True,
        cwd="/",
        timeout=300,
    )
    assert proc.returncode == 2
    assert "unknown command 'frobnicate'" in proc.stderr
