"""The colour behind a scene's Gaussians, read from its context views (``background.colour_from_views``).

A per-view background draws only what its views saw. Where no context view saw anything, such as the floor under
the table and the table's sides seen from another side, a render shows the colour behind the Gaussians. A learned
colour is one colour for every workspace; this one is the scene's own: the median colour of the context pixels
whose depth puts them below the support surface (the floor and the table's sides, which is what the views miss
most). It needs depth, and it reads no world coordinates but the support surface's height.
"""

from __future__ import annotations

import torch
from torch import Tensor

from particlesplat.core.world import BELOW_SUPPORT, SUPPORT_Z
from particlesplat.model.evidence import world_points

MIN_SHARE = 0.01
"""The least share of the context pixels that must lie below the support surface for their colour to be used."""


def views_backdrop(rgb: Tensor, depth: Tensor | None, K: Tensor, c2w: Tensor) -> Tensor | None:
    """The median colour of one scene's context pixels below the support surface.

    rgb: (V, 3, H, W) in [0, 1]; depth: (V, 1, H, W) planar metres (0 = missing) or None; K: (V, 3, 3);
    c2w: (V, 4, 4) OpenCV camera-to-world. Returns (3,) RGB in [0, 1] on rgb's device, or None without depth or
    when fewer than :data:`MIN_SHARE` of the pixels lie more than :data:`BELOW_SUPPORT` below the surface.
    """
    if depth is None:
        return None
    points = world_points(depth.to(K.dtype), K, c2w)  # (V, H, W, 3)
    below = (depth[:, 0] > 0) & (points[..., 2] < SUPPORT_Z - BELOW_SUPPORT)
    if int(below.sum()) < MIN_SHARE * below.numel():
        return None
    colours = rgb.permute(0, 2, 3, 1)[below.to(rgb.device)]  # (N, 3)
    return colours.median(dim=0).values.to(torch.float32)
