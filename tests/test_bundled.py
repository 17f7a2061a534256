"""Bundled data (shipped models, recipes, demo scenes, shaders) is found installed and from a bare checkout."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from particlesplat.core.bundled import BundledDataMissing, bundled_assets, data_dir
from particlesplat.core.errors import UserError

CHECKOUT = Path(__file__).resolve().parents[1]


def test_the_installed_packages_hold_the_bundled_files():
    assert (bundled_assets() / "recipe.yaml").is_file()
    assert (bundled_assets() / "robot" / "model.pt").is_file()
    assert (data_dir("viewer.shaders", "shaders") / "splat.vert").is_file()


def test_a_checkout_run_without_installing_reads_its_top_level_folders():
    """``python -S`` skips site-packages (the installed copy and its editable-install hooks); the checkout on
    PYTHONPATH alone has no ``particlesplat.assets`` or ``viewer.shaders`` packages."""
    code = (
        "import importlib.util as u\n"
        "from particlesplat.core.bundled import bundled_assets, data_dir\n"
        "print(u.find_spec('particlesplat.assets') is None)\n"
        "print(bundled_assets())\n"
        "print(data_dir('viewer.shaders', 'shaders'))\n"
    )
    env = {**os.environ, "PYTHONPATH": str(CHECKOUT)}
    out = subprocess.run([sys.executable, "-S", "-c", code], env=env, cwd="/", capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split("\n")[:3] == ["True", str(CHECKOUT / "assets"), str(CHECKOUT / "shaders")]


def test_neither_installed_nor_in_the_checkout_is_a_one_line_user_error(tmp_path):
    with pytest.raises(BundledDataMissing) as e:
        data_dir("particlesplat.no_such_data", "no_such_folder", checkout=tmp_path)
    message = str(e.value)
    assert isinstance(e.value, UserError) and "\n" not in message
    assert "particlesplat.no_such_data" in message and str(tmp_path / "no_such_folder") in message
    assert "pip install -e ." in message
