"""Rendered layers (``particlesplat.rendering.layers``): compositing one render over another against one render
of both Gaussian sets, and area pooling against hand-computed blocks."""

from __future__ import annotations

import pytest
import torch

from particlesplat import Camera, Gaussians, render
from particlesplat.core.sh import rgb_to_sh_dc
from particlesplat.rendering.layers import composite_over, pool_layer, render_layer

pytestmark = pytest.mark.usefixtures("rasterizer")  # every test: fused kernels and torch twin

BG = (0.2, 0.3, 0.4)


def gaussians_at_depth(n: int, near: float, far: float, seed: int) -> Gaussians:
    """n Gaussians in front of a camera at the origin looking down +z (OpenCV), at depths in [near, far] metres."""
    gen = torch.Generator().manual_seed(seed)
    z = near + (far - near) * torch.rand(n, generator=gen)
    xy = (torch.rand(n, 2, generator=gen) - 0.5) * 0.6 * z[:, None]
    return Gaussians(
        torch.cat([xy, z[:, None]], 1),
        torch.nn.functional.normalize(torch.randn(n, 4, generator=gen), dim=1),
        0.04 + 0.08 * torch.rand(n, 3, generator=gen),
        0.2 + 0.5 * torch.rand(n, generator=gen),
        rgb_to_sh_dc(torch.rand(n, 3, generator=gen))[:, None],
        torch.zeros(n, dtype=torch.int64),
    )


def test_composite_over_equals_one_render_of_both_sets_when_the_back_lies_behind():
    """Front Gaussians 1.0-1.6 m away, back ones 2.5-3.5 m: every back Gaussian lies behind every front one
    on every ray, so the front's render (over black) composited over the back's (over the background) is the
    render of both sets together: colour, depth and alpha."""
    cam = Camera(torch.tensor([[60.0, 0, 32], [0, 60.0, 32], [0, 0, 1]]), torch.eye(4), 64, 64)
    front, back = gaussians_at_depth(40, 1.0, 1.6, 0), gaussians_at_depth(60, 2.5, 3.5, 1)
    both = render(Gaussians.cat([front, back]), cam, background=BG)
    f, b = render(front, cam), render(back, cam, background=BG)
    out = composite_over(render_layer(f.rgb, f.depth, f.alpha), render_layer(b.rgb, b.depth, b.alpha))
    assert f.alpha.amax() > 0.9 and (f.alpha < 0.05).float().mean() > 0.05  # the front covers some pixels, not all
    assert ((f.alpha < 0.5) & (b.alpha > 0.5)).any()  # and the back shows through somewhere
    torch.testing.assert_close(out, render_layer(both.rgb, both.depth, both.alpha), rtol=1e-4, atol=2e-5)


def test_pool_layer_averages_colour_and_alpha_and_weights_depth_by_alpha():
    """A 2x4 layer pooled to 1x2: the left block is half transparent (its depth is the alpha-weighted mean
    of the drawn pixels), the right one empty (depth 0)."""
    alpha = torch.tensor([[1.0, 0.5, 0.0, 0.0], [0.0, 0.5, 0.0, 0.0]])
    depth = torch.tensor([[2.0, 4.0, 0.0, 0.0], [0.0, 6.0, 0.0, 0.0]])
    rgb = torch.arange(24, dtype=torch.float32).reshape(2, 4, 3) / 24
    out = pool_layer(render_layer(rgb, depth, alpha)[None], (1, 2))[0]
    torch.testing.assert_close(out[:3, 0, 0], rgb[:, :2].reshape(4, 3).mean(0))
    torch.testing.assert_close(out[:3, 0, 1], rgb[:, 2:].reshape(4, 3).mean(0))
    torch.testing.assert_close(out[4, 0], torch.tensor([0.5, 0.0]))
    torch.testing.assert_close(out[3, 0], torch.tensor([(1 * 2 + 0.5 * 4 + 0.5 * 6) / 2.0, 0.0]))
