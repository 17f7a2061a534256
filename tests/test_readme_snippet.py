"""The README's library snippet runs as written from any directory (not only the repository root)."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"


def test_the_library_snippet_runs_outside_the_repository(tmp_path):
    text = README.read_text()
    section = text[text.index("## The library") :]
    code = re.search(r"```python\n(.*?)```", section, re.DOTALL).group(1)
    proc = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "scene.ply").is_file()  # what the snippet saves, in the directory it ran in


def test_the_snippet_gives_a_robot_model_the_robot_scene_s_pose():
    """``scene.pose(model)`` in the snippet hands a robot model what its scene.json records of the robot (the
    joint angles, base and gripper it reads, packed), so the snippet works on robot scenes as written; a tabletop
    model reads nothing."""
    import json

    from particlesplat.core.panda_arm import pack_arm_state
    from particlesplat.data import load_scene
    from particlesplat.editing import demo_scenes
    from particlesplat.model import load_model

    robot_scene = next(p for p in demo_scenes() if "robot" in str(p))
    robot = load_model(README.parent / "assets" / "robot" / "model.pt")
    scene = load_scene(robot_scene, resolution=robot.config.resolution)
    meta = json.loads((robot_scene / "scene.json").read_text())
    state = pack_arm_state(meta["arm_joints_rad"], meta["robot_base"], meta["gripper"])
    pose = scene.pose(robot)
    assert pose is not None and pose.tolist() == pytest.approx(state, abs=1e-6)  # float32
    assert scene.pose(load_model()) is None
