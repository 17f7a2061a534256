"""The static background layer: flat Gaussians on the ground plane, learned over the whole dataset.

The tabletop family (``docs/dataset.md``) shares one world frame (+z up, floor plane z = 0) and one
floor in every scene. The per-view background can only draw what a context view saw, so wide-baseline
targets show holes where neither view framed the floor. This layer covers the floor everywhere: a
``grid`` × ``grid`` lattice of flat discs over the square |x|, |y| <= ``extent`` on z = 0, each with a
learned colour and opacity (a learned texture of the plane, shared by all scenes; beyond the floor's edge
the discs learn to be transparent). Its Gaussians are background (owner -1).
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from ..sh import num_sh_bases, rgb_to_sh_dc
from .config import ModelConfig

DISC_SIGMA = 0.6     # in-plane standard deviation of a disc, in grid cells (neighbours overlap smoothly)
DISC_FLATNESS = 0.05  # out-of-plane standard deviation relative to the in-plane one


class StaticBackground(nn.Module):
    """``bg_static_grid``² flat Gaussians on z = 0 with learned colour (SH DC) and opacity logits."""

    def __init__(self, cfg: ModelConfig):
        super().__init__()
        n, ext = cfg.bg_static_grid, cfg.bg_static_extent
        cell = 2.0 * ext / n
        ar = (torch.arange(n, dtype=torch.float32) + 0.5) * cell - ext
        gy, gx = torch.meshgrid(ar, ar, indexing="ij")
        self.register_buffer("means", torch.stack([gx, gy, torch.zeros_like(gx)], -1).reshape(-1, 3),
                             persistent=False)
        self.register_buffer("scales", torch.tensor([DISC_SIGMA, DISC_SIGMA, DISC_SIGMA * DISC_FLATNESS])
                             .mul(cell).expand(n * n, 3).clone(), persistent=False)
        self.num_bases = num_sh_bases(cfg.sh_degree)
        self.sh_dc = nn.Parameter(rgb_to_sh_dc(torch.full((n * n, 3), 0.6)))  # mid grey
        self.opacity_logit = nn.Parameter(torch.full((n * n,), 4.0))

    @property
    def num(self) -> int:
        return self.means.shape[0]

    def forward(self) -> dict[str, Tensor]:
        """Gaussian fields of the layer: means (N, 3) world metres, quats (N, 4), scales (N, 3) metres,
        opacities (N,), sh (N, K, 3) (degree > 0 bases are zero: the colour is view-independent)."""
        n = self.num
        quats = torch.zeros(n, 4, device=self.means.device)
        quats[:, 0] = 1.0
        sh = torch.zeros(n, self.num_bases, 3, device=self.means.device, dtype=self.sh_dc.dtype)
        sh = torch.cat([self.sh_dc[:, None], sh[:, 1:]], dim=1)
        return {"means": self.means, "quats": quats, "scales": self.scales,
                "opacities": torch.sigmoid(self.opacity_logit), "sh": sh}
