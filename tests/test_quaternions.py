"""Quaternions of any norm rotate like their unit quaternion; zero is the identity."""

from __future__ import annotations

import pytest
import torch

from particlesplat import Camera, Gaussians, render
from particlesplat.core.gaussians import quats_to_rotations

pytestmark = pytest.mark.usefixtures("rasterizer")  # every test: fused kernels and torch twin


@pytest.mark.parametrize("scale", [1e-30, 5e-13, 1.0, 1e20])
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_any_norm_gives_the_unit_rotation(scale: float, dtype: torch.dtype) -> None:
    q = torch.tensor([[0.3, -0.5, 0.7, 0.2], [1.0, 0.0, 0.0, 1.0]], dtype=torch.float64)
    unit = q / q.norm(dim=-1, keepdim=True)
    w, x, y, z = unit.unbind(-1)
    expect = torch.stack(
        [
            1 - 2 * (y * y + z * z),
            2 * (x * y - w * z),
            2 * (x * z + w * y),
            2 * (x * y + w * z),
            1 - 2 * (x * x + z * z),
            2 * (y * z - w * x),
            2 * (x * z - w * y),
            2 * (y * z + w * x),
            1 - 2 * (x * x + y * y),
        ],
        -1,
    ).reshape(-1, 3, 3)
    got = quats_to_rotations((q * scale).to(dtype))
    assert torch.allclose(got.double(), expect, atol=1e-6 if dtype == torch.float32 else 1e-12)


def test_zero_quaternion_is_identity_with_finite_gradient() -> None:
    q = torch.zeros(1, 4, dtype=torch.float64, requires_grad=True)
    R = quats_to_rotations(q)
    assert torch.equal(R[0], torch.eye(3, dtype=torch.float64))
    R.sum().backward()
    assert torch.isfinite(q.grad).all()


def test_render_is_invariant_to_quaternion_scale() -> None:
    gen = torch.Generator().manual_seed(0)
    n = 50
    q = torch.randn(n, 4, generator=gen, dtype=torch.float64)
    base = dict(
        means=torch.randn(n, 3, generator=gen, dtype=torch.float64) * 0.4,
        scales=torch.rand(n, 3, generator=gen, dtype=torch.float64) * 0.2 + 0.01,
        opacities=torch.rand(n, generator=gen, dtype=torch.float64),
        sh=torch.randn(n, 1, 3, generator=gen, dtype=torch.float64),
        owner=torch.zeros(n, dtype=torch.int64),
    )
    cam = Camera.orbit((0, 0, 0), 10, 20, 3.0, width=24, height=20, dtype=torch.float64)
    ref = render(Gaussians(quats=q / q.norm(dim=-1, keepdim=True), **base), cam)
    tiny = render(Gaussians(quats=q * 1e-14, **base), cam)
    assert torch.allclose(tiny.rgb, ref.rgb, atol=1e-10) and torch.allclose(tiny.alpha, ref.alpha, atol=1e-10)
