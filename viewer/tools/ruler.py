"""The ruler: the distance in metres between two points picked on surfaces.

A click with the ruler on (L) finds the surface under the cursor: the point on the pixel's ray at the depth the
Gaussians that draw there composite to (each Gaussian's densest point on the ray, weighted by what it adds to the
pixel by the rules of :func:`particlesplat.rendering.pixel.pixel_weights`). Two points give the distance; a third
starts over.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch
from torch import Tensor

from particlesplat.core.camera import Camera
from particlesplat.core.gaussians import Gaussians
from particlesplat.core.vectors import float3
from particlesplat.rendering.pixel import pixel_weights

if TYPE_CHECKING:
    from ..state import ViewState

MIN_COVER = 0.5  # a surface is picked where the Gaussians cover at least this much of the pixel


def surface_point(gaussians: Gaussians, camera: Camera, x: float, y: float) -> Tensor | None:
    """(3,) float64 world metres of the surface seen at framebuffer pixel (x, y) (its centre), or None where the
    Gaussians cover less than :data:`MIN_COVER` of it (the background shows)."""
    cam = camera.to("cpu", torch.float64)
    g = gaussians.detach().to("cpu")
    index, weights = pixel_weights(g, cam, (int(x), int(y)))
    w = weights.double()
    total = float(w.sum())
    if total < MIN_COVER:
        return None
    origin = cam.c2w[:3, 3]
    ray = cam.unproject(
        torch.tensor([int(x) + 0.5, int(y) + 0.5], dtype=torch.float64), torch.ones((), dtype=torch.float64)
    )
    ray = ray - origin  # one metre of planar depth along the pixel's ray
    # each Gaussian's densest point on the ray: t = (mu - o)^T S^-1 d / d^T S^-1 d (a flat one: where the ray
    # crosses its plane)
    inv = torch.linalg.inv(g.covariances()[index].double() + 1e-12 * torch.eye(3, dtype=torch.float64))
    to_mean = g.means[index].double() - origin
    t = torch.einsum("ni,nij,j->n", to_mean, inv, ray) / torch.einsum("i,nij,j->n", ray, inv, ray)
    ok = torch.isfinite(t)
    return origin + ray * float((w[ok] * t[ok]).sum() / w[ok].sum()) if bool(ok.any()) else None


def ruler_click(state: ViewState, gaussians: Gaussians, camera: Camera, x: float, y: float) -> str:
    """A click at framebuffer pixel (x, y) with the ruler on: a point of it (the third starts over). Returns the
    status line: the distance once there are two."""
    p = surface_point(gaussians, camera, x, y)
    if p is None:
        return "ruler: no surface under the cursor (click on an object or the floor)"
    if len(state.ruler_points) >= 2:
        state.ruler_points.clear()
    state.ruler_points.append(float3(p))
    if len(state.ruler_points) < 2:
        return "ruler: first point {:.3f}, {:.3f}, {:.3f} m; click the second".format(*state.ruler_points[0])
    return f"ruler: {ruler_distance(state):.3f} m"


def ruler_distance(state: ViewState) -> float | None:
    """Metres between the ruler's two points, or None before there are two."""
    if len(state.ruler_points) < 2:
        return None
    a, b = (torch.tensor(p, dtype=torch.float64) for p in state.ruler_points[:2])
    return float((a - b).norm())


def draw_ruler(state: ViewState, camera: Camera, pixel_ratio: tuple[float, float]) -> None:
    """The ruler's points and the line between them, with its length, over the scene (``camera``: framebuffer
    pixels; ``pixel_ratio``: framebuffer pixels per window point)."""
    from imgui_bundle import imgui

    if not state.ruler or not state.ruler_points:
        return
    uv, z = camera.project(torch.tensor(state.ruler_points, dtype=torch.float64).to(camera.K.dtype))
    if not bool((z > 0).all()):
        return
    sx, sy = pixel_ratio
    pts = [imgui.ImVec2(float(u) / sx, float(v) / sy) for u, v in uv.tolist()]
    draw = imgui.get_foreground_draw_list()
    colour = imgui.IM_COL32(80, 230, 255, 255)
    for p in pts:
        draw.add_circle_filled(p, 4.0, colour)
    distance = ruler_distance(state)
    if distance is not None:
        draw.add_line(pts[0], pts[1], colour, 2.0)
        mid = imgui.ImVec2(0.5 * (pts[0].x + pts[1].x) + 6.0, 0.5 * (pts[0].y + pts[1].y))
        draw.add_text(mid, colour, f"{distance:.3f} m")
