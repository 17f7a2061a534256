"""The static background layer: flat Gaussians on the ground plane, learned over the whole dataset.

The tabletop family (``docs/dataset.md``) shares one world frame (+z up, floor plane z = 0) and one
floor in every scene. The per-view background can only draw what a context view saw, so wide-baseline
targets show holes where neither view framed the floor. This layer covers the floor everywhere: a
``grid`` × ``grid`` lattice of flat discs over the square |x|, |y| <= ``extent`` on z = 0, each with a
learned colour and opacity (a learned texture of the plane, shared by all scenes; beyond the floor's edge
a disc learns the colour behind it or to be transparent). Its Gaussians are background (owner -1).
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from particlesplat.core.sh import num_sh_bases, rgb_to_sh_dc
from particlesplat.model.config import ModelConfig

DISC_SIGMA = 0.6  # in-plane standard deviation of a disc, in grid cells (neighbours overlap smoothly)
DISC_FLATNESS = 0.05  # out-of-plane standard deviation relative to the in-plane one


class StaticBackground(nn.Module):
    """``bg_static_grid``² flat Gaussians on z = 0 with learned colour (SH DC) and opacity logits."""

    def __init__(self, cfg: ModelConfig):
        super().__init__()
        n, ext = cfg.bg_static_grid, cfg.bg_static_extent
        cell = 2.0 * ext / n
        ar = (torch.arange(n, dtype=torch.float32) + 0.5) * cell - ext
        gy, gx = torch.meshgrid(ar, ar, indexing="ij")
        self.register_buffer("means", torch.stack([gx, gy, torch.zeros_like(gx)], -1).reshape(-1, 3), persistent=False)
        self.register_buffer(
            "scales",
            torch.tensor([DISC_SIGMA, DISC_SIGMA, DISC_SIGMA * DISC_FLATNESS]).mul(cell).expand(n * n, 3).clone(),
            persistent=False,
        )
        self.register_buffer(
            "quats", torch.tensor([1.0, 0.0, 0.0, 0.0]).expand(n * n, 4).clone(), persistent=False
        )  # identity: the discs lie in the plane
        self.num_bases = num_sh_bases(cfg.sh_degree)
        self.sh_dc = nn.Parameter(rgb_to_sh_dc(torch.full((n * n, 3), 0.6)))  # mid grey
        self.opacity_logit = nn.Parameter(torch.full((n * n,), 4.0))

    @property
    def num(self) -> int:
        return self.means.shape[0]

    def forward(self) -> dict[str, Tensor]:
        """Gaussian fields of the layer: means (N, 3) world metres, quats (N, 4), scales (N, 3) metres,
        opacities (N,), sh (N, K, 3) (degree > 0 bases are zero: the colour is view-independent)."""
        sh = torch.cat([self.sh_dc[:, None], self.sh_dc.new_zeros(self.num, self.num_bases - 1, 3)], dim=1)
        return {
            "means": self.means,
            "quats": self.quats,
            "scales": self.scales,
            "opacities": torch.sigmoid(self.opacity_logit),
            "sh": sh,
        }
