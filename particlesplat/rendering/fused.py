"""The fused CPU rasterizer as a torch autograd function (kernels in :mod:`.fused_kernels`).

Binning, compositing and the analytic backward each run as one numba kernel over all views, instead of the torch
twin's padded chunk tensors and per-pair autograd graph. Inputs and outputs are those of the twin's
:class:`~particlesplat.rendering.rasterize.RasterizeFunction` one level up: per-Gaussian rows, not per-pair ones, so
autograd sees one node for the whole rasterization.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from particlesplat.rendering.rasterize import TILE, tile_centres, tile_grids


@dataclass
class FusedBins:
    """Tile lists of all views.

    Attributes:
        grids: per view (tiles_x, tiles_y, first tile id).
        gauss: (P,) int64 Gaussian row of each pair, grouped by tile, front to back.
        tile_start: (T + 1,) int64 offset of each tile's list in ``gauss``.
        tile_origin: (T, 2) float64 tile centres, pixels.
        log_o: (M,) ln opacity of each Gaussian row (the binning's and the compositing's), working dtype.
    """

    grids: list[tuple[int, int, int]]
    gauss: np.ndarray
    tile_start: np.ndarray
    tile_origin: np.ndarray
    log_o: Tensor

    @property
    def num_tiles(self) -> int:
        return self.tile_origin.shape[0]


def _numpy(t: Tensor) -> np.ndarray:
    """A contiguous CPU tensor's numpy view (no copy where already contiguous)."""
    return t.detach().contiguous().numpy()


@functools.lru_cache(maxsize=32)
def _tile_layout(sizes: tuple[tuple[int, int], ...]) -> tuple[list[tuple[int, int, int]], np.ndarray, np.ndarray]:
    """Tile grids, tile centres (T, 2) float64 and per view (width, height, tiles_x, first tile) (V, 4) int64 of a
    list of view sizes (cached: training renders the same sizes every step). The arrays are read-only."""
    grids = tile_grids(list(sizes))
    origin = tile_centres(grids, torch.float64, torch.device("cpu")).numpy()
    per_view = np.array([[w, h, tx, f] for (w, h), (tx, _, f) in zip(sizes, grids, strict=True)], np.int64)
    per_view = per_view.reshape(-1, 4)
    origin.flags.writeable = False
    per_view.flags.writeable = False
    return grids, origin, per_view


def bin_fused(
    means2d: Tensor,
    conics: Tensor,
    log_o: Tensor,
    radius: Tensor,
    depths: Tensor,
    view: Tensor,
    sizes: list[tuple[int, int]],
) -> FusedBins:
    """Tile lists under the twin's rule (:func:`~particlesplat.rendering.rasterize.bin_gaussians`).

    means2d: (M, 2) float64 pixels; conics: (M, 3); log_o: (M,) ln opacity; radius: (M, 2) half extents of the
    α ≥ 1/255 box in pixels (< 0: none); depths: (M,) camera z (order, ties by row); view: (M,) int64;
    sizes: (width, height) per view.
    """
    from particlesplat.rendering import fused_kernels as k

    grids, origin, per_view = _tile_layout(tuple(sizes))
    gauss, tile_start = k.bin_tiles(
        _numpy(means2d.double()),
        _numpy(radius.double()),
        _numpy(view),
        np.ascontiguousarray(per_view[:, :2]),
        np.ascontiguousarray(per_view[:, 2]),
        np.ascontiguousarray(per_view[:, 3]),
        _numpy(depths),
        _numpy(conics),
        _numpy(log_o),
        origin,
    )
    return FusedBins(grids, gauss, tile_start, origin, log_o.detach().contiguous())


def _kernel_inputs(bins: FusedBins, *tensors: Tensor) -> tuple:
    """The arguments the compositing kernels share: the tile lists, then the tensors' numpy views (Gaussian rows:
    means2d, conics, ln o, features; the forward's output and last-weighed positions)."""
    return (bins.tile_start, bins.gauss, bins.tile_origin, *(t.numpy() for t in tensors))


class FusedRasterize(torch.autograd.Function):
    """Composite per-Gaussian features front to back in every tile.

    Inputs: means2d (M, 2) float64 pixels, conics (M, 3), opacities (M,), features (M, C), the bins.
    Output: (T, 16, C + 1) per tile pixel Σ w·feature, and Σ w (alpha) in the last column, in the dtype of
    ``conics``. Differentiable with respect to the first four inputs.
    """

    @staticmethod
    def forward(ctx, means2d: Tensor, conics: Tensor, opacities: Tensor, features: Tensor, bins: FusedBins) -> Tensor:
        from particlesplat.rendering import fused_kernels as k

        dtype = conics.dtype
        log_o = bins.log_o
        feats = features.detach().to(dtype).contiguous()
        m2 = means2d.detach().double().contiguous()
        con = conics.detach().contiguous()
        out = torch.zeros(bins.num_tiles, TILE * TILE, feats.shape[1] + 1, dtype=dtype)
        last = torch.zeros(bins.num_tiles, TILE * TILE, dtype=torch.int64)
        if bins.gauss.shape[0]:
            k.rasterize_forward(*_kernel_inputs(bins, m2, con, log_o, feats, out, last))
        if any(ctx.needs_input_grad[:4]):
            ctx.save_for_backward(m2, con, log_o, feats, out, last, opacities.detach())
            ctx.bins = bins
            ctx.means_dtype = means2d.dtype
        return out

    @staticmethod
    def backward(ctx, grad_out: Tensor):
        from particlesplat.rendering import fused_kernels as k

        m2, con, log_o, feats, out, last, opacities = ctx.saved_tensors
        bins: FusedBins = ctx.bins
        C = feats.shape[1]
        d_pair = torch.zeros(bins.gauss.shape[0], 6 + C, dtype=con.dtype)
        if bins.gauss.shape[0]:
            grad = _numpy(grad_out.to(con.dtype))
            k.rasterize_backward(*_kernel_inputs(bins, m2, con, log_o, feats, out, last), grad, d_pair.numpy())
        d_rows = torch.zeros(m2.shape[0], 6 + C, dtype=con.dtype)
        k.scatter_add_rows(bins.gauss, d_pair.numpy(), d_rows.numpy())
        d_means = d_rows[:, :2].to(ctx.means_dtype)
        d_conics = d_rows[:, 2:5]
        # ln o is clamped at 1e-30: no gradient below it (as in the twin)
        d_opac = torch.where(opacities > 1e-30, d_rows[:, 5] / opacities.clamp_min(1e-30), torch.zeros_like(opacities))
        return d_means, d_conics, d_opac.to(opacities.dtype), d_rows[:, 6:], None


def rasterize_fused(
    means2d: Tensor,
    conics: Tensor,
    opacities: Tensor,
    features: Tensor,
    radius: Tensor,
    depths: Tensor,
    view: Tensor,
    sizes: list[tuple[int, int]],
) -> tuple[Tensor, list[tuple[int, int, int]]]:
    """Bin and composite M projected Gaussians of all views; returns tile values (T, 16, C + 1) (see
    :class:`FusedRasterize`) and the tile grids. Shapes as in :func:`bin_fused`; features: (M, C)."""
    log_o = torch.log(opacities.detach().clamp_min(1e-30)).to(conics.dtype)
    bins = bin_fused(means2d, conics, log_o, radius, depths, view, sizes)
    return FusedRasterize.apply(means2d, conics, opacities, features, bins), bins.grids
