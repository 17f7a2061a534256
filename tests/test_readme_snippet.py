"""The README's library snippet runs as written from any directory (not only the repository root)."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

README = Path(__file__).resolve().parents[1] / "README.md"


# appended to the snippet: what it chose and drew, for the test to judge against the scene's own files
PROBE = """
import dataclasses, json
import numpy as np
np.save("segmentation.npy", out.segmentation().numpy())
print(json.dumps({"scene": str(scene_dir), "config": dataclasses.asdict(model.config),
                  "K": cam.K.tolist(), "c2w": cam.c2w.tolist(), "size": [cam.width, cam.height]}))
"""


def _snippet() -> str:
    text = README.read_text()
    section = text[text.index("## The library") :]
    return re.search(r"```python\n(.*?)```", section, re.DOTALL).group(1)


def _project(K: np.ndarray, c2w: np.ndarray, point) -> tuple[float, float, float]:
    """Pixel (u, v) and camera z of a world point: a pinhole written out here (OpenCV axes)."""
    w2c = np.linalg.inv(c2w)
    x, y, z = w2c[:3, :3] @ np.asarray(point, dtype=np.float64) + w2c[:3, 3]
    return K[0, 0] * x / z + K[0, 2], K[1, 1] * y / z + K[1, 2], z


@pytest.mark.parametrize("family, index", [("tabletop", 0), ("robot", 3)])
def test_the_library_snippet_runs_on_both_families(tmp_path, family, index):
    """The snippet as written (the tabletop demo scene), and with the robot demo scene the README names
    (``demo_scenes()[3]``), run from a directory outside the repository: it encodes each scene with its family's
    shipped model (the checkpoint's own config) and its camera frames the scene: at the scale its cameras
    recorded in scene.json, every object's centre in view and drawn by a particle."""
    import json

    from particlesplat.model import load_model
    from particlesplat.model.io import shipped_model_path

    code = _snippet()
    assert "demo_scenes()[0]" in code and "demo_scenes()[3]" in code  # the README names the robot scene
    code = code.replace("scene_dir = demo_scenes()[0]", f"scene_dir = demo_scenes()[{index}]", 1)
    proc = subprocess.run(
        [sys.executable, "-c", code + PROBE], cwd=tmp_path, capture_output=True, text=True, timeout=300
    )
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "scene.ply").is_file()  # what the snippet saves, in the directory it ran in
    got = json.loads(proc.stdout.strip().splitlines()[-1])
    meta = json.loads((Path(got["scene"]) / "scene.json").read_text())
    assert meta.get("family", "tabletop") == family
    import dataclasses

    assert got["config"] == json.loads(json.dumps(dataclasses.asdict(load_model(shipped_model_path(family)).config)))
    K, c2w, (width, height) = np.array(got["K"]), np.array(got["c2w"]), got["size"]
    seg = np.load(tmp_path / "segmentation.npy")
    centres = np.array([o["center"] for o in meta["objects"]])
    # the scale: the camera is about as far from the objects as the scene's own cameras are from what they look at
    seen = float(np.linalg.norm(c2w[:3, 3] - centres.mean(0)))
    assert 0.6 * meta["distance"] < seen < 2.0 * meta["distance"], (seen, meta["distance"])
    drawn = 0
    for centre in centres:
        u, v, z = _project(K, c2w, centre)
        assert z > 0 and 0.05 * width < u < 0.95 * width and 0.05 * height < v < 0.95 * height, (centre, u, v)
        drawn += int(seg[int(v), int(u)] >= 0)
    assert drawn >= max(1, len(centres) - 1), (drawn, len(centres))


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


def test_a_shipped_model_s_name_opens_it_from_any_directory(tmp_path, monkeypatch, capsys):
    """``assets/robot/model.pt``, as ``model info``, the viewer and edit files name the shipped robot model, opens
    it from a directory that has no ``assets/`` (the library and the command line); a file of that name in the
    working directory is opened instead; ``load_model(scene=DIR)`` follows the scene's family and refuses a
    folder that does not exist."""
    from particlesplat.cli.main import main
    from particlesplat.core.errors import UserError
    from particlesplat.data.families import shipped_model_named
    from particlesplat.editing import demo_scenes
    from particlesplat.model import load_model, read_checkpoint
    from particlesplat.model.io import shipped_model_path

    monkeypatch.chdir(tmp_path)
    robot = shipped_model_path("robot")
    assert shipped_model_named("assets/robot/model.pt") == robot
    assert shipped_model_named("./assets/model.pt") == shipped_model_path()
    assert shipped_model_named("assets/other.pt") is None and shipped_model_named("robot/model.pt") is None
    assert read_checkpoint("assets/robot/model.pt")["step"] == read_checkpoint(robot)["step"]
    assert load_model("assets/robot/model.pt").config == load_model(robot).config
    assert main(["model", "info", "assets/robot/model.pt"]) == 0
    assert "robot workspace" in capsys.readouterr().out
    from particlesplat.data.folders import check_file

    check_file("assets/robot/model.pt", "--checkpoint", shipped=True)  # what commands check before torch loads
    with pytest.raises(FileNotFoundError, match="--ply assets/robot/model.pt: no such file"):
        check_file("assets/robot/model.pt", "--ply")
    from particlesplat.core.outputs import OutputError, guard_outputs

    with pytest.raises(OutputError, match="is --checkpoint assets/robot/model.pt, which this command reads"):
        guard_outputs([("--out", robot)], [("--checkpoint", "assets/robot/model.pt")])  # the file that name opens
    robot_scene = str(demo_scenes()[3])
    argv = ["render", "--checkpoint", "assets/robot/model.pt", "--scene", robot_scene, "--width", "64"]
    assert main([*argv, "--height", "48", "--out", str(tmp_path / "r.png")]) == 0 and (tmp_path / "r.png").is_file()
    (tmp_path / "assets" / "robot").mkdir(parents=True)
    (tmp_path / "assets" / "robot" / "model.pt").write_bytes(b"not a checkpoint")
    assert shipped_model_named("assets/robot/model.pt") is None  # the working directory's own file
    with pytest.raises(UserError, match=r"^assets/robot/model.pt: "):  # this file, not the shipped one
        load_model("assets/robot/model.pt")
    assert load_model(scene=robot_scene).config == load_model(robot).config
    assert load_model(scene=demo_scenes()[0]).config == load_model().config
    with pytest.raises(FileNotFoundError, match="missing_scene: scene folder not found"):
        load_model(scene=tmp_path / "missing_scene")
