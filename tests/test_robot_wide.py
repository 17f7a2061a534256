"""The wide robot world (``--world wide``): small generated scenes checked against MuJoCo's own ground truth (depth
and masks against rays cast in the simulated model), the ranges each split draws from (the held-out split outside
the training ones), determinism from the seed, the grippers' actuation, and ``scene check`` on robot scenes (the
robot rigs' scale, a turned world found and turned back)."""

from __future__ import annotations

import colorsys
import importlib.util
import json
import math
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from particlesplat.cli.main import main
from particlesplat.data.families.robot_assets import INSTALL

if importlib.util.find_spec("mujoco") is None or importlib.util.find_spec("robosuite") is None:
    pytest.skip(f"robot scenes need the sim extra: {INSTALL}", allow_module_level=True)

RES = 64
VIEWS = 5
SEED = 5


def _config(cameras: str = "arc"):
    from particlesplat.data.families.robot import RobotSceneConfig

    return RobotSceneConfig(RES, RES, cameras=cameras, views=VIEWS, world="wide")  # type: ignore[arg-type]


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    from particlesplat.data.families.robot_synth import generate

    out = tmp_path_factory.mktemp("wide") / "data"
    counts = {"train": 1, "val": 0, "test": 0, "heldout": 1}
    times = generate(out, counts, seed=SEED, config=_config(), workers=1, progress=False, edits=())
    assert len(times) == 2
    return out


def _meta(folder: Path) -> dict:
    return json.loads((folder / "scene.json").read_text())


def _hue(rgba) -> float:
    return colorsys.rgb_to_hsv(*rgba[:3])[0] * 360.0


def _inside(v: float, intervals) -> bool:
    return any(lo <= v <= hi for lo, hi in intervals)


# ------------------------------------------------------------------------------------------ simulator truth
def _rebuild(split: str, index: int = 0):
    """The scene as the generator built it (same RNG), with its MuJoCo model and data."""
    from particlesplat.data.families.robot_synth import scene_rngs
    from particlesplat.data.families.robot_wide import build_wide_scene

    rng, _ = scene_rngs(SEED, split, index, False)
    return build_wide_scene(rng, _config(), heldout=split == "heldout")


@pytest.mark.parametrize("split", ["train", "heldout"])
def test_depth_and_masks_match_rays_cast_in_the_simulated_scene(dataset, split):
    """Every stored pixel's depth and instance id against ``mj_ray`` through its centre in the rebuilt model."""
    from PIL import Image

    from particlesplat.data.families.robot_assets import import_mujoco
    from particlesplat.data.families.robot_compose import HIDDEN_GROUP

    mujoco = import_mujoco()
    folder = dataset / split / "scene_00000"
    scene = _rebuild(split)
    comp = scene.comp
    assert _meta(folder)["arm_joints_rad"] == [float(v) for v in scene.arm]
    tr = json.loads((folder / "transforms.json").read_text())
    groups = np.ones(6, np.uint8)
    groups[HIDDEN_GROUP] = 0
    geomid = np.zeros(1, np.int32)
    rng = np.random.default_rng(0)
    depth_err, mask_wrong, hits, total = [], 0, 0, 0
    for frame in tr["frames"]:
        c2w = np.asarray(frame["transform_matrix"]) @ np.diag([1.0, -1.0, -1.0, 1.0])  # OpenCV
        depth = np.asarray(Image.open(folder / frame["depth_file_path"]), np.float64) * tr["depth_unit_scale_factor"]
        mask = np.asarray(Image.open(folder / frame["instance_mask_path"]))
        for v, u in rng.integers(0, RES, size=(150, 2)):
            ray = np.array([(u + 0.5 - tr["cx"]) / tr["fl_x"], (v + 0.5 - tr["cy"]) / tr["fl_y"], 1.0])
            direction = c2w[:3, :3] @ ray
            norm = np.linalg.norm(direction)
            dist = mujoco.mj_ray(comp.model, comp.data, c2w[:3, 3], direction / norm, groups, 1, -1, geomid)
            truth_depth = dist / norm if geomid[0] >= 0 else 0.0  # planar depth: distance over |ray| (z = 1)
            truth_id = int(comp.geom_instance[geomid[0]]) if geomid[0] >= 0 else 0
            total += 1
            if truth_depth > 0 and depth[v, u] > 0:
                hits += 1
                depth_err.append(abs(depth[v, u] - truth_depth))
            mask_wrong += int(mask[v, u] != truth_id)
    depth_err = np.asarray(depth_err)
    # silhouettes: a pixel centre a hair from an edge may fall either side in the rasteriser and the ray caster
    assert hits > 0.9 * total
    assert np.median(depth_err) < 1e-3 and (depth_err < 5e-3).mean() > 0.97
    assert mask_wrong < 0.03 * total
    # every object of scene.json is seen in some view's mask
    seen = set()
    for frame in tr["frames"]:
        seen |= set(np.unique(np.asarray(Image.open(folder / frame["instance_mask_path"]))).tolist())
    assert set(range(1, len(_meta(folder)["objects"]) + 1)) <= seen


def test_robot_base_and_gripper_as_simulated(dataset):
    """scene.json's robot_base is the simulated base body's pose (robosuite's frame: behind the table at -x,
    facing +x), and gripper_joints the simulated joints."""
    meta = _meta(dataset / "train" / "scene_00000")
    scene = _rebuild("train")
    m, d = scene.comp.model, scene.comp.data
    base = m.body("robot_base").id
    T = np.asarray(meta["robot_base"])
    np.testing.assert_allclose(T[:3, 3], d.xpos[base], atol=1e-9)
    np.testing.assert_allclose(T[:3, :3], d.xmat[base].reshape(3, 3), atol=1e-9)
    assert T[0, 3] < -meta["table_half_extent"][0] and abs(T[1, 3]) < 1e-9 and T[0, 0] == pytest.approx(1.0)
    assert meta["world_frame"] == "robosuite" and meta["generator"] == "particlesplat.data.families.robot_wide"
    joints = [d.qpos[m.jnt_qposadr[m.joint("robot_gripper_" + n).id]] for n in meta["gripper_joints"]]
    np.testing.assert_allclose(joints, list(meta["gripper_joints"].values()), atol=1e-12)


def test_scenes_respect_their_split_ranges(dataset):
    from particlesplat.data.families.robot_wide import HELDOUT, TRAIN

    for split, ranges, other in (("train", TRAIN, HELDOUT), ("heldout", HELDOUT, TRAIN)):
        meta = _meta(dataset / split / "scene_00000")
        assert meta["ranges"] == split and meta["gripper"] in ranges.grippers
        assert _inside(meta["distance"], ranges.arc_distance) and not _inside(meta["distance"], other.arc_distance)
        assert _inside(meta["elevation_deg"], ranges.arc_elevation)
        assert not _inside(meta["elevation_deg"], other.arc_elevation)
        kinds = {o["kind"] for o in meta["objects"]}
        assert kinds <= {*ranges.primitives, *ranges.asset_objects, *ranges.unseen}
        for obj in meta["objects"]:
            if obj["rgba"] is not None:
                assert _inside(_hue(obj["rgba"]), ranges.hues)
            if obj["texture"] is not None:
                assert obj["texture"] in ranges.textures
    assert {o["kind"] for o in _meta(dataset / "heldout" / "scene_00000")["objects"]} & set(HELDOUT.unseen)


def test_heldout_draws_are_disjoint_from_training_ranges():
    """Many draws of each split's cameras, objects and surfaces: the held-out ones never fall in a training
    range (colours, textures, grippers, shapes, camera distance and elevation), the training ones always do."""
    from particlesplat.data.families.robot_wide import (
        HELDOUT,
        TRAIN,
        draw_surface,
        draw_wide_cameras,
        object_drawer,
    )

    assert not set(HELDOUT.grippers) & set(TRAIN.grippers)
    assert not set(HELDOUT.textures) & set(TRAIN.textures)
    assert not set(HELDOUT.unseen) & {*TRAIN.primitives, *TRAIN.asset_objects}
    rng = np.random.default_rng(1)
    for ranges, other in ((TRAIN, HELDOUT), (HELDOUT, TRAIN)):
        draw = object_drawer(ranges)
        unseen_first = 0
        for _ in range(300):
            arc = draw_wide_cameras(rng, "arc", ranges)
            assert _inside(arc.distance, ranges.arc_distance) and not _inside(arc.distance, other.arc_distance)
            assert not _inside(arc.elevation_deg, other.arc_elevation)
            offset = np.linalg.norm(np.subtract(arc.look_at, (0.0, 0.0, 0.05)) * [1, 1, 2])
            assert ranges.look_at_offset[0] - 1e-9 <= offset <= ranges.look_at_offset[1] + 1e-9
            rig = draw_wide_cameras(rng, "rlbench", ranges)
            for eye, target in zip(rig.eyes, rig.targets, strict=True):
                dist = float(np.linalg.norm(np.subtract(eye, target)))
                assert _inside(dist, ranges.rig_distance) and not _inside(dist, other.rig_distance)
            obj = draw(rng, set())
            unseen_first += obj.kind in ranges.unseen
            if obj.rgba is not None:
                hue = _hue(obj.rgba)
                assert _inside(hue, ranges.hues) and not any(lo < hue < hi for lo, hi in other.hues)
            assert obj.texture is None or obj.texture in ranges.textures
            surface = draw_surface(rng, ranges)
            assert surface.texture is None or surface.texture in ranges.textures
        assert unseen_first == (300 if ranges is HELDOUT else 0)  # a held-out scene's first object is unseen


def test_deterministic_from_the_seed(dataset, tmp_path):
    """The same (seed, split, index) written again gives byte-identical files."""
    from particlesplat.data.families.robot_synth import generate

    again = tmp_path / "again"
    generate(again, {"train": 0, "heldout": 1}, seed=SEED, config=_config(), workers=1, progress=False, edits=())
    a, b = dataset / "heldout" / "scene_00000", again / "heldout" / "scene_00000"
    files = sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file())
    assert files and files == sorted(p.relative_to(b) for p in b.rglob("*") if p.is_file())
    for rel in files:
        assert (a / rel).read_bytes() == (b / rel).read_bytes(), rel
    # resuming writes nothing; the narrow world into a wide folder is refused, naming synth.json and the key
    assert generate(again, {"heldout": 1}, seed=SEED, config=_config(), workers=1, progress=False, edits=()) == []
    from particlesplat.core.errors import UserError
    from particlesplat.data.families.robot import RobotSceneConfig

    with pytest.raises(UserError, match="synth.json: key 'generator'"):
        generate(again, {"train": 1}, seed=SEED, config=RobotSceneConfig(RES, RES, views=VIEWS), workers=1)


def test_cli_split_writes_only_that_split(tmp_path):
    out = tmp_path / "w"
    argv = ["synth", "--family", "robot", "--world", "wide", str(out), "--split", "heldout", "--heldout", "1"]
    assert main([*argv, "--res", "32", "--workers", "1", "--cameras", "rlbench"]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["heldout", "synth.json"]
    scene = out / "heldout" / "scene_00000"
    meta = _meta(scene)
    assert meta["split"] == "heldout" and meta["gripper"] == "robotiq140" and len(meta["camera_eyes"]) == 4
    edit = json.loads((scene / "edits.json").read_text())
    if edit["object"] is not None:  # the edited scenes list their objects with the same keys
        moved = _meta(scene / "edits" / "move")["objects"]
        assert [o["rgba"] for o in moved] == [o["rgba"] for o in meta["objects"]]


def test_gripper_opens_and_closes_by_its_actuators():
    """The Panda gripper driven open and closed by robosuite's control mapping reaches its joint limits."""
    from particlesplat.data.families.robot import _settle
    from particlesplat.data.families.robot_assets import assets_dir, import_mujoco
    from particlesplat.data.families.robot_compose import PANDA_HOME, WorldSetup, compose
    from particlesplat.data.families.robot_grippers import GRIPPERS

    mujoco = import_mujoco()
    gripper = GRIPPERS["panda"]
    for opening, want in ((1.0, (0.04, -0.04)), (0.0, (0.0, 0.0))):
        comp = compose(mujoco, assets_dir(), [], [], (8, 8), WorldSetup("robosuite", "panda"))
        ctrl = gripper.controls(comp.model.actuator_ctrlrange[comp.gripper_actuators], opening)
        np.testing.assert_allclose(ctrl, want, atol=1e-12)  # robosuite: bias + weight * formatted action
        comp.data.ctrl[comp.gripper_actuators] = ctrl
        comp.data.qpos[comp.finger_qpos] = (0.02, -0.02)
        # no objects: _settle returns once the fingers rest
        _settle(mujoco, comp, np.asarray(PANDA_HOME), fingers=None)
        np.testing.assert_allclose(comp.data.qpos[comp.finger_qpos], want, atol=2e-3)


def test_cli_refuses_heldout_outside_the_wide_world(tmp_path):
    from particlesplat.core.errors import OptionError

    for family in (["--family", "tabletop"], ["--family", "robot", "--world", "narrow"]):
        with pytest.raises(OptionError, match="--heldout: only the robot family's wide world"):
            main(["synth", str(tmp_path / "t"), *family, "--train", "0", "--test", "0", "--heldout", "1"])
    assert not (tmp_path / "t").exists()


# ------------------------------------------------------------------------------------------ scene check
def test_scene_check_accepts_a_wide_scene(dataset, capsys):
    assert main(["scene", "check", str(dataset / "train" / "scene_00000")]) == 0
    out = capsys.readouterr().out
    assert "robot family" in out and "robot training scenes' are 0.8-1.25 m: ok" in out
    assert "from the scene.json robot_base), at -x" in out


@pytest.mark.parametrize("turn", [90.0, -90.0, 35.0])
def test_scene_check_finds_a_turned_robot_scene_and_turns_it_back(dataset, tmp_path, capsys, turn):
    """The world turned about z (cameras turned, images unchanged) and robot_base dropped: the turn is measured
    from the depth, and the written transforms.json turns the cameras back."""
    src = dataset / "train" / "scene_00000"
    bad = tmp_path / "turned"
    shutil.copytree(src, bad)
    meta = _meta(bad)
    meta.pop("robot_base")
    (bad / "scene.json").write_text(json.dumps(meta))
    c, s = math.cos(math.radians(turn)), math.sin(math.radians(turn))
    Rz = np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])
    tr = json.loads((src / "transforms.json").read_text())
    for frame in tr["frames"]:
        frame["transform_matrix"] = (Rz @ np.asarray(frame["transform_matrix"])).tolist()
    (bad / "transforms.json").write_text(json.dumps(tr))
    fixed = tmp_path / "fixed.json"
    assert main(["scene", "check", str(bad), "--write", str(fixed)]) == 1
    out = capsys.readouterr().out
    measured = re.search(r"turned ([+-]\d+) degrees about z", out)
    assert measured and abs(float(measured.group(1)) - turn) <= 3.0, out
    back = np.array([f["transform_matrix"] for f in json.loads(fixed.read_text())["frames"]])
    orig = np.array([f["transform_matrix"] for f in json.loads((src / "transforms.json").read_text())["frames"]])
    np.testing.assert_allclose(back[:, :3, :3], orig[:, :3, :3], atol=0.04)  # within the measurement's ~2 degrees
    np.testing.assert_allclose(back[:, :3, 3], orig[:, :3, 3], atol=0.05)
