"""The workspace layer (a static background anywhere in space, found in the training data without labels), the
support clamp (no particle Gaussian under the surface objects rest on), the skirt metric, and the robot recipe."""

from __future__ import annotations

import dataclasses
import json
import re

import numpy as np
import pytest
import torch
import yaml
from model_data import TINY_MODEL, tiny_config, tiny_dataset

from particlesplat.analysis.metrics import SKIRT_MARGIN, below_support
from particlesplat.cli.main import main
from particlesplat.core.bundled import bundled_assets
from particlesplat.core.camera import Camera
from particlesplat.data.scene import read_scene
from particlesplat.data.synth import scene_name, write_scene
from particlesplat.data.workspace_points import workspace_points
from particlesplat.model import ConfigError, ModelConfig, ParticleSplat, load_config, read_checkpoint
from particlesplat.model.decoder import clamp_to_support
from particlesplat.model.static_background import WORKSPACE_SCALE, WorkspaceBackground


def _recipe_text(name: str) -> str:
    return (bundled_assets() / name).read_text()


def test_the_robot_recipe_is_the_same_architecture_with_its_own_values_and_every_key_documented():
    tabletop, robot = (yaml.safe_load(_recipe_text(n)) for n in ("recipe.yaml", "robot/recipe.yaml"))
    for section in ("model", "train"):
        assert sorted(robot[section]) == sorted(tabletop[section]), section  # one architecture, a config per family
    cfg, tc = load_config(bundled_assets() / "robot/recipe.yaml")
    # nothing memorised in world coordinates: no static layer; the evidence of depth and the arm's kinematics
    assert cfg.resolution == 128 and cfg.bg_static_points == 0 and cfg.bg_static_grid == 0 and cfg.support_clamp
    assert cfg.fg_evidence and cfg.bg_per_view and tc.beta_fg > 0  # the foreground term reads the evidence
    # every key is documented: a comment on its line, or its name in a comment (s_max beside s_min)
    text = _recipe_text("robot/recipe.yaml")
    comments = " ".join(line.partition("#")[2] for line in text.splitlines())
    for line in text.splitlines():
        if m := re.match(r"^  ([a-z_]+):", line):
            assert "#" in line or m.group(1) in comments, line


def test_the_two_static_layers_exclude_each_other():
    with pytest.raises(ConfigError, match=r"model\.background\.static_points: the static layer is either"):
        ModelConfig(bg_static_grid=8, bg_static_points=100).validate()
    with pytest.raises(ConfigError, match=r"model\.background\.per_view"):
        ModelConfig(bg_static_grid=0, bg_static_points=0, bg_per_view=False).validate()
    ModelConfig(bg_static_grid=0, bg_static_points=100).validate()


def test_workspace_points_are_the_shared_floor_not_the_objects_that_move(tmp_path):
    """Tabletop scenes share their floor (z = 0) and place their objects differently: the voxels occupied in most
    scenes lie on the floor, and almost none inside an object's box (instance masks are not read)."""
    dirs = []
    for i in range(6):
        write_scene(tmp_path / scene_name(i), 3, "train", i, 32)
        dirs.append(tmp_path / scene_name(i))
    found = workspace_points(dirs, max_points=5000, min_share=0.5, resolution=32)
    assert len(found.points) > 50
    assert np.all(found.share >= 0.5)
    on_floor = np.abs(found.points[:, 2]) <= found.sizes
    assert on_floor.mean() > 0.9
    # a ball well inside each object (its centre, its smallest half-size less 2 cm)
    balls = [
        (np.array(o["center"]), min(o["size"]) - 0.02)
        for d in dirs
        for o in json.loads((d / "scene.json").read_text())["objects"]
    ]
    inside = np.zeros(len(found.points), dtype=bool)
    for centre, radius in balls:
        inside |= np.linalg.norm(found.points - centre, axis=1) < radius
    assert inside.mean() < 0.02
    # the floor's colour is the checker's grey, not an object's colour (pixels at object edges mix a little in)
    floor = found.colours[on_floor]
    grey = np.abs(floor - floor.mean(1, keepdims=True)).max(1) < 0.06
    assert grey.mean() > 0.95


def test_the_workspace_layer_starts_at_its_points_and_draws_nothing_beyond_them():
    layer = WorkspaceBackground(ModelConfig(bg_static_grid=0, bg_static_points=5))
    assert float(layer()["opacities"].detach().max()) < 1e-4  # nothing draws before it is placed
    pts = torch.tensor([[0.0, 0.0, 0.0], [0.1, 0.2, 0.3], [-1.0, 2.0, 0.5]])
    cols = torch.tensor([[0.2, 0.4, 0.6], [1.0, 0.0, 0.0], [0.5, 0.5, 0.5]])
    layer.initialise(pts, cols, torch.tensor([0.02, 0.02, 0.06]))
    f = layer()
    assert torch.allclose(f["means"][:3], pts)
    assert torch.allclose(f["scales"][2], torch.full((3,), 0.06 * WORKSPACE_SCALE))
    assert torch.all(f["opacities"][:3] > 0.9) and torch.all(f["opacities"][3:] < 1e-4)
    colour = f["sh"][:3, 0] * 0.28209479177387814 + 0.5  # the SH DC colour rule
    assert torch.allclose(colour, cols, atol=1e-5)
    # the anchors travel in the state dict, so a checkpoint rebuilds the layer
    other = WorkspaceBackground(ModelConfig(bg_static_grid=0, bg_static_points=5))
    other.load_state_dict(layer.state_dict())
    assert torch.equal(other()["means"], f["means"])


def test_clamp_to_support_moves_points_under_the_surface_onto_their_ray_hit():
    """A camera 2 m up whose ray falls 0.5 m per metre of planar depth meets z = 0 at planar depth 4."""
    zeta = torch.tensor([3.0, 5.0, 5.0, 5.0], dtype=torch.float64)
    origin_z = torch.tensor([2.0, 2.0, 2.0, -1.0], dtype=torch.float64)
    dir_z = torch.tensor([-0.5, -0.5, 0.5, -0.5], dtype=torch.float64)  # down, down, up, down from below
    out = clamp_to_support(zeta, origin_z, dir_z)
    assert out.tolist() == [3.0, 4.0, 5.0, 5.0]


@pytest.mark.parametrize("clamp", [False, True])
def test_decoded_particles_stay_above_the_support_with_the_clamp(clamp):
    """Particles placed deep (depth logits high) from views looking down at the floor: without the clamp their
    Gaussians hang under z = 0; with it none is more than a float's error below."""
    torch.manual_seed(0)
    cfg = ModelConfig(**{**TINY_MODEL, "support_clamp": clamp, "d_min": 1.0, "d_max": 12.0})
    model = ParticleSplat(cfg).eval()
    cams = [Camera.orbit((0, 0, 0.15), az, 35, 3.3, width=32, height=32) for az in (-30, 30)]
    with torch.no_grad():
        p = model.encode(torch.rand(2, 3, 32, 32), None, cams)
        p = dataclasses.replace(p, z_d=torch.full_like(p.z_d, 2.0), z_t=torch.ones_like(p.z_t))
        g = model.decode(p, background=False)
    low = float(g.means[:, 2].min())
    if clamp:
        assert low > -1e-4
    else:
        assert low < -0.5


def test_each_particle_is_clamped_to_the_surface_under_it():
    """With per-particle support heights (an object placed on the floor below a table), the clamp holds each
    particle's Gaussians at its own surface: those at -1 m reach below z = 0 but not below -1 m, each where its
    unclamped twin's ray crosses that height (float64); heights all at z = 0 decode exactly
    as no heights at all (the particles as encoded)."""
    torch.manual_seed(0)
    cfg = ModelConfig(**{**TINY_MODEL, "support_clamp": True, "d_min": 1.0, "d_max": 12.0})
    model = ParticleSplat(cfg).eval()
    cams = [Camera.orbit((0, 0, 0.15), az, 35, 3.3, width=32, height=32) for az in (-30, 30)]
    with torch.no_grad():
        p = model.encode(torch.rand(2, 3, 32, 32), None, cams)
        p = dataclasses.replace(p, z_d=torch.full_like(p.z_d, 2.0), z_t=torch.ones_like(p.z_t))
        low = torch.arange(p.num) % 2 == 1
        heights = torch.where(low, -1.0, 0.0)[:, None].to(p.z_t)
        g = model.decode(dataclasses.replace(p, support=heights), background=False)
        same = model.decode(dataclasses.replace(p, support=torch.zeros_like(heights)), background=False)
        plain = model.decode(p, background=False)
    assert torch.equal(same.means, plain.means) and torch.equal(same.opacities, plain.opacities)
    on_floor = low[g.owner]
    assert float(g.means[~on_floor, 2].min()) > -1e-4  # the shared surface, as before
    assert float(g.means[on_floor, 2].min()) > -1.0 - 1e-4 and float(g.means[on_floor, 2].min()) < -0.5
    # each floor particle's Gaussian is where the unclamped one's ray from its view crosses z = -1 when that one lies
    # deeper, else where the unclamped one is (float64, from a model without the clamp)
    free = ParticleSplat(ModelConfig(**{**TINY_MODEL, "d_min": 1.0, "d_max": 12.0})).eval()
    free.load_state_dict(model.state_dict())
    with torch.no_grad():
        raw = free.decode(p, background=False)
    assert torch.equal(raw.owner, g.owner) and float(raw.means[on_floor, 2].min()) < -1.0  # some are held
    for i in torch.nonzero(on_floor).flatten().tolist():
        eye = cams[int(p.view[int(g.owner[i])])].c2w[:3, 3].double()
        m = raw.means[i].double()
        want = eye + (-1.0 - float(eye[2])) / float(m[2] - eye[2]) * (m - eye) if float(m[2]) < -1.0 else m
        assert torch.allclose(g.means[i].double(), want, atol=1e-4), i


def test_the_support_cut_hides_what_hangs_under_the_surface_and_nothing_else():
    """Particles placed deep from views looking down: with ``support_cut`` 0.01 every Gaussian more than 1 cm
    under z = 0 has opacity 0, and every other Gaussian is exactly as without the cut."""
    torch.manual_seed(0)
    base = {**TINY_MODEL, "d_min": 1.0, "d_max": 12.0}
    model = ParticleSplat(ModelConfig(**base)).eval()
    cut = ParticleSplat(ModelConfig(**{**base, "support_cut": 0.01})).eval()
    cut.load_state_dict(model.state_dict())
    cams = [Camera.orbit((0, 0, 0.15), az, 35, 3.3, width=32, height=32) for az in (-30, 30)]
    with torch.no_grad():
        p = model.encode(torch.rand(2, 3, 32, 32), None, cams)
        p = dataclasses.replace(p, z_d=torch.linspace(-2, 2, p.num)[:, None], z_t=torch.ones_like(p.z_t))
        g, h = model.decode(p, background=False), cut.decode(p, background=False)
    under = g.means[:, 2] < -0.01
    assert 0 < int(under.sum()) < g.num  # some hang under the surface, some do not
    assert torch.equal(g.means, h.means) and bool((h.opacities[under] == 0).all())
    assert torch.equal(g.opacities[~under], h.opacities[~under])
    assert below_support(h.means, h.opacities, h.owner) == 0.0 < below_support(g.means, g.opacities, g.owner)


def test_below_support_counts_opaque_object_gaussians_under_the_surface():
    means = torch.tensor([[0, 0, -0.5], [0, 0, -0.005], [0, 0, 0.2], [0, 0, -0.5], [0, 0, -0.5]], dtype=torch.float32)
    opac = torch.tensor([0.9, 0.9, 0.9, 0.2, 0.9])
    owner = torch.tensor([0, 1, 2, 0, -1])  # the last is background: not an object's
    assert below_support(means, opac, owner) == pytest.approx(1 / 3)
    assert below_support(means, opac, owner, support_z=-1.0) == 0.0
    assert -0.005 > -SKIRT_MARGIN  # the second one is within the margin
    assert np.isnan(below_support(means, torch.zeros(5), owner))


def test_a_run_with_the_workspace_layer_places_it_from_the_data_and_resumes_it(tmp_path_factory, tmp_path):
    data = tiny_dataset(tmp_path_factory)
    cfg = tiny_config(tmp_path / "tiny.yaml", steps=2, val_every=2)
    text = yaml.safe_load(cfg.read_text())
    text["model"].update(bg_static_grid=0, bg_static_points=300, support_clamp=True)
    cfg.write_text(yaml.safe_dump(text))
    out = tmp_path / "run"
    assert main(["train", "--config", str(cfg), "--data", str(data), "--out", str(out), "--stop-after", "1"]) == 0
    anchor = read_checkpoint(out / "last.pt")["state_dict"]["static_bg.anchor"]
    assert anchor.shape == (300, 3) and float(anchor.abs().sum()) > 0
    # the points are the floor's voxels of the training scenes
    pts = workspace_points([data / "train" / scene_name(i) for i in range(2)], 300)
    assert torch.allclose(anchor[: len(pts.points)], torch.from_numpy(pts.points))
    assert main(["train", "--config", str(cfg), "--data", str(data), "--out", str(out), "--resume"]) == 0
    after = read_checkpoint(out / "last.pt")
    assert after["step"] == 2
    assert torch.equal(after["state_dict"]["static_bg.anchor"], anchor)  # placed once, not again on resume
    assert read_scene(data / "train" / scene_name(0)).has_depth
