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


def test_a_robot_demo_scene_is_judged_against_robot_rigs_and_found_turned(capsys, tmp_path):
    """A shipped robot scene (robosuite's frame: robot at -x) is at the robot rigs' scale and matches; the same
    scene turned a quarter turn about z (cameras and robot base: the robot at +y) is found turned, and the
    transform turns +y back to -x."""
    robot = [p for p in demo_scenes() if p.parent.parent.name == "robot"][0]
    assert main(["scene", "check", str(robot)]) == 0
    out = capsys.readouterr().out
    assert "robot family" in out and "robot training scenes' are 0.8-1.25 m: ok" in out
    assert "at -x, robosuite's convention: ok" in out and "matches the expected world frame" in out

    turned = tmp_path / robot.name
    shutil.copytree(robot, turned)
    turn = np.eye(4)
    turn[:2, :2] = [[0.0, 1.0], [-1.0, 0.0]]  # -90 degrees about z: -x goes to +y
    transforms = json.loads((turned / "transforms.json").read_text())
    for frame in transforms["frames"]:
        frame["transform_matrix"] = (turn @ np.array(frame["transform_matrix"])).tolist()
    (turned / "transforms.json").write_text(json.dumps(transforms))
    meta = json.loads((turned / "scene.json").read_text())
    meta["robot_base"] = (turn @ np.array(meta["robot_base"])).tolist()
    (turned / "scene.json").write_text(json.dumps(meta))
    assert main(["scene", "check", str(turned)]) == 1
    out = capsys.readouterr().out
    assert "s = 1," in out and "turned -90 degrees about z" in out
    rows = out.split("R = [")[1].split("]")[0].split(";")
    R = np.array([[float(v) for v in row.split()] for row in rows])
    assert np.allclose(R, [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]], atol=0.01)  # the base's azimuth
    # is measured from the scene centre, a few millimetres off the origin
