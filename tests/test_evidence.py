"""Foreground evidence from depth and the arm's kinematics, checked against the simulator's object masks on
generated wide-world scenes; and a model that reads the workspace from its views (``fg_evidence``,
``canonical_frame``) renders a scene turned about z as it renders the scene itself."""

from __future__ import annotations

import importlib.util
import json
import math
from pathlib import Path

import pytest
import torch

from particlesplat.core.camera import Camera
from particlesplat.core.panda_arm import ARM_STATE_KEY, pack_arm_state
from particlesplat.data.scene import load_scene
from particlesplat.model import ModelConfig
from particlesplat.model.evidence import canonical_turn, foreground_evidence
from particlesplat.model.particlesplat import ParticleSplat
from particlesplat.rendering.api import render

if importlib.util.find_spec("mujoco") is None or importlib.util.find_spec("robosuite") is None:
    pytest.skip("the wide robot world needs the sim extra", allow_module_level=True)

RES = 96
VIEWS = 6


@pytest.fixture(scope="module")
def scenes(tmp_path_factory) -> list[Path]:
    from particlesplat.data.families.robot import RobotSceneConfig
    from particlesplat.data.families.robot_synth import generate

    out = tmp_path_factory.mktemp("wide") / "data"
    config = RobotSceneConfig(RES, RES, views=VIEWS, world="wide")  # type: ignore[arg-type]
    generate(
        out,
        {"train": 2, "val": 0, "test": 0, "heldout": 1},
        seed=11,
        config=config,
        workers=1,
        progress=False,
        edits=(),
    )
    return sorted(out.glob("*/scene_*"))


def _state(folder: Path) -> torch.Tensor:
    meta = json.loads((folder / "scene.json").read_text())
    return torch.tensor(pack_arm_state(meta["arm_joints_rad"], meta.get("robot_base"), meta.get("gripper")))


def _turn(angle: float) -> torch.Tensor:
    c, s = math.cos(angle), math.sin(angle)
    t = torch.eye(4)
    t[:2, :2] = torch.tensor([[c, -s], [s, c]])
    return t


def _turned_state(state: torch.Tensor, turn: torch.Tensor) -> torch.Tensor:
    base = torch.eye(4)
    base[:3] = state[7:19].reshape(3, 4)
    out = state.clone()
    out[7:19] = (turn @ base)[:3].reshape(-1)
    return out


def test_evidence_finds_the_objects_and_leaves_the_arm_out(scenes):
    """Against the simulator's object masks (the arm, table, floor and walls are background there): at least
    90 % of the evidence pixels are objects' and at least 70 % of the objects' pixels are evidence; without the
    arm's state, much of the arm counts."""
    hits = evidence_px = object_px = arm_px = 0
    for folder in scenes:
        sc = load_scene(folder)
        state = _state(folder)[None].expand(sc.num_views, -1)
        ev = foreground_evidence(sc.depth, sc.K(), sc.c2w(), state)[:, 0] > 0
        blind = foreground_evidence(sc.depth, sc.K(), sc.c2w(), None)[:, 0] > 0
        obj = sc.masks > 0
        hits += int((ev & obj).sum())
        evidence_px += int(ev.sum())
        object_px += int(obj.sum())
        arm_px += int((blind & ~obj).sum())
    assert hits / evidence_px >= 0.9
    assert hits / object_px >= 0.7
    assert arm_px > 0.2 * hits  # what the arm's kinematics take out


def test_evidence_is_unchanged_by_a_turn_of_the_world(scenes):
    sc = load_scene(scenes[0])
    state = _state(scenes[0])
    turn = _turn(1.1)
    ev = foreground_evidence(sc.depth, sc.K(), sc.c2w(), state[None].expand(sc.num_views, -1))
    turned = foreground_evidence(
        sc.depth, sc.K(), turn @ sc.c2w(), _turned_state(state, turn)[None].expand(sc.num_views, -1)
    )
    assert float((ev != turned).float().mean()) < 1e-3


def test_canonical_turn_undoes_a_turn_about_z():
    g = torch.Generator().manual_seed(0)
    c2w = torch.eye(4).repeat(3, 2, 1, 1)
    c2w[..., :3, :3] = torch.linalg.qr(torch.randn(3, 2, 3, 3, generator=g))[0]
    c2w[..., :3, 3] = torch.randn(3, 2, 3, generator=g)
    turn = _turn(-2.3)
    a = canonical_turn(c2w)[:, None] @ c2w
    b = canonical_turn(turn @ c2w)[:, None] @ (turn @ c2w)
    torch.testing.assert_close(a, b, atol=1e-5, rtol=0)


def _model() -> ParticleSplat:
    torch.manual_seed(0)
    cfg = ModelConfig(
        resolution=RES,
        particles_per_view=4,
        channels=8,
        d_obj=16,
        d_bg=4,
        bg_latent_stride=2,
        bg_block=2,
        bg_static_grid=0,
        bg_per_view=True,
        fg_evidence=True,
        canonical_frame=True,
        bg_static_pose=ARM_STATE_KEY,
        bg_static_pose_dims=21,
        patch_gaussians=4,
        patch_base=4,
        patch_channels=8,
        patch_hidden=16,
        refine_steps=0,
        token_dim=16,
        d_min=0.3,
        d_max=5.0,
        support_clamp=True,
    )
    return ParticleSplat(cfg).eval()


def test_a_model_that_reads_its_views_renders_a_turned_scene_alike(scenes):
    """A scene whose world frame is turned about z (cameras and robot base turned, images unchanged) renders the
    same images from the turned target cameras: a pixel differs by at most 1e-3."""
    model = _model()
    sc = load_scene(scenes[-1])
    ctx, tgt = [0, 3], [1, 4]
    state = _state(scenes[-1])
    for angle in (math.pi / 2, 2.0):
        turn = _turn(angle)
        images = []
        for c2w, st in ((sc.c2w(), state), (turn @ sc.c2w(), _turned_state(state, turn))):
            cams = [Camera(sc.K()[i], c2w[i], RES, RES) for i in range(sc.num_views)]
            with torch.no_grad():
                p = model.encode(sc.rgb[ctx], sc.depth[ctx], [cams[i] for i in ctx], st)
                g = model.decode(p, z_t_threshold=0.0)
            images.append(torch.stack([render(g, cams[i], background=(0.3, 0.3, 0.3)).rgb for i in tgt]))
        assert float((images[0] - images[1]).abs().max()) < 1e-3


def test_training_an_evidence_model_and_encoding_flags_the_robot(scenes, tmp_path):
    """Two training steps of a model that reads the robot state: the one-sided foreground term is logged, finite
    and at most one per pixel of the views; the checkpoint records the robot state's trained range; ``encode``
    writes a robot array, and no particle the arm holds is in an object."""
    import yaml

    from particlesplat.analysis.particle_arrays import ParticleArrays
    from particlesplat.cli.main import main

    data = scenes[0].parent.parent
    model = _model().config
    config = {
        "model": {**{k: getattr(model, k) for k in model.__dataclass_fields__}},
        "train": {
            "steps": 2,
            "batch_size": 1,
            "target_views": 1,
            "val_every": 5,
            "beta_fg": 1.0,
            "log_every": 1,
            "particles_per_view": 2,
            "num_threads": 1,
            "ckpt_every": 1,
        },
    }
    cfg = tmp_path / "tiny.yaml"
    cfg.write_text(yaml.safe_dump(config))
    run = tmp_path / "run"
    assert main(["train", "--config", str(cfg), "--data", str(data), "--out", str(run)]) == 0
    rows = [json.loads(ln) for ln in (run / "metrics.jsonl").read_text().splitlines()]
    fg = [r["fg"] for r in rows if "fg" in r]
    assert len(fg) == 2 and all(0.0 <= v <= 3 * RES * RES for v in fg)
    ckpt = torch.load(run / "last.pt", weights_only=True)
    assert len(ckpt["input_ranges"][ARM_STATE_KEY]["min"]) == 21
    out = tmp_path / "particles"
    assert main(["encode", "--checkpoint", str(run / "last.pt"), "--data", str(scenes[0]), "--out", str(out)]) == 0
    arrays = ParticleArrays.load(next(out.rglob("*.npz")))
    assert arrays.robot.shape == arrays.active.shape
    assert not bool((arrays.object[arrays.robot] >= 0).any())


def test_anchored_background_gaussians_lie_flat_on_the_surface_they_see():
    """A camera 45° above a plane z = 0, anchors at the plane's exact depths: every background Gaussian sits on the
    plane (to 1 mm), its thinnest axis along z, and its in-plane spread spans the step to the next block (no gaps
    seen from above: the largest in-plane standard deviation is at least a third of the block spacing there)."""
    from particlesplat.model.decoder import background_gaussians, block_anchors, gaussian_channels

    res, k = 32, 2
    cfg = ModelConfig(
        resolution=res,
        bg_block=k,
        bg_latent_stride=k,
        bg_per_view=True,
        bg_static_grid=0,
        fg_evidence=True,
        d_min=0.3,
        d_max=5.0,
    )
    K = torch.tensor([[[40.0, 0, 16], [0, 40.0, 16], [0, 0, 1]]])
    a = math.radians(45)
    R = torch.tensor([[1.0, 0, 0], [0, -math.sin(a), -math.cos(a)], [0, math.cos(a), -math.sin(a)]])
    c2w = torch.eye(4)[None]
    c2w[0, :3, :3] = R
    c2w[0, :3, 3] = torch.tensor([0.0, -1.0, 1.0])
    v, u = torch.meshgrid(torch.arange(res) + 0.5, torch.arange(res) + 0.5, indexing="ij")
    rays = torch.stack([(u - 16) / 40, (v - 16) / 40, torch.ones_like(u)], -1) @ R.T  # world dirs, camera z = 1
    depth = (1.0 / -rays[..., 2])[None, None]  # planar depth where each pixel's ray meets z = 0
    anchor = block_anchors(torch.full((1, 3, res, res), 0.5), depth, torch.zeros(1, 1, res, res), k)
    n = (res // k) ** 2
    raw = torch.zeros(1, n, gaussian_channels(0))
    raw[..., 6] = 1.0  # identity quaternion (unused by anchored shapes)
    g = background_gaussians(raw, K, c2w, cfg, anchor.flatten(2).transpose(1, 2))
    assert float(g["means"][..., 2].abs().max()) < 1e-3  # a block's mean depth: within a millimetre
    from particlesplat.model.geometry import quaternion_to_rotation_matrix

    axes = quaternion_to_rotation_matrix(g["quats"][0])  # (n, 3, 3), columns the axes
    thin = g["scales"][0].argmin(-1)
    normal = axes[torch.arange(n), :, thin]
    assert float(normal[:, 2].abs().min()) > 0.99
    spacing = (depth[0, 0, 0, 0] * k / 40.0).item()  # the nearest block's width on the plane, at least
    assert float(g["scales"][0].max(-1).values.min()) > spacing / 3


def test_eval_turn_scores_a_turned_world_alike_for_a_model_that_reads_its_views(scenes, tmp_path):
    """``eval --turn 90`` turns cameras, robot base and object centres: the evidence model's PSNR and FG-ARI are
    unchanged (to float rounding), and the turn is recorded in the JSON."""
    from particlesplat.analysis.evaluate import evaluate_dataset

    model = _model()
    split = scenes[0].parent
    plain = evaluate_dataset(model, split, progress_bar=False, z_t_threshold=0.0)
    turned = evaluate_dataset(model, split, progress_bar=False, z_t_threshold=0.0, turn=90.0)
    assert turned["turn_deg"] == 90.0
    assert abs(plain["mean"]["psnr"] - turned["mean"]["psnr"]) < 0.01
    assert abs(plain["mean"]["fg_ari"] - turned["mean"]["fg_ari"]) < 0.01


def test_turn_item_turns_cameras_and_the_robot_base_only():
    from particlesplat.analysis.world_turn import turn_item, turn_matrix, turn_points

    state = torch.tensor(pack_arm_state([0.1] * 7, None, "panda"))
    item = {"context_c2w": torch.eye(4)[None], "target_c2w": torch.eye(4)[None], "pose": state}
    out = turn_item(item, 90.0, ARM_STATE_KEY)
    torch.testing.assert_close(out["context_c2w"][0], turn_matrix(90.0).float())
    torch.testing.assert_close(out["pose"][:7], state[:7])
    assert out["pose"][7 + 3].item() == pytest.approx(0.0, abs=1e-6)  # base x: -0.56 turned onto -y
    assert out["pose"][7 + 7].item() == pytest.approx(-0.56, abs=1e-6)
    assert turn_points(None, 30.0) is None


def test_evidence_error_weighs_the_miss_and_the_overhang():
    """One view of 4 pixels, evidence on the first two: weight 0.5 on each gives 2 x 0.25 on the evidence plus
    outside x 2 x 0.25 beyond it."""
    from particlesplat.training.loss import evidence_error

    fg = torch.full((1, 1, 2, 2), 0.5)
    ev = torch.tensor([[[[1.0, 1.0], [0.0, 0.0]]]])
    assert evidence_error(fg, ev, 0.0).item() == pytest.approx(0.5)
    assert evidence_error(fg, ev, 0.25).item() == pytest.approx(0.5 + 0.125)
    assert evidence_error(ev, ev, 1.0).item() == 0.0
