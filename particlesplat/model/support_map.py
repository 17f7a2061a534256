"""What the support surface looks like where no Gaussian draws it, read from the context views
(``background.support_map``).

A per-view background draws only what its views saw. A novel view also sees the table top where both context
views were blocked by an object or the arm, or looked past it; there a render showed the one colour behind the
Gaussians (:mod:`particlesplat.model.backdrop`), often the floor's. The support map is a top-down picture of the
plane z = :data:`~particlesplat.core.world.SUPPORT_Z`, :data:`CELLS` x :data:`CELLS` cells over
[-:data:`HALF_EXTENT`, :data:`HALF_EXTENT`]² world metres, built from the context pixels:

- a pixel whose surface point lies on the plane adds its colour, and says "support here";
- a pixel whose surface point lies below the plane (the floor past the table's edge) says "no support where my
  ray crossed the plane".

Holes are filled by push-pull (each coarser level averages the evidence of four cells; each finer level keeps
its own evidence and takes the coarser level's where it has none), so a table's unseen corner takes the colour
of the table around it, and a region no view saw at all takes the scene's average. The fourth channel is the
share of "support here" evidence: where it is over one half a ray that meets the plane shows the map's colour,
elsewhere the colour behind everything. It reads no world coordinates but the support surface's height; turning
the world about z by a quarter turn turns the map with it.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

from particlesplat.core.camera import Camera
from particlesplat.core.world import BELOW_SUPPORT, ON_SUPPORT, SUPPORT_Z
from particlesplat.model.decoder import clamp_to_support
from particlesplat.model.evidence import world_points

CELLS = 64
"""Cells along each side of the map (a power of two: push-pull halves it down to one cell)."""
HALF_EXTENT = 1.0
"""Metres from the world origin to the map's edge along x and along y."""
FILL_LEVELS = 2
"""Coarser levels that fill a hole in the support evidence: a hole up to 2**2 cells (12.5 cm) wide, such as the
table under an object, takes its surroundings' share; a region farther from any evidence is not support (chosen
on validation: docs/robot-workspaces.md)."""
EDGE_SOFTNESS = 0.1
"""Width of the ramp of the support share around one half that blends the map's colour into the backdrop."""


def _splat(xy: Tensor, values: Tensor) -> Tensor:
    """Sum ``values`` (N, C) into the map's cells at world ``xy`` (N, 2) -> (C, CELLS, CELLS), rows along y."""
    ij = ((xy + HALF_EXTENT) / (2 * HALF_EXTENT) * CELLS).floor().long()
    inside = ((ij >= 0) & (ij < CELLS)).all(-1)
    flat = ij[inside, 1] * CELLS + ij[inside, 0]
    out = torch.zeros(values.shape[1], CELLS * CELLS, dtype=values.dtype, device=values.device)
    out.index_add_(1, flat, values[inside].T)
    return out.view(-1, CELLS, CELLS)


def push_pull(values: Tensor, weight: Tensor, levels: int | None = None) -> Tensor:
    """Fill the holes of summed ``values`` (C, N, N) of summed ``weight`` (N, N) (N a power of two): each cell's
    mean where its weight is at least 1, blended with the next coarser level's filled mean by the weight where it
    is less. With ``levels``, at most that many coarser levels fill a hole (a hole wider than 2**levels cells
    keeps zero at its centre); else down to one cell. Returns (C, N, N) means; no weight at all gives zeros."""
    own = values / weight.clamp_min(1e-12)
    w = weight.clamp(0, 1)
    if values.shape[-1] == 1 or levels == 0:
        return w * own
    coarse = push_pull(
        F.avg_pool2d(values[None], 2)[0] * 4,
        F.avg_pool2d(weight[None, None], 2)[0, 0] * 4,
        None if levels is None else levels - 1,
    )
    up = F.interpolate(coarse[None], scale_factor=2, mode="nearest")[0]
    return w * own + (1 - w) * up


def views_support_map(
    rgb: Tensor, depth: Tensor | None, K: Tensor, c2w: Tensor, hidden: Tensor | None = None
) -> Tensor | None:
    """The support map of one scene's context views.

    rgb: (V, 3, H, W) in [0, 1]; depth: (V, 1, H, W) planar metres (0 = missing) or None; K: (V, 3, 3);
    c2w: (V, 4, 4) OpenCV camera-to-world; hidden: (V, 1, H, W) in [0, 1], pixels that count for nothing (over one
    half: an object's and those around its foot), or None. Returns (4, CELLS, CELLS) float32 on rgb's
    device: RGB and the share of support evidence per cell (rows along world y, columns along x, cell (0, 0) at
    (-HALF_EXTENT, -HALF_EXTENT)), or None without depth or without a context pixel on the support surface.
    """
    if depth is None:
        return None
    points = world_points(depth.to(K.dtype), K, c2w).reshape(-1, 3)  # (N, 3)
    origins = c2w[:, None, None, :3, 3].expand(-1, depth.shape[2], depth.shape[3], -1).reshape(-1, 3)
    valid = depth.reshape(-1) > 0
    if hidden is not None:
        valid = valid & (hidden.reshape(-1) <= 0.5)
    colours = rgb.permute(0, 2, 3, 1).reshape(-1, 3).to(points)
    on = valid & ((points[:, 2] - SUPPORT_Z).abs() <= ON_SUPPORT)
    if not bool(on.any()):
        return None
    below = valid & (points[:, 2] < SUPPORT_Z - BELOW_SUPPORT) & (origins[:, 2] > SUPPORT_Z)
    o, step = origins[below], points[below] - origins[below]
    s = clamp_to_support(torch.ones_like(o[:, 2]), o[:, 2], step[:, 2])  # where the ray crosses the plane, in (0, 1)
    crossing = (o + s[:, None] * step)[:, :2]
    ones_on = torch.ones_like(points[on, :1])
    seen = _splat(points[on, :2], torch.cat([colours[on], ones_on], dim=-1))  # (4, N, N): colour sums, count
    past = _splat(crossing, torch.ones_like(crossing[:, :1]))[0]  # (N, N)
    colour = push_pull(seen[:3], seen[3])
    share = push_pull(seen[3:4], seen[3] + past, FILL_LEVELS)[0]  # support counts over all counts, holes filled
    return torch.cat([colour, share[None]]).to(torch.float32)


def _sample(support_map: Tensor, camera: Camera) -> tuple[Tensor, Tensor]:
    """The map's colour (H, W, 3) where each pixel's ray of ``camera`` meets the support plane, and the weight (H, W)
    in [0, 1] with which it stands for what the pixel sees there (the support share ramped about one half, 0 for a
    ray that misses the plane or the map)."""
    cam = camera.to(device=support_map.device, dtype=support_map.dtype)
    origins, dirs = cam.rays()  # (H, W, 3)
    t = clamp_to_support(torch.full_like(dirs[..., 2], float("inf")), origins[..., 2], dirs[..., 2])
    down = torch.isfinite(t)  # rays that meet the plane in front of the camera
    xy = (origins + torch.where(down, t, 0)[..., None] * dirs)[..., :2] / HALF_EXTENT  # [-1, 1] inside the map
    sample = F.grid_sample(support_map[None], xy[None], mode="bilinear", padding_mode="border", align_corners=False)
    rgb, share = sample[0, :3].permute(1, 2, 0), sample[0, 3]
    weight = ((share - 0.5) / EDGE_SOFTNESS + 0.5).clamp(0, 1) * down * (xy.abs() < 1).all(-1)
    return rgb, weight


def support_at(support_map: Tensor, camera: Camera) -> tuple[Tensor, Tensor]:
    """Where each pixel's ray of ``camera`` meets the support plane: the map's colour there (H, W, 3) and how surely
    the point lies on the support (H, W) in [0, 1] (the table, not the floor past its edge; the map's support share
    there, :func:`views_support_map`)."""
    return _sample(support_map, camera)


def support_map_image(support_map: Tensor, backdrop: Tensor, camera: Camera) -> Tensor:
    """The colour behind the Gaussians per pixel of ``camera``: where a pixel's ray meets the support plane inside
    the map at a cell whose support share is over one half, the map's colour, elsewhere ``backdrop``.

    support_map: (4, CELLS, CELLS) from :func:`views_support_map`; backdrop: (3,) RGB. Returns (H, W, 3) in the
    dtype and on the device of ``support_map``.
    """
    rgb, weight = _sample(support_map, camera)
    bg = backdrop.to(support_map).reshape(1, 1, 3)
    return weight[..., None] * rgb + (1 - weight[..., None]) * bg
