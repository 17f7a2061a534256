"""The ruler picks the surface under a pixel: on a floor of flat opaque Gaussians seen from an oblique camera, the
picked points are where the pixels' rays meet the plane (analytic), and their distance is that of those points."""

from __future__ import annotations

import pytest
import torch

from particlesplat.core.camera import Camera
from particlesplat.core.gaussians import Gaussians
from viewer.state import ViewState
from viewer.tools.ruler import ruler_click, ruler_distance, surface_point


def floor(height: float = 0.1, step: float = 0.02, half: float = 1.0) -> Gaussians:
    """A square floor at z = ``height`` of flat, overlapping, nearly opaque Gaussians."""
    ax = torch.arange(-half, half + 1e-9, step, dtype=torch.float32)
    gx, gy = torch.meshgrid(ax, ax, indexing="ij")
    n = gx.numel()
    means = torch.stack([gx.flatten(), gy.flatten(), torch.full((n,), height)], 1)
    return Gaussians(
        means=means,
        quats=torch.tensor([[1.0, 0.0, 0.0, 0.0]]).repeat(n, 1),
        scales=torch.tensor([[step, step, 1e-4]]).repeat(n, 1),
        opacities=torch.full((n,), 0.95),
        sh=torch.full((n, 1, 3), 0.5),
        owner=torch.zeros(n, dtype=torch.int64),
    )


def ray_plane(cam: Camera, x: int, y: int, height: float) -> torch.Tensor:
    """Where the ray through the centre of pixel (x, y) meets the plane z = ``height`` (float64)."""
    c = cam.to("cpu", torch.float64)
    uv = torch.tensor([x + 0.5, y + 0.5], dtype=torch.float64)
    o, p = c.c2w[:3, 3], c.unproject(uv, torch.tensor(1.0, dtype=torch.float64))
    d = p - o
    return o + d * (height - o[2]) / d[2]


def test_a_ruler_point_lies_where_the_ray_meets_the_surface_and_two_give_their_distance():
    g = floor()
    cam = Camera.orbit((0.0, 0.0, 0.1), 20.0, 45.0, 2.0, width=96, height=72)
    for x, y in ((48, 36), (20, 50), (70, 30)):
        p = surface_point(g, cam, x, y)
        assert p is not None
        torch.testing.assert_close(p, ray_plane(cam, x, y, 0.1), atol=5e-3, rtol=0)
    state = ViewState(ruler=True)
    assert ruler_click(state, g, cam, 20, 50).startswith("ruler: first point")
    message = ruler_click(state, g, cam, 70, 30)
    want = float((ray_plane(cam, 20, 50, 0.1) - ray_plane(cam, 70, 30, 0.1)).norm())
    assert ruler_distance(state) == pytest.approx(want, abs=0.01) and message == f"ruler: {ruler_distance(state):.3f} m"
    ruler_click(state, g, cam, 48, 36)  # a third point starts over
    assert len(state.ruler_points) == 1 and ruler_distance(state) is None


def test_no_ruler_point_off_the_surface():
    cam = Camera.orbit((0.0, 0.0, 0.1), 20.0, 10.0, 2.0, width=96, height=72)
    assert surface_point(floor(), cam, 48, 2) is None  # above the horizon: the background
    state = ViewState(ruler=True)
    assert "no surface" in ruler_click(state, floor(), cam, 48, 2) and not state.ruler_points
