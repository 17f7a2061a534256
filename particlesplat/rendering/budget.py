"""What a render will allocate, estimated before it runs (the job's memory budget, :mod:`particlesplat.core.limits`).

The rasterizer's memory grows with the (tile, Gaussian) candidate pairs: every Gaussian is listed in each 4x4-pixel
tile its footprint box covers, and the pair lists are built in int64 index arrays before the exact test thins them
(:func:`particlesplat.rendering.rasterize.bin_gaussians`). 20,000 Gaussians of 0.5 m filling a 2048^2 view are
1.2e9 pairs: ~35 GB in one block. :func:`render_memory` projects the Gaussians (O(N), no pairs built), counts the
boxes' tiles and prices pairs and pixels; :func:`check_render_memory` refuses an estimate over the limit in one line.
"""

from __future__ import annotations

import torch

from particlesplat.core.camera import Camera
from particlesplat.core.gaussians import Gaussians, quats_to_rotations
from particlesplat.core.limits import check_memory
from particlesplat.rendering.projection import footprint_extents, project_views
from particlesplat.rendering.rasterize import tile_boxes

# peak bytes per candidate pair while the tile lists are built (about a dozen int64 arrays of the pair count alive
# at once) and per pixel (the colour, depth, alpha and weight planes and their composited copies). Measured
# 2026-11-28 (peak RSS over the render, 2-core CPU): 96.5 B a pair at 3.9e7 pairs (5,000 Gaussians, 1024^2), 98.5 B
# at 3.4e7 (500, 2048^2); 501 MB for 3.9e6 pairs at 1024^2, where 100 B a pair + 80 B a pixel say 479 MB
BYTES_PER_PAIR = 100.0
BYTES_PER_PAIR_OWNER = 4.0  # per pair and owner slot, with owner weights (segmentation modes)
BYTES_PER_PIXEL = 80.0


def candidate_pairs(gaussians: Gaussians, camera: Camera) -> int:
    """(tile, Gaussian) pairs the rasterizer lists before its exact test: the tiles of each footprint box, clipped
    to the image, as :func:`particlesplat.rendering.rasterize.bin_gaussians` counts them."""
    if len(gaussians) == 0:
        return 0
    with torch.no_grad():
        g = gaussians
        cam = camera.to(device=g.means.device, dtype=g.means.dtype)
        rows = torch.arange(len(g), device=g.means.device)
        proj = project_views(g.means, quats_to_rotations(g.quats), g.scales, rows, torch.zeros_like(rows), [cam])
        radius = footprint_extents(proj, g.opacities.index_select(0, rows.index_select(0, proj.index)))
        wh = torch.tensor([cam.width, cam.height], dtype=torch.float64, device=proj.means2d.device)
        first, last, ok = tile_boxes(proj.means2d, radius, wh)
        tiles = last - first + 1
        return int(torch.where(ok, tiles[:, 0] * tiles[:, 1], 0.0).sum())


def render_memory(gaussians: Gaussians, camera: Camera, owners: int = 0) -> tuple[float, int]:
    """(estimated peak bytes, candidate pairs) of rendering ``gaussians`` into ``camera`` (``owners``: the owner
    weight slots of a segmentation render, 0 for colour)."""
    pairs = candidate_pairs(gaussians, camera)
    per_pair = BYTES_PER_PAIR + BYTES_PER_PAIR_OWNER * owners
    return pairs * per_pair + camera.width * camera.height * (BYTES_PER_PIXEL + 4.0 * owners), pairs


def check_render_memory(gaussians: Gaussians, camera: Camera, what: str, owners: int = 0) -> None:
    """BudgetError naming ``what`` (the scene, .ply or checkpoint) when the render would not fit the memory limit."""
    estimate, pairs = render_memory(gaussians, camera, owners)
    check_memory(
        estimate,
        f"{what}: {len(gaussians):,} Gaussians covering {pairs:,} (tile, Gaussian) pairs at "
        f"{camera.width}x{camera.height}",
    )
