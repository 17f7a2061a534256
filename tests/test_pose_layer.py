"""A workspace layer that follows each scene's pose (``model.bg_static_pose``: a robot's joint angles).

Each Gaussian's mean moves by its learned 3 x D Jacobian times the scene's pose minus the training scenes' mean
pose; everything that reads a scene passes its pose from ``scene.json``.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
import warnings

import pytest
import torch
import yaml
from model_data import TINY_MODEL, tiny_config, tiny_dataset

from particlesplat.cli.main import main
from particlesplat.core.errors import InputWarning
from particlesplat.data import SceneDataset
from particlesplat.data.scene import SceneFormatError
from particlesplat.data.scene_meta import read_pose, scene_pose
from particlesplat.editing.open_scene import encode_scene
from particlesplat.model import ModelConfig, ParticleSplat, read_checkpoint
from particlesplat.model.config import ConfigError
from particlesplat.model.static_background import POSE_STEP, WORKSPACE_STEP, WorkspaceBackground

POSED = dict(bg_static_grid=0, bg_static_points=40, bg_static_pose="arm_joints_rad", bg_static_pose_dims=2)


def _posed_layer() -> WorkspaceBackground:
    torch.manual_seed(0)
    layer = WorkspaceBackground(ModelConfig(**{**TINY_MODEL, **POSED}))
    layer.initialise(torch.rand(40, 3), torch.rand(40, 3), torch.full((40,), 0.02))
    with torch.no_grad():
        layer.offset.normal_()
        layer.pose_jacobian.normal_()  # type: ignore[union-attr]
    layer.set_pose_mean(torch.tensor([[0.1, -0.2], [0.3, 0.0]]))
    return layer


def test_each_mean_moves_by_its_jacobian_times_the_pose_offset():
    layer = _posed_layer()
    assert torch.allclose(layer.pose_mean, torch.tensor([0.2, -0.1]))
    pose = torch.tensor([[0.2, -0.1], [0.5, 0.3], [-0.1, 0.0]])
    f = layer(pose)
    # float64 by hand: anchor + step * offset + step_J * J (pose - mean)
    J = layer.pose_jacobian.detach().double()  # type: ignore[union-attr]
    base = layer.anchor.double() + WORKSPACE_STEP * layer.offset.detach().double()
    for b in range(3):
        want = base + POSE_STEP * J @ (pose[b].double() - torch.tensor([0.2, -0.1], dtype=torch.float64))
        assert torch.allclose(f["means"][b].double(), want, atol=1e-6)
    assert torch.allclose(f["means"][0], layer()["means"])  # at the mean pose: the shared layer
    for k in ("quats", "scales", "opacities", "sh"):  # only the means follow the pose
        assert f[k].shape[0] == 3 and torch.equal(f[k][1], layer()[k])
    with pytest.raises(ValueError, match=r"pose must be \(B, 2\)"):
        layer(torch.zeros(3))


def test_the_pose_keys_go_together_and_need_the_workspace_layer():
    with pytest.raises(ConfigError, match=r"background\.static_pose: and background\.static_pose_dims go together"):
        ModelConfig(**{**POSED, "bg_static_pose_dims": 0}).validate()
    with pytest.raises(ConfigError, match=r"background\.static_pose"):
        ModelConfig(**{**POSED, "bg_static_pose": ""}).validate()
    with pytest.raises(ConfigError, match=r"needs background\.static_points > 0"):
        ModelConfig(**{**POSED, "bg_static_grid": 16, "bg_static_points": 0}).validate()
    ModelConfig(**POSED).validate()


def test_a_layer_without_a_pose_keeps_the_checkpoint_layout():
    layer = WorkspaceBackground(ModelConfig(**{**TINY_MODEL, **POSED, "bg_static_pose": "", "bg_static_pose_dims": 0}))
    assert layer.pose_dims == 0 and layer.pose_jacobian is None
    assert not any("pose" in k for k in layer.state_dict())  # checkpoints made before the pose load unchanged
    assert {"static_bg.pose_mean", "static_bg.pose_jacobian"} <= set(
        ParticleSplat(ModelConfig(**{**TINY_MODEL, **POSED})).state_dict()
    )


def _posed_scenes(tmp_path_factory, tmp_path, poses):
    """A copy of the tiny dataset whose scenes record ``poses`` (per split, per scene) under arm_joints_rad."""
    data = tmp_path / "data"
    shutil.copytree(tiny_dataset(tmp_path_factory), data)
    for split, values in poses.items():
        for folder, value in zip(sorted(p for p in (data / split).iterdir() if p.is_dir()), values, strict=True):
            meta = json.loads((folder / "scene.json").read_text())
            if value is None:
                meta.pop("arm_joints_rad", None)
            else:
                meta["arm_joints_rad"] = value
            (folder / "scene.json").write_text(json.dumps(meta))
    return data


def test_scenes_give_their_pose_and_name_the_file_when_it_is_bad(tmp_path_factory, tmp_path):
    data = _posed_scenes(tmp_path_factory, tmp_path, {"train": [[0.5, 1.0], [1.5, "x"]], "val": [None]})
    a, b = sorted((data / "train").iterdir())
    assert read_pose(a, "arm_joints_rad", 2) == [0.5, 1.0]
    ds = SceneDataset(data / "train", resolution=32, pose_key="arm_joints_rad", pose_dims=2)
    assert torch.equal(ds[0]["pose"], torch.tensor([0.5, 1.0]))
    with pytest.raises(SceneFormatError, match=r"scene\.json: key 'arm_joints_rad' must be 2 finite numbers"):
        ds[1]
    val = SceneDataset(data / "val", resolution=32, pose_key="arm_joints_rad", pose_dims=2)
    with pytest.raises(SceneFormatError, match=r"scene\.json: no key 'arm_joints_rad'"):
        val[0]
    assert "pose" not in SceneDataset(data / "train", resolution=32)[0]
    # inference reads what a scene records, and holds the mean pose (with a warning) where it records none
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert scene_pose(next((data / "val").iterdir()), "arm_joints_rad", 2) is None
        assert scene_pose(a, "", 0) is None
    assert len(caught) == 1 and issubclass(caught[0].category, InputWarning) and "mean pose" in str(caught[0].message)
    assert torch.equal(scene_pose(a, "arm_joints_rad", 2), torch.tensor([0.5, 1.0]))


def test_a_scenes_pose_moves_its_decoded_workspace_layer(tmp_path_factory, tmp_path):
    """Encoding reads the scene's pose; the decoded background Gaussians are the layer at that pose, and the
    particles, encoded against the layer's render, follow it too."""
    data = _posed_scenes(tmp_path_factory, tmp_path, {"train": [[0.0, 0.0], [0.4, -0.3]], "val": [[0.2, 0.1]]})
    torch.manual_seed(0)
    model = ParticleSplat(ModelConfig(**{**TINY_MODEL, **POSED})).eval()
    layer = model.static_bg
    assert isinstance(layer, WorkspaceBackground)
    layer.initialise(torch.rand(40, 3) - 0.5, torch.rand(40, 3), torch.full((40,), 0.05))
    with torch.no_grad():
        layer.pose_jacobian.normal_()  # type: ignore[union-attr]
    scene = sorted((data / "train").iterdir())[1]
    enc = encode_scene(model, scene, [0, 1])
    assert torch.equal(enc.particles.pose, torch.tensor([0.4, -0.3]))
    g = model.decode(enc.particles, z_t_threshold=0.0)
    background = g.means[g.owner < 0]
    assert torch.allclose(background, layer(torch.tensor([[0.4, -0.3]]))["means"][0])
    assert not torch.allclose(background, layer()["means"])
    # the same scene at the mean pose (its pose dropped): the layer as trained, the same particle count
    mean = model.decode(dataclasses.replace(enc.particles, pose=None), z_t_threshold=0.0)
    assert torch.allclose(mean.means[mean.owner < 0], layer()["means"])


def test_training_follows_the_poses_about_their_mean_and_resumes(tmp_path_factory, tmp_path):
    data = _posed_scenes(tmp_path_factory, tmp_path, {"train": [[0.0, 0.2], [0.4, -0.4]], "val": [[0.2, 0.1]]})
    cfg = tiny_config(tmp_path / "tiny.yaml", steps=2, val_every=2)
    text = yaml.safe_load(cfg.read_text())
    text["model"].update(POSED)
    cfg.write_text(yaml.safe_dump(text))
    out = tmp_path / "run"
    assert main(["train", "--config", str(cfg), "--data", str(data), "--out", str(out), "--stop-after", "1"]) == 0
    state = read_checkpoint(out / "last.pt")["state_dict"]
    assert torch.allclose(state["static_bg.pose_mean"], torch.tensor([0.2, -0.1]))
    assert float(state["static_bg.pose_jacobian"].abs().max()) > 0  # trained: the poses differ
    assert main(["train", "--config", str(cfg), "--data", str(data), "--out", str(out), "--resume"]) == 0
    after = read_checkpoint(out / "last.pt")
    assert after["step"] == 2 and torch.equal(after["state_dict"]["static_bg.pose_mean"], state["static_bg.pose_mean"])
