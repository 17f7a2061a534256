"""Without --checkpoint, a command opens a scene with the shipped model of the scene's family: a scene records its
family (scene.json), a dataset its generator (synth.json)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
import torch

from particlesplat.data.scene_meta import default_checkpoint, read_family
from particlesplat.editing.open_scene import demo_scenes, load_model_scene
from particlesplat.model.io import shipped_model_name, shipped_model_path

ROOT = Path(__file__).resolve().parents[1]
TABLETOP, ROBOT = ROOT / "assets" / "scenes" / "scene_00000", ROOT / "assets" / "robot" / "scenes" / "scene_00019"


def test_a_scene_folder_names_its_family():
    assert read_family(TABLETOP) == "tabletop"  # its scene.json records the tabletop generator
    assert read_family(ROBOT) == "robot"  # its scene.json records family: robot
    assert read_family(ROOT / "assets" / "robot" / "scenes") == "robot"  # a split folder: its first scene's
    assert read_family(ROOT / "docs") is None


def test_a_dataset_folder_names_its_family_from_synth_json(tmp_path):
    data = tmp_path / "robot_data"
    shutil.copytree(ROBOT, data / "test" / "scene_00000")
    (data / "test" / "scene_00000" / "scene.json").write_text("{}")  # nothing recorded in the scene itself
    assert read_family(data) is None
    (data / "synth.json").write_text(json.dumps({"generator": "particlesplat.data.families.robot", "seed": 0}))
    assert read_family(data) == "robot"
    assert read_family(data / "test") == "robot"  # a split folder: the dataset's synth.json above it
    assert default_checkpoint(data) == shipped_model_path("robot")
    assert default_checkpoint(tmp_path) == shipped_model_path("tabletop")  # nothing recorded: the tabletop model


def test_a_bad_scene_json_is_named(tmp_path):
    from particlesplat.data.scene import SceneFormatError

    (tmp_path / "scene.json").write_text("{not json")
    with pytest.raises(SceneFormatError, match=r"scene.json: not valid JSON"):
        read_family(tmp_path)


def test_each_family_opens_with_its_own_model():
    torch.set_num_threads(1)
    assert {p.name for p in demo_scenes()} >= {"scene_00000"}
    tabletop, _, name = load_model_scene(None, TABLETOP)
    assert name == "assets/model.pt" and tabletop.config.resolution == 64
    robot, enc, name = load_model_scene(None, ROBOT)
    assert name == "assets/robot/model.pt" and robot.config.resolution == 128
    assert robot.config.fg_evidence and enc.particles.num > 0
    assert shipped_model_name(shipped_model_path("robot")) == "assets/robot/model.pt"
    assert shipped_model_name("runs/x/last.pt") == "runs/x/last.pt"


def test_every_shipped_checkpoint_records_its_provenance():
    from particlesplat.model import read_checkpoint
    from particlesplat.model.provenance import describe

    for family in ("tabletop", "robot"):
        ckpt = read_checkpoint(shipped_model_path(family))  # also checks config_sha256
        prov = ckpt.get("provenance")
        assert prov and prov.get("data") and prov.get("scene_list_sha256"), family
        line = describe(prov)
        assert line.startswith("provenance: from ") and "none recorded" not in line
    tabletop = read_checkpoint(shipped_model_path("tabletop"))["provenance"]
    assert "staged chain" in tabletop["init"] and "hours not recorded" in describe(tabletop)


def test_refinement_runs_once_its_run_trained_it_and_the_robot_model_reads_the_arm():
    """A checkpoint written before its run's refine_start loads with refinement off (the refiner is still at its
    start, a correction of exactly zero: tests/test_refiner.py); one that records no schedule, like the tabletop
    model, keeps it. The shipped robot model trains without refinement and reads what each scene's robot knows
    of itself (joint angles, base, gripper: ``robot_state``), which places the arm's capsules for its evidence."""
    from particlesplat.data.scene_meta import read_arm_state
    from particlesplat.model.config import model_config_from_dict
    from particlesplat.model.io import read_checkpoint, refinement_trained

    tabletop = read_checkpoint(shipped_model_path("tabletop"))
    assert refinement_trained(tabletop)
    schedule = {"refine_start": 0.5, "steps": 100}
    assert not refinement_trained({**tabletop, "step": 49, "train": schedule})
    assert refinement_trained({**tabletop, "step": 50, "train": schedule})
    robot_ckpt = read_checkpoint(shipped_model_path("robot"))
    cfg = model_config_from_dict(robot_ckpt["config"])
    assert (cfg.refine_steps, cfg.bg_static_pose, cfg.bg_static_pose_dims) == (0, "robot_state", 21)
    assert cfg.fg_evidence and cfg.bg_static_points == 0 and cfg.bg_static_grid == 0
    assert not any(k.startswith("refiner.") for k in robot_ckpt["state_dict"])
    torch.set_num_threads(1)
    robot, enc, _ = load_model_scene(None, ROBOT)
    assert robot.refiner is None and enc.particles.num == cfg.particles_per_view * len(enc.context)
    state = read_arm_state(ROBOT)
    assert state is not None and enc.particles.pose is not None
    assert torch.allclose(enc.particles.pose.cpu().double(), torch.tensor(state, dtype=torch.float64), atol=1e-6)
