"""SH of degree 1 in the decoder: rotation into the world, and decoding a model built with it."""

from __future__ import annotations

import torch
from kornia.geometry.conversions import axis_angle_to_rotation_matrix
from model_data import TINY_MODEL

from particlesplat import Camera
from particlesplat.core.sh import eval_sh_colors
from particlesplat.model import ParticleSplat
from particlesplat.model.config import ModelConfig
from particlesplat.model.geometry import rotate_sh_to_world


def test_rotated_coefficients_give_the_same_colour_along_the_rotated_direction() -> None:
    gen = torch.Generator().manual_seed(0)
    sh = torch.randn(7, 4, 3, generator=gen, dtype=torch.float64)
    R = axis_angle_to_rotation_matrix(torch.randn(7, 3, generator=gen, dtype=torch.float64))
    d = torch.nn.functional.normalize(torch.randn(7, 3, generator=gen, dtype=torch.float64), dim=-1)
    world = rotate_sh_to_world(sh, R)
    got = eval_sh_colors(world, (R @ d[..., None])[..., 0])
    assert torch.allclose(got, eval_sh_colors(sh, d), atol=1e-12)


def test_degree_one_model_decodes_all_and_subsets() -> None:
    torch.manual_seed(0)
    model = ParticleSplat(ModelConfig(**{**TINY_MODEL, "sh_degree": 1})).eval()
    cams = [Camera.orbit((0, 0, 0.15), az, 30, 3.3, width=32, height=32) for az in (-20, 20)]
    particles = model.encode(torch.rand(2, 3, 32, 32), torch.rand(2, 1, 32, 32) + 3.0, cams)
    full = model.decode(particles, z_t_threshold=0.0)
    assert full.sh_degree == 1 and torch.isfinite(full.sh).all()
    one = model.decode(particles, torch.tensor([1]), background=False, z_t_threshold=0.0)
    assert torch.allclose(one.sh, full.of_owner(1).sh, atol=1e-6)  # batched matmuls may round differently
