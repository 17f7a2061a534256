"""Tile-based front-to-back alpha compositing with an analytic backward (pure torch).

Screen is split into 4×4-pixel tiles (measured ~1.8× faster than 8×8 for small splats). Each projected Gaussian is listed in every tile its
α ≥ 1/255 footprint's bounding box touches; lists are sorted by depth (ties by index).
Tiles are bucketed by list length, and each bucket is processed in chunks of about
``CHUNK_ELEMENTS`` (tile, pixel, slot) entries, so memory stays bounded for any N and size.

Per pixel and Gaussian, the exponent ``ln o - ½ dᵀ C d`` is one matmul of six pixel features
``[x², xy, y², x, y, 1]`` (tile-centred coordinates) with six per-Gaussian coefficients.
The backward recomputes α and T per chunk instead of storing them, and uses the suffix sum
``S_i = Σ_{k>i} v_k w_k``: ∂L/∂α_i = v_i T_i − S_i / (1 − α_i).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from .projection import ALPHA_MAX, ALPHA_MIN

TILE = 4
CHUNK_ELEMENTS = 1 << 18
T_MIN = 1e-4  # a pixel stops before the Gaussian that would take T to <= T_MIN
_EXP_FLOOR = -6.0  # exp(-6) < 1/255: clamping the exponent changes nothing and keeps exp() fast


@dataclass
class TileBins:
    """Gaussian lists per tile, for one or several views (each view has its own tile grid).

    Attributes:
        grids: per view (tiles_x, tiles_y, first tile id).
        gauss: (P,) int64 Gaussian (row in the rasterizer's inputs) per list entry, grouped by
            tile, front to back within a tile.
        start: (T,) int64 offset of each tile's list in ``gauss``; count: (T,) int64 lengths.
        tile_origin: (T, 2) pixel coordinates of each tile's centre in its view.
        chunks: list of (tile ids (Tb,), padded length L) processed together.
    """

    grids: list[tuple[int, int, int]]
    gauss: Tensor
    start: Tensor
    count: Tensor
    tile_origin: Tensor
    chunks: list[tuple[Tensor, int]]

    @property
    def num_tiles(self) -> int:
        tx, ty, first = self.grids[-1]
        return first + tx * ty


def bin_gaussians(means2d: Tensor, conics: Tensor, opacities: Tensor, radius: Tensor, depths: Tensor,
                  view: Tensor, sizes: list[tuple[int, int]]) -> TileBins:
    """Assign Gaussians to the tiles of their view.

    A Gaussian is listed in a tile iff α ≥ 1/255 at one of the tile's pixel centres: candidate
    tiles come from the bounding box of its footprint, then each candidate is tested exactly.

    means2d: (M, 2) pixels; conics: (M, 3); opacities: (M,); radius: (M, 2) half extents in
    pixels of the α ≥ 1/255 box (< 0 means no footprint); depths: (M,) camera z used for
    ordering (ties by row index); view: (M,) int64 view of each row; sizes: (width, height) per view.
    """
    device = means2d.device
    grids, first = [], 0
    for w, h in sizes:
        tx, ty = -(-w // TILE), -(-h // TILE)
        grids.append((tx, ty, first))
        first += tx * ty
    n_tiles = first
    with torch.no_grad():
        wh = torch.tensor(sizes, dtype=torch.float64, device=device)[view]  # (M, 2)
        g_tx = torch.tensor([g[0] for g in grids], device=device)[view]
        g_first = torch.tensor([g[2] for g in grids], device=device)[view]
        m = means2d.detach().double()
        r = radius.detach().double()
        # pixel u is covered if its centre u + 0.5 lies within [m - r, m + r]
        lo = torch.maximum(torch.ceil(m - r - 0.5), torch.zeros_like(m))
        hi = torch.minimum(torch.floor(m + r - 0.5), wh - 1)
        ok = (r[:, 0] >= 0) & (hi >= lo).all(-1) & torch.isfinite(m).all(-1)
        t0, t1 = (lo // TILE).long(), (hi // TILE).long()
        nx = torch.where(ok, t1[:, 0] - t0[:, 0] + 1, 0)
        ny = torch.where(ok, t1[:, 1] - t0[:, 1] + 1, 0)
        order = torch.sort(depths.detach(), stable=True).indices  # front to back, ties by index
        per = (nx * ny)[order]
        total = int(per.sum())
        g = torch.repeat_interleave(order, per)
        offs = torch.arange(total, device=device) - torch.repeat_interleave(torch.cumsum(per, 0) - per, per)
        gnx = nx[g]
        tile = g_first[g] + (t0[g, 1] + offs // gnx) * g_tx[g] + t0[g, 0] + offs % gnx
        origin = torch.cat([torch.stack(torch.meshgrid(torch.arange(ty), torch.arange(tx), indexing="ij")[::-1],
                                        dim=-1).reshape(-1, 2) for tx, ty, _ in grids]).to(device)
        origin = origin * TILE + TILE / 2
        hit = _tile_hits(g, tile, origin, means2d.detach(), conics.detach(), opacities.detach())
        g, tile = g[hit], tile[hit]
        tile_sorted, perm = torch.sort(tile, stable=True)
        gauss = g[perm]
        count = torch.bincount(tile_sorted, minlength=n_tiles)
        start = torch.cumsum(count, 0) - count
        chunks = _make_chunks(count)
    return TileBins(grids, gauss, start, count, origin, chunks)


def _tile_hits(g: Tensor, tile: Tensor, origin: Tensor, means2d: Tensor, conics: Tensor, opacities: Tensor,
               block: int = 1 << 16) -> Tensor:
    """(P,) bool: does Gaussian g[i] reach α ≥ 1/255 at a pixel centre of tile[i]? (blocks of pairs)"""
    feats = _pixel_features(means2d.dtype, means2d.device)
    log_o = torch.log(opacities.clamp_min(1e-30))
    thresh = math.log(ALPHA_MIN)
    hit = torch.empty(g.shape[0], dtype=torch.bool, device=g.device)
    for i in range(0, g.shape[0], block):
        gi, ti = g[i:i + block], tile[i:i + block]
        coef = _coefficients(means2d[gi] - origin[ti].to(means2d.dtype), conics[gi], log_o[gi])
        hit[i:i + block] = (coef @ feats.T).amax(-1) >= thresh - 1e-3  # margin: the raster decides exactly
    return hit


def _make_chunks(count: Tensor) -> list[tuple[Tensor, int]]:
    """Bucket non-empty tiles by list length (padded to 1..8, 10, 12, 14, 16, 20, ...: quarter octaves) and chunk them."""
    chunks: list[tuple[Tensor, int]] = []
    nonempty = torch.nonzero(count > 0).squeeze(1)
    if nonempty.numel() == 0:
        return chunks
    c = count[nonempty].double()
    step = torch.clamp(torch.pow(2.0, torch.floor(torch.log2(c))) / 4, min=1.0)  # quarter-octave steps
    padded = (torch.ceil(c / step) * step).long()
    for length in torch.unique(padded).tolist():
        tiles = nonempty[padded == length]
        per_chunk = max(1, CHUNK_ELEMENTS // (TILE * TILE * length))
        for i in range(0, tiles.numel(), per_chunk):
            chunks.append((tiles[i:i + per_chunk], int(length)))
    return chunks


def _pixel_features(dtype: torch.dtype, device: torch.device) -> Tensor:
    """(64, 6) features [x², xy, y², x, y, 1] of a tile's pixel centres relative to the tile centre."""
    r = torch.arange(TILE, dtype=dtype, device=device) + 0.5 - TILE / 2
    y, x = torch.meshgrid(r, r, indexing="ij")
    x, y = x.reshape(-1), y.reshape(-1)
    return torch.stack([x * x, x * y, y * y, x, y, torch.ones_like(x)], dim=-1)


def _gather(bins: TileBins, tiles: Tensor, length: int) -> tuple[Tensor, Tensor]:
    """(Tb, L) Gaussian rows of the tiles' lists (padding repeats row 0) and (Tb, L) validity."""
    slot = torch.arange(length, device=tiles.device)
    valid = slot[None, :] < bins.count[tiles][:, None]
    idx = (bins.start[tiles][:, None] + slot[None, :]).clamp(max=max(bins.gauss.numel() - 1, 0))
    return bins.gauss[idx], valid


def _coefficients(m: Tensor, conic: Tensor, log_o: Tensor) -> Tensor:
    """Exponent coefficients (…, 6) for features [x², xy, y², x, y, 1].

    m: (…, 2) tile-local centre; conic: (…, 3) (a, b, c); log_o: (…) ln opacity.
    ln o − ½ (a dx² + 2b dx dy + c dy²) with d = pixel − m.
    """
    a, b, c = conic.unbind(-1)
    mx, my = m.unbind(-1)
    lx, ly = a * mx + b * my, b * mx + c * my
    const = log_o - 0.5 * (mx * lx + my * ly)
    return torch.stack([-0.5 * a, -b, -0.5 * c, lx, ly, const], dim=-1)


class _ChunkState:
    """α, T and weights of one chunk (recomputed in the backward), each (Tb, 64, L)."""

    def __init__(self, feats: Tensor, coef: Tensor):
        raw = torch.matmul(feats, coef.transpose(1, 2))  # exponent ln o − ½ dᵀCd
        raw.clamp_min_(_EXP_FLOOR).exp_()
        alpha = raw.clamp_max_(ALPHA_MAX)
        alpha.masked_fill_(alpha < ALPHA_MIN, 0.0)
        self.alpha = alpha
        self.one_minus = 1.0 - alpha
        t_incl = torch.cumprod(self.one_minus, dim=-1)
        self.t_excl = t_incl / self.one_minus
        self.keep = t_incl > T_MIN
        # w_i = α_i T_i = T_i − T_{i+1}, zero from the terminating Gaussian on
        self.weights = torch.sub(self.t_excl, t_incl).masked_fill_(~self.keep, 0.0)


def _chunk_inputs(bins: TileBins, tiles: Tensor, length: int, means2d: Tensor, conics: Tensor,
                  log_o: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    rows, valid = _gather(bins, tiles, length)
    local = means2d[rows] - bins.tile_origin[tiles].to(means2d.dtype)[:, None, :]
    lo = torch.where(valid, log_o[rows], torch.full_like(log_o[rows], -30.0))
    return rows, local, _coefficients(local, conics[rows], lo)


def tiles_to_images(tile_values: Tensor, bins: TileBins, sizes: list[tuple[int, int]]) -> list[Tensor]:
    """(T, 64, C) -> per view (H, W, C) (differentiable reshapes and slices)."""
    C = tile_values.shape[-1]
    images = []
    for (tx, ty, first), (w, h) in zip(bins.grids, sizes):
        img = tile_values[first:first + tx * ty].reshape(ty, tx, TILE, TILE, C).permute(0, 2, 1, 3, 4)
        images.append(img.reshape(ty * TILE, tx * TILE, C)[:h, :w])
    return images


class RasterizeFunction(torch.autograd.Function):
    """Composite features front to back: (T, 64, C+1) per tile pixel Σ w·[feature, 1]."""

    @staticmethod
    def forward(ctx, means2d: Tensor, conics: Tensor, opacities: Tensor, features: Tensor,
                bins: TileBins) -> Tensor:
        log_o = torch.log(opacities.clamp_min(1e-30))
        feats = _pixel_features(means2d.dtype, means2d.device)
        out = means2d.new_zeros(bins.num_tiles, TILE * TILE, features.shape[1] + 1)
        for tiles, length in bins.chunks:
            rows, _, coef = _chunk_inputs(bins, tiles, length, means2d, conics, log_o)
            st = _ChunkState(feats, coef)
            out[tiles] = torch.bmm(st.weights, _with_ones(features[rows]))
        ctx.save_for_backward(means2d, conics, opacities, features)
        ctx.bins = bins
        return out

    @staticmethod
    def backward(ctx, grad_out: Tensor):
        means2d, conics, opacities, features = ctx.saved_tensors
        bins = ctx.bins
        log_o = torch.log(opacities.clamp_min(1e-30))
        feats = _pixel_features(means2d.dtype, means2d.device)
        d_m = torch.zeros_like(means2d)
        d_conic = torch.zeros_like(conics)
        d_logo = torch.zeros_like(opacities)
        d_f = torch.zeros(features.shape[0], features.shape[1] + 1, dtype=features.dtype, device=features.device)
        for tiles, length in bins.chunks:
            rows, local, coef = _chunk_inputs(bins, tiles, length, means2d, conics, log_o)
            st = _ChunkState(feats, coef)
            f1 = _with_ones(features[rows])
            G = grad_out[tiles]  # (Tb, 64, C+1)
            flat = rows.reshape(-1)
            d_f.index_add_(0, flat, torch.bmm(st.weights.transpose(1, 2), G).reshape(-1, f1.shape[-1]))
            v = torch.bmm(G, f1.transpose(1, 2))  # (Tb, 64, L) upstream · feature
            vw = v.mul_(st.weights)
            suffix = vw.sum(-1, keepdim=True) - torch.cumsum(vw, dim=-1)  # S_i = Σ_{k>i} v_k w_k
            # ∂L/∂exponent = α ∂L/∂α = α (v T − S / (1 − α)) = v w − S α / (1 − α), where α is
            # neither clamped at 0.99 nor past termination (α = 0 below 1/255 gives 0 by itself)
            d_expo = vw.sub_(suffix.mul_(st.alpha).div_(st.one_minus))
            d_expo.masked_fill_(~st.keep | (st.alpha >= ALPHA_MAX), 0.0)
            g = torch.matmul(d_expo.transpose(1, 2), feats)  # (Tb, L, 6) ∂L/∂coefficients
            g0, g1, g2, g3, g4, g5 = g.unbind(-1)
            a, b, c = conics[rows].unbind(-1)
            mx, my = local.unbind(-1)
            lx, ly = a * mx + b * my, b * mx + c * my
            da = -0.5 * g0 + g3 * mx - 0.5 * g5 * mx * mx
            db = -g1 + g3 * my + g4 * mx - g5 * mx * my
            dc = -0.5 * g2 + g4 * my - 0.5 * g5 * my * my
            d_m.index_add_(0, flat, torch.stack([g3 * a + g4 * b - g5 * lx, g3 * b + g4 * c - g5 * ly],
                                                dim=-1).reshape(-1, 2))
            d_conic.index_add_(0, flat, torch.stack([da, db, dc], dim=-1).reshape(-1, 3))
            d_logo.index_add_(0, flat, g5.reshape(-1))
        return d_m, d_conic, d_logo / opacities.clamp_min(1e-30), d_f[:, :-1], None


def _with_ones(features: Tensor) -> Tensor:
    """(..., C) -> (..., C+1) with a trailing 1 (its weighted sum is alpha)."""
    return torch.cat([features, torch.ones_like(features[..., :1])], dim=-1)


def owner_weight_tiles(means2d: Tensor, conics: Tensor, opacities: Tensor, owner_slot: Tensor, num_slots: int,
                       bins: TileBins) -> Tensor:
    """(T, 64, num_slots) Σ T·α per owner slot (no gradient). owner_slot: (M,) int64 in [0, num_slots)."""
    with torch.no_grad():
        log_o = torch.log(opacities.clamp_min(1e-30))
        feats = _pixel_features(means2d.dtype, means2d.device)
        out = means2d.new_zeros(bins.num_tiles, TILE * TILE, num_slots)
        for tiles, length in bins.chunks:
            rows, _, coef = _chunk_inputs(bins, tiles, length, means2d, conics, log_o)
            st = _ChunkState(feats, coef)
            onehot = torch.nn.functional.one_hot(owner_slot[rows], num_slots).to(means2d.dtype)
            out[tiles] = torch.bmm(st.weights, onehot)
        return out
