"""Rendered layers as image stacks: pooled to a smaller size and composited front over back.

A layer is (..., 5, H, W): colour (3), expected planar depth (metres, 0 where nothing draws) and alpha, as
:class:`~particlesplat.rendering.api.RenderResult` holds them. A front layer's colour is over black; a back
layer's is over whatever background it was rendered on.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor


def render_layer(rgb: Tensor, depth: Tensor, alpha: Tensor) -> Tensor:
    """(H, W, 3), (H, W), (H, W) of one render -> its layer (5, H, W)."""
    return torch.cat([rgb.permute(2, 0, 1), depth[None], alpha[None]])


def pool_layer(layer: Tensor, size: tuple[int, int]) -> Tensor:
    """Area-average a layer (M, 5, H, W) to ``size`` (h, w) pixels: colour and alpha averaged, depth averaged
    with the alpha as its weight (as one render at the smaller size composites it)."""
    rgb, depth, alpha = layer[:, :3], layer[:, 3:4], layer[:, 4:5]
    pooled = F.interpolate(torch.cat([rgb, alpha * depth, alpha], 1), size=size, mode="area")
    a = pooled[:, 4:5]
    d = torch.where(a > 0, pooled[:, 3:4] / a.clamp_min(1e-12), torch.zeros_like(a))
    return torch.cat([pooled[:, :3], d, a], 1)


def composite_over(front: Tensor, back: Tensor) -> Tensor:
    """``front`` over ``back``, both (..., 5, H, W): what one render of both Gaussian sets gives where every
    Gaussian of the back lies behind every Gaussian of the front (up to the renderer's early stop where the
    transmittance falls below 1e-4). Colour: front + (1 - α_front) back; alpha: α_f + (1 - α_f) α_b; depth:
    the two alpha-weighted."""
    af, ab = front[..., 4:5, :, :], back[..., 4:5, :, :]
    behind = (1.0 - af) * ab
    alpha = af + behind
    acc_depth = af * front[..., 3:4, :, :] + behind * back[..., 3:4, :, :]
    depth = torch.where(alpha > 0, acc_depth / alpha.clamp_min(1e-12), torch.zeros_like(alpha))
    rgb = front[..., :3, :, :] + (1.0 - af) * back[..., :3, :, :]
    return torch.cat([rgb, depth, alpha], dim=-3)
