"""``particlesplat scene check``: a demo scene is in the expected world frame; the same scene turned (+y up),
in millimetres and raised is found out, and the transforms.json it writes brings the cameras back."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from particlesplat.cli.main import main
from particlesplat.core.errors import InputWarning
from particlesplat.editing.open_scene import demo_scenes

# a known similarity x' = s R x + t: a quarter turn about x (+z becomes -y), millimetres, shifted
R0 = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
S0 = 1000.0
T0 = np.array([150.0, -80.0, 400.0])


def _matrices(path) -> np.ndarray:
    return np.array([f["transform_matrix"] for f in json.loads(path.read_text())["frames"]], np.float64)


def test_a_demo_scene_matches(capsys):
    assert main(["scene", "check", str(demo_scenes()[0])]) == 0
    out = capsys.readouterr().out
    assert "matches the expected world frame" in out and "differs" not in out


def test_a_turned_scaled_raised_scene_is_reported_and_fixed(tmp_path, capsys):
    src = demo_scenes()[0]
    bad = tmp_path / "mine"
    shutil.copytree(src, bad)
    meta = json.loads((src / "transforms.json").read_text())
    for frame in meta["frames"]:
        m = np.asarray(frame["transform_matrix"], np.float64)
        m[:3, :3] = R0 @ m[:3, :3]
        m[:3, 3] = S0 * (R0 @ m[:3, 3]) + T0
        frame["transform_matrix"] = m.tolist()
    meta["depth_unit_scale_factor"] *= S0
    (bad / "transforms.json").write_text(json.dumps(meta))
    fixed = tmp_path / "fixed.json"
    with pytest.warns(InputWarning, match="depth_unit_scale_factor' makes the median depth"):  # millimetres
        assert main(["scene", "check", str(bad), "--write", str(fixed)]) == 1
    out = capsys.readouterr().out
    assert "up axis: (+0.000, -1.000, +0.000)" in out  # measured from the floor
    assert "the units look like millimetres" in out and "s = 0.001" in out
    assert "support surface: z = +0.080 m" in out  # R0^T T0 = (150, 400, 80) mm
    # the written file, in a copy of the folder, passes, and its cameras are the original ones (up to the
    # shift in x, y, which stays: the scene centre is within 1 m of the origin)
    good = tmp_path / "good"
    shutil.copytree(bad, good)
    shutil.copyfile(fixed, good / "transforms.json")
    assert main(["scene", "check", str(good)]) == 0
    a, b = _matrices(src / "transforms.json"), _matrices(good / "transforms.json")
    np.testing.assert_allclose(b[:, :3, :3], a[:, :3, :3], atol=1e-3)
    np.testing.assert_allclose(
        b[:, :3, 3] - a[:, :3, 3], np.broadcast_to([0.15, 0.40, 0.0], a[:, :3, 3].shape), atol=5e-3
    )
    assert (
        json.loads(fixed.read_text())["depth_unit_scale_factor"]
        == json.loads((src / "transforms.json").read_text())["depth_unit_scale_factor"]
    )


def test_a_robot_demo_scene_is_judged_against_robot_rigs_and_found_turned(capsys):
    """A shipped robot scene (the narrow world: robot at +y) is at the robot rigs' scale, and turned a quarter
    turn from robosuite's convention (robot at -x); the transform turns +y to -x."""
    robot = [p for p in demo_scenes() if p.parent.parent.name == "robot"][0]
    assert main(["scene", "check", str(robot)]) == 1
    out = capsys.readouterr().out
    assert "robot family" in out and "robot training scenes' are 0.8-1.25 m: ok" in out and "s = 1," in out
    assert "turned -90 degrees about z" in out
    assert "R = [+0.000000 -1.000000 +0.000000; +1.000000 +0.000000 +0.000000; +0.000000 +0.000000 +1.000000]" in out
