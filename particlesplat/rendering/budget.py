"""What a render will allocate, estimated before it runs (the job's memory budget, :mod:`particlesplat.core.limits`).

The rasterizer's memory grows with the (tile, Gaussian) candidate pairs: every Gaussian is listed in each 4x4-pixel
tile its footprint box covers, and the pair lists are built in int64 index arrays before the exact test thins them
(:func:`particlesplat.rendering.rasterize.bin_gaussians`). 20,000 Gaussians of 0.5 m filling a 2048^2 view are
1.2e9 pairs: ~35 GB in one block. :func:`render_memory` projects the Gaussians (O(N), no pairs built), counts the
boxes' tiles and prices pairs and pixels; :func:`check_render_memory` refuses an estimate over the limit in one line.

Where the Gaussians exist only inside a job (a model's encoding renders its context views to refine the particles,
``eval`` renders the decoded Gaussians), the job runs in :func:`render_budget`: every render pass
(:func:`particlesplat.rendering.api.render_batch`) then prices its pairs from the projection it has already made
(:func:`check_pass`, no second projection) and refuses before it bins them. Training prices its step's pass
ahead of the run from the first scene's Gaussians (:meth:`particlesplat.training.trainer.Trainer._check_step_renders`).
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from contextvars import ContextVar

import torch
from torch import Tensor

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
# a pass with gradients keeps its pair lists and planes for the backward pass. Measured 2026-11-28 (peak RSS over
# forward + backward against the forward estimate, 2-core CPU): the pure-torch twin 1.36x (5.2e6 pairs, 512^2) and
# 1.64x (2 views of 256^2, 2.8e6 pairs), the fused kernels 0.50x and 0.65x; the same factor as ``bench render``'s
GRAD_FACTOR = 2.0

_job: ContextVar[str | None] = ContextVar("particlesplat_render_budget", default=None)


@contextmanager
def render_budget(what: str) -> Iterator[None]:
    """While inside, every render pass checks its estimate (:func:`check_pass`); ``what`` names the job's input and
    the config keys that size its renders (e.g. ``"--checkpoint M.pt (model.resolution 64, ...)"``)."""
    token = _job.set(what)
    try:
        yield
    finally:
        _job.reset(token)


def _box_tiles(means2d: Tensor, radius: Tensor, wh: Tensor) -> int:
    """Tiles of every footprint box clipped to its image (:func:`particlesplat.rendering.rasterize.tile_boxes`)."""
    first, last, ok = tile_boxes(means2d, radius, wh)
    tiles = last - first + 1
    return int(torch.where(ok, tiles[:, 0] * tiles[:, 1], 0.0).sum())


def pass_memory(pairs: int, pixels: int, owners: int = 0, grad: bool = False) -> float:
    """Estimated peak bytes of one render pass of ``pairs`` candidate pairs into ``pixels`` pixels (all its views),
    ``owners`` owner weight slots, with gradients (``grad``) or without."""
    per_pair = BYTES_PER_PAIR + BYTES_PER_PAIR_OWNER * owners
    return (pairs * per_pair + pixels * (BYTES_PER_PIXEL + 4.0 * owners)) * (GRAD_FACTOR if grad else 1.0)


def _pass_text(what: str, sizes: Sequence[tuple[int, int]], gaussians: int, pairs: int, grad: bool) -> str:
    w, h = sizes[0]
    shape = f"{w}x{h}" if len(sizes) == 1 else f"{len(sizes)} views of {w}x{h}"
    if len(set(sizes)) > 1:
        shape = f"{len(sizes)} views of {sum(a * b for a, b in sizes):,} pixels"
    each = " (summed over the views)" if len(sizes) > 1 else ""
    return (
        f"{what}: a render pass of {shape}{' with gradients' if grad else ''}, {gaussians:,} Gaussians{each} "
        f"covering {pairs:,} (tile, Gaussian) pairs"
    )


def check_pass(
    means2d: Tensor, radius: Tensor, view: Tensor, sizes: Sequence[tuple[int, int]], owners: int, grad: bool
) -> None:
    """Inside :func:`render_budget`: BudgetError naming the job when the pass would not fit the memory limit.
    means2d, radius: (M, 2) pixels of the M projected (view, Gaussian) instances; view: (M,) their view; sizes:
    (width, height) per view. Outside, nothing (one lookup)."""
    what = _job.get()
    if what is None or not sizes:
        return
    wh = torch.tensor(sizes, dtype=torch.float64, device=means2d.device).index_select(0, view)
    pairs = _box_tiles(means2d, radius, wh) if len(view) else 0
    check_memory(
        pass_memory(pairs, sum(w * h for w, h in sizes), owners, grad),
        _pass_text(what, sizes, len(view), pairs, grad),
    )


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
        return _box_tiles(proj.means2d, radius, wh)


def render_memory(gaussians: Gaussians, camera: Camera, owners: int = 0) -> tuple[float, int]:
    """(estimated peak bytes, candidate pairs) of rendering ``gaussians`` into ``camera`` (``owners``: the owner
    weight slots of a segmentation render, 0 for colour)."""
    pairs = candidate_pairs(gaussians, camera)
    return pass_memory(pairs, camera.width * camera.height, owners), pairs


def check_render_memory(gaussians: Gaussians, camera: Camera, what: str, owners: int = 0) -> None:
    """BudgetError naming ``what`` (the scene, .ply or checkpoint) when the render would not fit the memory limit."""
    estimate, pairs = render_memory(gaussians, camera, owners)
    check_memory(
        estimate,
        f"{what}: {len(gaussians):,} Gaussians covering {pairs:,} (tile, Gaussian) pairs at "
        f"{camera.width}x{camera.height}",
    )
