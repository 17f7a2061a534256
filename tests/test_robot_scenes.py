"""Robot-workspace scenes (MuJoCo + robosuite's asset files): a tiny generated scene checked against independent
truth (depth re-projected between views with kornia, object centres against masks, the ground-truth move), the
loader reading it, and the one-line errors when the extra, the asset folder or GL is missing."""

from __future__ import annotations

import importlib.util
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from particlesplat.data import load_scene
from particlesplat.data.families.robot_assets import INSTALL, SimSetupError, assets_dir

if importlib.util.find_spec("mujoco") is None or importlib.util.find_spec("robosuite") is None:
    pytest.skip(f"robot scenes need the sim extra: {INSTALL}", allow_module_level=True)

kornia = pytest.importorskip("kornia")

RES = 64
VIEWS = 5


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    from particlesplat.data.families.robot import RobotSceneConfig
    from particlesplat.data.families.robot_synth import generate

    out = tmp_path_factory.mktemp("robot") / "data"
    cfg = RobotSceneConfig(RES, RES, views=VIEWS)
    times = generate(out, {"train": 0, "val": 0, "test": 1}, seed=3, config=cfg, workers=1, progress=False)
    assert len(times) == 1
    return out


@pytest.fixture(scope="module")
def scene_dir(dataset) -> Path:
    return dataset / "test" / "scene_00000"


def _frames(folder: Path) -> tuple[dict, list[np.ndarray]]:
    """transforms.json and the (4, 4) OpenCV camera-to-world of each frame, read straight from the file."""
    tr = json.loads((folder / "transforms.json").read_text())
    flip = np.diag([1.0, -1.0, -1.0, 1.0])
    return tr, [np.asarray(f["transform_matrix"]) @ flip for f in tr["frames"]]


def _K(tr: dict) -> torch.Tensor:
    """Intrinsics for kornia, whose pixel grid has pixel centres at integers (ours at u + 0.5)."""
    return torch.tensor(
        [[tr["fl_x"], 0.0, tr["cx"] - 0.5], [0.0, tr["fl_y"], tr["cy"] - 0.5], [0.0, 0.0, 1.0]], dtype=torch.float64
    )


def _load(folder: Path, i: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    from PIL import Image

    tr = json.loads((folder / "transforms.json").read_text())
    f = tr["frames"][i]
    rgb = np.asarray(Image.open(folder / f["file_path"]), dtype=np.float64) / 255.0
    depth = np.asarray(Image.open(folder / f["depth_file_path"]), dtype=np.float64) * tr["depth_unit_scale_factor"]
    mask = np.asarray(Image.open(folder / f["instance_mask_path"]))
    return rgb, depth, mask


def test_scene_json_and_loader(scene_dir):
    meta = json.loads((scene_dir / "scene.json").read_text())
    assert meta["family"] == "robot" and meta["support_z"] == 0.0
    assert 2 <= len(meta["objects"]) <= 5
    for k, obj in enumerate(meta["objects"], start=1):
        assert obj["id"] == k
        lo, hi, c = (np.asarray(obj[key]) for key in ("aabb_min", "aabb_max", "center"))
        assert np.allclose(c, (lo + hi) / 2) and abs(lo[2]) < 0.01  # resting on the table top z = 0
        assert np.all(np.abs(c[:2]) < meta["table_half_extent"][0])
    scene = load_scene(scene_dir)
    assert scene.rgb.shape == (VIEWS, 3, RES, RES) and scene.depth is not None and scene.masks is not None
    from particlesplat.core.camera import Camera

    for cam, az in zip(scene.cameras, meta["azimuths_deg"], strict=True):
        want = Camera.orbit(
            meta["look_at"],
            az,
            meta["elevation_deg"],
            meta["distance"],
            fov_y_deg=meta["fov_y_deg"],
            width=RES,
            height=RES,
        )
        assert torch.allclose(cam.c2w.double(), want.c2w.double(), atol=1e-5)
        assert torch.allclose(cam.K.double(), want.K.double(), atol=1e-4)
        assert (
            abs(
                float(torch.linalg.norm(cam.center.double() - torch.tensor(meta["look_at"]).double()))
                - meta["distance"]
            )
            < 1e-5
        )


def test_depth_reprojects_between_views(scene_dir):
    """Back-project view a's depth and project it into view b: where b sees the same surface, colour and mask
    agree (kornia's pinhole geometry, on the raw transforms.json values)."""
    tr, c2ws = _frames(scene_dir)
    K = _K(tr)
    for a, b in [(1, 2), (2, 3)]:
        rgb_a, depth_a, mask_a = _load(scene_dir, a)
        rgb_b, depth_b, mask_b = _load(scene_dir, b)
        d = torch.from_numpy(depth_a)[None, None]
        pts_cam = kornia.geometry.depth.depth_to_3d_v2(d[:, 0], K[None]).reshape(-1, 3)  # (H*W, 3) camera a frame
        valid = d.reshape(-1) > 0
        a2b = torch.from_numpy(np.linalg.inv(c2ws[b]) @ c2ws[a])
        pts_b = kornia.geometry.linalg.transform_points(a2b[None], pts_cam[None])[0]
        uv = kornia.geometry.camera.perspective.project_points(pts_b, K)  # pixel centres at integers
        u, v = torch.round(uv[:, 0]).long(), torch.round(uv[:, 1]).long()
        inside = valid & (pts_b[:, 2] > 0) & (u >= 0) & (u < RES) & (v >= 0) & (v < RES)
        idx = torch.nonzero(inside)[:, 0]
        z_seen = torch.from_numpy(depth_b)[v[idx], u[idx]]
        same = (z_seen - pts_b[idx, 2]).abs() < 0.005 + 0.01 * pts_b[idx, 2]  # visible in b, not occluded
        assert int(same.sum()) > 0.3 * RES * RES
        src, dst = idx[same], (v[idx][same], u[idx][same])
        ma, mb = (
            torch.from_numpy(mask_a.astype(np.int64)).reshape(-1)[src],
            torch.from_numpy(mask_b.astype(np.int64))[dst],
        )
        assert float((ma == mb).double().mean()) > 0.97
        ca = torch.from_numpy(rgb_a).reshape(-1, 3)[src]
        cb = torch.from_numpy(rgb_b)[dst]
        assert float((ca - cb).abs().mean(1).median()) < 0.05  # specular highlights differ; most surfaces agree
        for k in np.unique(mask_a)[1:]:  # every object seen in a and b lands on itself
            sel = ma == int(k)
            if int(sel.sum()) >= 3:
                assert float((mb[sel] == int(k)).double().mean()) > 0.8


def test_object_centres_land_on_their_masks(scene_dir):
    meta = json.loads((scene_dir / "scene.json").read_text())
    tr, c2ws = _frames(scene_dir)
    K = _K(tr)
    hits = 0
    for i in range(VIEWS):
        _, depth, mask = _load(scene_dir, i)
        w2c = torch.from_numpy(np.linalg.inv(c2ws[i]))
        for obj in meta["objects"]:
            p = kornia.geometry.linalg.transform_points(
                w2c[None], torch.tensor([[obj["center"]]], dtype=torch.float64)
            )[0]
            u, v = (int(round(float(x))) for x in kornia.geometry.camera.perspective.project_points(p, K)[0])
            assert 0 <= u < RES and 0 <= v < RES
            if mask[v, u] == obj["id"]:
                hits += 1
            else:  # hidden: something nearer the camera covers the centre (the arm, another object)
                assert 0 < depth[v, u] < float(p[0, 2]), (i, obj["name"], mask[v, u])
    assert hits >= 0.6 * VIEWS * len(meta["objects"])


def test_ground_truth_edits(scene_dir):
    edits = json.loads((scene_dir / "edits.json").read_text())
    k, off = edits["object"], np.asarray(edits["offset"])
    assert 0.10 - 1e-9 <= float(np.linalg.norm(off[:2])) <= 0.20 + 1e-9 and off[2] == 0.0
    orig = json.loads((scene_dir / "scene.json").read_text())["objects"]
    moved = json.loads((scene_dir / edits["move"] / "scene.json").read_text())["objects"]
    removed = json.loads((scene_dir / edits["remove"] / "scene.json").read_text())["objects"]
    for a, b in zip(orig, moved, strict=True):
        shift = off if a["id"] == k else np.zeros(3)
        for key in ("center", "aabb_min", "aabb_max"):
            assert np.allclose(np.asarray(b[key]), np.asarray(a[key]) + shift, atol=1e-9), (a["name"], key)
        assert np.allclose(b["pose"]["quaternion_wxyz"], a["pose"]["quaternion_wxyz"])
    assert [o["id"] for o in removed] == [o["id"] for o in orig if o["id"] != k]
    tr, c2ws = _frames(scene_dir)
    K = _K(tr)
    for i in range(VIEWS):
        _, _, m0 = _load(scene_dir, i)
        _, _, mm = _load(scene_dir / edits["move"], i)
        _, _, mr = _load(scene_dir / edits["remove"], i)
        assert not (mr == k).any()
        others = (m0 > 0) & (m0 != k)
        assert float((mr[others] == m0[others]).mean()) > 0.95  # the rest of the scene stays where it was
        if (mm == k).sum() >= 4:  # the moved object's pixels sit where its new centre projects
            w2c = torch.from_numpy(np.linalg.inv(c2ws[i]))
            c = torch.from_numpy((np.asarray(orig[k - 1]["center"]) + off)[None, None])
            uv = kornia.geometry.camera.perspective.project_points(
                kornia.geometry.linalg.transform_points(w2c[None], c)[0], K
            )
            ys, xs = np.nonzero(mm == k)
            assert math.hypot(xs.mean() - float(uv[0, 0]), ys.mean() - float(uv[0, 1])) < 0.25 * RES


def test_ground_truth_lift(scene_dir):
    """The lift: the moved object raised straight up by the recorded height (0.15 m where nothing is in the way),
    the rest of the scene exactly as it was; its depth puts the object's pixels at the lifted box's heights, and
    its mask shows it where its lifted centre projects, higher in every image than where it stood."""
    edits = json.loads((scene_dir / "edits.json").read_text())
    k, h = edits["object"], edits["lift_height"]
    assert edits["lift"] == "edits/lift" and h == 0.15  # this scene's object has room above it
    orig = json.loads((scene_dir / "scene.json").read_text())["objects"]
    lifted_json = json.loads((scene_dir / edits["lift"] / "scene.json").read_text())
    assert lifted_json["edit"] == "lift" and lifted_json["lift_height"] == h
    lifted = lifted_json["objects"]
    for a, b in zip(orig, lifted, strict=True):
        shift = np.array([0.0, 0.0, h]) if a["id"] == k else np.zeros(3)
        for key in ("center", "aabb_min", "aabb_max"):
            assert np.allclose(np.asarray(b[key]), np.asarray(a[key]) + shift, rtol=0.0, atol=1e-12), (a["name"], key)
        assert b["pose"]["quaternion_wxyz"] == a["pose"]["quaternion_wxyz"]
    lo, hi = np.asarray(lifted[k - 1]["aabb_min"]), np.asarray(lifted[k - 1]["aabb_max"])
    tr, c2ws = _frames(scene_dir)
    K = _K(tr)
    rose = 0
    for i in range(VIEWS):
        _, _, m0 = _load(scene_dir, i)
        _, depth, ml = _load(scene_dir / edits["lift"], i)
        others = (m0 > 0) & (m0 != k) & (ml != k)  # not hidden behind the lifted object
        assert float((ml[others] == m0[others]).mean()) > 0.95
        sel = ml == k
        if sel.sum() < 4:
            continue
        pts = kornia.geometry.depth.depth_to_3d_v2(torch.from_numpy(depth)[None], K[None])[0][torch.from_numpy(sel)]
        world = kornia.geometry.linalg.transform_points(torch.from_numpy(c2ws[i])[None], pts[None])[0].numpy()
        # in the air at the lifted box's heights, not on the table
        assert (world[:, 2] > lo[2] - 0.005).all() and (world[:, 2] < hi[2] + 0.005).all()
        w2c = torch.from_numpy(np.linalg.inv(c2ws[i]))
        uv = kornia.geometry.camera.perspective.project_points(
            kornia.geometry.linalg.transform_points(w2c[None], torch.from_numpy(((lo + hi) / 2)[None, None]))[0], K
        )
        ys, xs = np.nonzero(sel)
        assert math.hypot(xs.mean() - float(uv[0, 0]), ys.mean() - float(uv[0, 1])) < 0.25 * RES
        if (m0 == k).sum() >= 4:
            assert ys.mean() < np.nonzero(m0 == k)[0].mean()  # the object's pixels moved up in the image
            rose += 1
    assert rose >= 2


def _stacked_boxes(gap: float | None):
    """A settled-scene stand-in: the arm at home and two 6 cm boxes at rest on the table, the second (when ``gap``
    is given) hanging ``gap`` metres straight above the first instead."""
    from particlesplat.data.families.robot import (
        PANDA_HOME,
        RobotSceneConfig,
        SettledScene,
        camera_poses,
        draw_cameras,
        object_states,
    )
    from particlesplat.data.families.robot_assets import import_mujoco
    from particlesplat.data.families.robot_compose import ObjectSpec, compose

    mujoco = import_mujoco()
    cfg = RobotSceneConfig(RES, RES, views=2)
    arc = draw_cameras(np.random.default_rng(0), "arc", 2)
    half = (0.03, 0.03, 0.03)
    specs = [ObjectSpec("box", x, -0.2, 0.0, half, tex) for x, tex in ((-0.25, "red-wood"), (0.1, "blue-wood"))]
    comp = compose(mujoco, assets_dir(), specs, camera_poses(arc.cameras(RES, RES), mujoco), (RES, RES))
    for adr, spec in zip(comp.object_qpos, specs, strict=True):
        comp.data.qpos[adr : adr + 7] = (spec.x, spec.y, half[2], 1.0, 0.0, 0.0, 0.0)
    if gap is not None:
        comp.data.qpos[comp.object_qpos[1] : comp.object_qpos[1] + 3] = (-0.25, -0.2, 3 * half[2] + gap)
    comp.data.qpos[comp.arm_qpos] = PANDA_HOME
    mujoco.mj_forward(comp.model, comp.data)
    return mujoco, SettledScene(comp, object_states(comp, specs), specs, np.asarray(PANDA_HOME), arc, cfg)


def test_lift_is_lowered_under_an_obstacle_and_skipped_without_room():
    """0.15 m with nothing above; under a box hanging 0.125 m above its top, the highest 1 cm step below it
    (0.12 m); under one 0.05 m above, no lift (and the edit then has none to render). The scene is left as it was."""
    from particlesplat.data.families.robot import GroundTruthEdit, apply_edit, lift_height

    for gap, want in ((None, 0.15), (0.125, 0.12), (0.05, None)):
        mujoco, scene = _stacked_boxes(gap)
        before = scene.comp.data.qpos.copy()
        assert lift_height(mujoco, scene, 1) == want, gap
        assert np.array_equal(scene.comp.data.qpos, before)
    edit = GroundTruthEdit(1, "box", (0.1, 0.0, 0.0), None)
    assert edit.kinds == ("move", "remove")
    assert edit.to_json()["lift"] is None and edit.to_json()["lift_height"] is None
    assert "lift" not in edit.to_json("move") and "lift_height" not in edit.to_json("remove")
    with pytest.raises(ValueError, match="no room to be lifted"):
        apply_edit(mujoco, scene, edit, "lift")


def test_resume_skips_and_deterministic(dataset, tmp_path):
    from particlesplat.data.families.robot import RobotSceneConfig
    from particlesplat.data.families.robot_synth import generate

    cfg = RobotSceneConfig(RES, RES, views=VIEWS)
    assert generate(dataset, {"train": 0, "val": 0, "test": 1}, 3, cfg, workers=1, progress=False) == []
    with pytest.raises(ValueError, match="seed"):
        generate(dataset, {"train": 0, "val": 0, "test": 1}, 4, cfg, workers=1, progress=False)
    again = tmp_path / "again"
    generate(again, {"train": 0, "val": 0, "test": 1}, 3, cfg, workers=1, progress=False)
    a, b = dataset / "test" / "scene_00000", again / "test" / "scene_00000"
    assert (a / "scene.json").read_text() == (b / "scene.json").read_text()
    assert (a / "masks" / "002.png").read_bytes() == (b / "masks" / "002.png").read_bytes()


def test_arm_still_is_the_home_scene_with_the_arm_exactly_home(dataset, tmp_path):
    from particlesplat.data.families.robot import PANDA_HOME, RobotSceneConfig
    from particlesplat.data.families.robot_synth import generate

    cfg = RobotSceneConfig(RES, RES, views=VIEWS, arm="still")
    generate(tmp_path, {"train": 0, "val": 0, "test": 1}, 3, cfg, workers=1, progress=False)
    home = json.loads((dataset / "test" / "scene_00000" / "scene.json").read_text())
    still = json.loads((tmp_path / "test" / "scene_00000" / "scene.json").read_text())
    assert np.allclose(still["arm_joints_rad"], PANDA_HOME) and not np.allclose(home["arm_joints_rad"], PANDA_HOME)
    assert [o["name"] for o in still["objects"]] == [o["name"] for o in home["objects"]]
    assert still["azimuths_deg"] == home["azimuths_deg"] and still["distance"] == home["distance"]


def test_missing_asset_folder_and_extra_are_one_line(tmp_path, monkeypatch):
    with pytest.raises(SimSetupError) as e:
        assets_dir(tmp_path / "no-such-assets")
    assert "\n" not in str(e.value) and "arenas/table_arena.xml" in str(e.value) and INSTALL in str(e.value)
    monkeypatch.delenv("PARTICLESPLAT_ROBOSUITE_ASSETS", raising=False)
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "robosuite" else real(name, *a))
    with pytest.raises(SimSetupError) as e:
        assets_dir()
    assert "\n" not in str(e.value) and INSTALL in str(e.value)


@pytest.mark.parametrize(
    ("env", "needle"),
    [
        ({"PARTICLESPLAT_ROBOSUITE_ASSETS": "/no/such/folder"}, "robosuite asset folder lacks"),
        ({"MUJOCO_GL": "osmesa"}, "headless GL"),
    ],
)
def test_generate_bad_setup_is_one_line(tmp_path, env, needle):
    """A child process (the GL backend is fixed at import): one line on stderr naming what to install."""
    code = (
        "import sys; from pathlib import Path\n"
        "from particlesplat.core.errors import run_command\n"
        "from particlesplat.data.families.robot import RobotSceneConfig\n"
        "from particlesplat.data.families.robot_synth import generate\n"
        "sys.exit(run_command('particlesplat synth', lambda: generate(Path(sys.argv[1]), {'train': 1}, 0, "
        "RobotSceneConfig(16, 16, views=1), workers=1, progress=False) and 0))\n"
    )
    import os

    proc = subprocess.run(
        [sys.executable, "-c", code, str(tmp_path / "out")],
        env={**os.environ, **env},
        capture_output=True,
        text=True,
        timeout=300,
    )
    if env.get("MUJOCO_GL") == "osmesa" and proc.returncode == 0:
        pytest.skip("this machine has OSMesa: MUJOCO_GL=osmesa works")
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and needle in lines[0], proc.stderr


def test_cli_robot_family_bad_assets_one_line(tmp_path):
    import os

    proc = subprocess.run(
        [sys.executable, "-m", "particlesplat.cli", "synth", "--family", "robot", str(tmp_path / "o"), "--train", "1"],
        env={**os.environ, "PARTICLESPLAT_ROBOSUITE_ASSETS": str(tmp_path / "missing")},
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and INSTALL in lines[0] and not (tmp_path / "o").exists()


def test_a_narrow_scene_records_its_robot_base_and_an_older_one_gets_it(scene_dir, tmp_path):
    """The narrow world's scene.json records the robot base the simulator placed (at +y, facing -y, its frame
    turned from robosuite's), so a model reading the robot's state places the arm where MuJoCo drew it; a scene
    written before the key was recorded gets the same base from its generator's name."""
    import shutil

    from particlesplat.core.panda_arm import link_frames
    from particlesplat.data.scene_meta import read_arm_state

    meta = json.loads((scene_dir / "scene.json").read_text())
    base = np.array(meta["robot_base"])
    assert np.allclose(base[:3, 3], [0.0, 0.56, 0.0]) and np.allclose(base[:3, 0], [0.0, -1.0, 0.0], atol=1e-12)
    # the hand by forward kinematics from that base lies over the table near the base's side, as drawn
    hand = link_frames(meta["arm_joints_rad"], base)[-1, :3, 3]
    assert hand[1] > 0.0 and hand[2] > 0.0
    older = tmp_path / "older"
    shutil.copytree(scene_dir, older)
    del meta["robot_base"]
    (older / "scene.json").write_text(json.dumps(meta))
    assert read_arm_state(older) == pytest.approx(read_arm_state(scene_dir), abs=1e-12)
