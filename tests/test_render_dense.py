"""The benchmark's dense all-pairs baseline agrees with the independent float64 reference."""

from __future__ import annotations

import pytest
import torch
from reference_render import reference_render

from particlesplat import Camera, Gaussians
from particlesplat.rendering.dense import render_dense

pytestmark = pytest.mark.usefixtures("rasterizer")  # every test: fused kernels and torch twin


def _scene(seed: int) -> tuple[Gaussians, Camera]:
    gen = torch.Generator().manual_seed(seed)
    n = 120
    g = Gaussians(
        torch.randn(n, 3, generator=gen) * 0.5,
        torch.randn(n, 4, generator=gen),
        torch.rand(n, 3, generator=gen) * 0.1 + 0.005,
        torch.rand(n, generator=gen),
        torch.randn(n, 4, 3, generator=gen) * 0.3,
        torch.zeros(n, dtype=torch.int64),
    )
    return g.to(dtype=torch.float64), Camera.orbit((0, 0, 0), 25, 30, 3.0, width=29, height=19, dtype=torch.float64)


@pytest.mark.parametrize("chunk", [None, 37])
def test_dense_matches_reference(chunk) -> None:
    g, cam = _scene(3)
    rgb, alpha, depth = render_dense(g, cam, background=(0.2, 0.1, 0.0), pixel_chunk=chunk)
    ref = reference_render(g, cam, background=(0.2, 0.1, 0.0))
    for got, want in ((rgb, ref.rgb), (alpha, ref.alpha), (depth, ref.depth)):
        assert torch.allclose(got, want.to(got.dtype), atol=1e-9)
