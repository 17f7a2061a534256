"""Moving particles rigidly in the world: anchors exactly, Gaussians within the stated perspective bound."""

from __future__ import annotations

import pytest
import torch
from model_data import TINY_MODEL

from particlesplat.core.camera import Camera
from particlesplat.editing.move import MoveError, anchor_points, translate
from particlesplat.model import ModelConfig, ParticleSplat

DELTA = (0.15, -0.1, 0.08)


@pytest.fixture(scope="module")
def scene():
    torch.manual_seed(0)
    model = ParticleSplat(ModelConfig(**{**TINY_MODEL, "patch_gaussians": 4})).eval()
    cams = [Camera.orbit((0.0, 0.0, 0.15), az, 30.0, 3.3, width=32, height=32) for az in (-40, 35)]
    gen = torch.Generator().manual_seed(1)
    rgb = torch.rand(2, 3, 32, 32, generator=gen)
    depth = 2.8 + torch.rand(2, 1, 32, 32, generator=gen)
    return model, model.encode(rgb, depth, cams)


def moved(particles, target):
    p = particles
    for i, attrs in target.items():
        for name, value in attrs.items():
            p = p.with_attribute(i, name, value)
    return p


def test_anchors_move_by_delta_and_gaussians_follow(scene):
    model, p = scene
    idx = [0, 4]  # one particle of each view
    q = moved(p, translate(p, idx, DELTA, model.config))
    cfg = model.config
    delta = torch.tensor(DELTA)
    torch.testing.assert_close(anchor_points(q, idx, cfg), anchor_points(p, idx, cfg) + delta, rtol=0, atol=1e-5)
    for i in idx:
        a, b = (
            model.decode(p, torch.tensor([i]), background=False),
            model.decode(q, torch.tensor([i]), background=False),
        )
        cam = p.cameras[int(p.view[i])]
        # the bound and the kept size are checked on the front layer (the first S*S Gaussians of a particle): a
        # back Gaussian's depth behind its front one follows the box's width, and it strays slightly
        front = cfg.patch_gaussians**2
        _, zeta = cam.project(a.means[:front])
        d = cfg.d_min + torch.sigmoid(p.z_d[i, 0]) * (cfg.d_max - cfg.d_min)
        _, d_new = cam.project(anchor_points(q, [i], cfg)[0])
        bound = float(delta.norm()) * (zeta - d).abs() / d_new + 1e-5  # the module's perspective bound
        err = (b.means[:front] - a.means[:front] - delta).norm(dim=-1)
        assert bool((err <= bound).all()), (err - bound).max()
        # metric size kept (particle 4 moves 0.19 m nearer its view: without the z_s change it grows 6 %)
        rel = (b.scales[:front].amax(-1) / a.scales[:front].amax(-1) - 1.0).abs()
        assert float(rel.max()) < 1e-3
        torch.testing.assert_close(b.opacities, a.opacities)


def test_moving_back_restores_the_particles(scene):
    model, p = scene
    idx = [1, 2, 5]
    q = moved(p, translate(p, idx, DELTA, model.config))
    r = moved(q, translate(q, idx, [-v for v in DELTA], model.config))
    for name in ("z_p", "z_d", "z_s"):
        torch.testing.assert_close(getattr(r, name), getattr(p, name), rtol=0, atol=1e-4)


def test_leaving_the_depth_range_is_an_error(scene):
    model, p = scene
    cam = p.cameras[int(p.view[0])]
    away = (cam.c2w[:3, 2] * (model.config.d_max + 1.0)).tolist()  # along the view axis, past d_max
    with pytest.raises(MoveError, match="particle 0: .*depth"):
        translate(p, [0], away, model.config)
