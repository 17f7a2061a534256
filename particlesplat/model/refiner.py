"""Amortised refinement of the particle posteriors (``refine_steps``).

The encoder sees each particle once, through a fixed-size glimpse. A refinement step decodes the posterior means,
renders the context views, and lets every particle look again at its own view inside its own box with the render
beside the observation (where it draws too much, too little, the wrong colour or depth). A small network turns
that look into corrections of the particle's posterior means. The corrections start at zero, so a model trained
without refinement starts from what it drew.
"""

from __future__ import annotations

from typing import TypeVar

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from particlesplat.model.config import ModelConfig
from particlesplat.model.encoder import conv3x3
from particlesplat.model.posterior import ParticlePosterior

# observed RGB 3, depth 2 (d / d_max, valid); rendered RGB 3, depth / d_max 1, alpha 1; the particle's own weight 1
GLIMPSE_CHANNELS = 11
P = TypeVar("P", bound=ParticlePosterior)  # corrected() keeps the posterior's type (a full Posterior stays one)
BOX_MARGIN = 1.25  # the refinement glimpse covers the particle's box enlarged by this factor (its edges and surround)


def latent_vector(post: ParticlePosterior) -> Tensor:
    """The posterior means a refinement step reads: (..., 7 + d_obj) = [mu_o 2, mu_s 2, mu_d, mu_e, E[z_t], mu_f]."""
    return torch.cat([post.mu_o, post.mu_s, post.mu_d, post.mu_e, post.t_mean(), post.mu_f], dim=-1)


def box_glimpses(images: Tensor, centre: Tensor, half: Tensor, size: int) -> Tensor:
    """Bilinear glimpses of per-particle images over their boxes.

    images: (M, C, H, W); centre: (M, 2) box centres in [-1, 1] (x, y); half: (M, 2) half-sizes in the same
    units -> (M, C, size, size) (outside the image: the border pixel).
    """
    M = images.shape[0]
    theta = torch.zeros(M, 2, 3, device=images.device, dtype=images.dtype)
    theta[:, 0, 0] = half[:, 0]
    theta[:, 1, 1] = half[:, 1]
    theta[:, :, 2] = centre
    grid = F.affine_grid(theta, [M, images.shape[1], size, size], align_corners=False)
    return F.grid_sample(images, grid, mode="bilinear", padding_mode="border", align_corners=False)


def _bounded_shift(value: Tensor, centre: float, bound: float, delta: Tensor) -> Tensor:
    """Move a tanh-bounded mean ``centre + bound * tanh(x)`` by ``delta`` in x: it stays within the bound, and
    ``delta`` 0 returns ``value`` exactly."""
    x = torch.atanh(((value - centre) / bound).clamp(-0.999, 0.999))
    moved = value + bound * (torch.tanh(x + delta) - torch.tanh(x))
    return moved.clamp(centre - bound, centre + bound)  # a mean saturated at the bound (x clamped) cannot pass it


class Refiner(nn.Module):
    """One refinement step's network: per-particle box glimpse (observation | render) + posterior means
    -> corrections of the means (zero at initialisation)."""

    def __init__(self, cfg: ModelConfig):
        super().__init__()
        self.cfg = cfg
        c, D = cfg.channels, cfg.d_obj
        g = cfg.glimpse_size
        self.cnn = nn.Sequential(conv3x3(GLIMPSE_CHANNELS, c // 2, 2), conv3x3(c // 2, c, 2), conv3x3(c, c, 2))
        n_lat = 7 + D
        hid = cfg.refine_hidden
        self.mlp = nn.Sequential(nn.Linear(c * (g // 8) ** 2 + n_lat, hid), nn.SiLU(), nn.Linear(hid, hid), nn.SiLU())
        self.out = nn.Linear(hid, n_lat)
        nn.init.zeros_(self.out.weight)
        nn.init.zeros_(self.out.bias)

    def forward(self, glimpses: Tensor, latents: Tensor) -> Tensor:
        """glimpses: (M, 11, g, g) (:data:`GLIMPSE_CHANNELS`, g = ``glimpse_size``); latents:
        (M, 7 + d_obj) (:func:`latent_vector`) -> (M, 7 + d_obj) corrections in the same layout (the z_t entry
        moves log a and -log b)."""
        h = self.cnn(glimpses).flatten(1)
        return self.out(self.mlp(torch.cat([h, latents], dim=1)))

    def corrected(self, post: P, delta: Tensor, scale_centre: float) -> P:
        """Posteriors with corrected means. post: (B, N, ·) particle fields; delta: (B, N, 7 + d_obj). The offset
        and scale means stay inside their tanh bounds; z_t's Beta(a, b) becomes Beta(a e^δ, b e^-δ) (its mean's
        log-odds move by 2δ); log-variances and the other fields are kept."""
        cfg = self.cfg
        return post.replace(
            mu_o=_bounded_shift(post.mu_o, 0.0, cfg.offset_bound, delta[..., 0:2]),
            mu_s=_bounded_shift(post.mu_s, scale_centre, cfg.scale_logit_bound, delta[..., 2:4]),
            mu_d=post.mu_d + delta[..., 4:5],
            mu_e=post.mu_e + delta[..., 5:6],
            beta_a=post.beta_a * torch.exp(delta[..., 6:7]),
            beta_b=post.beta_b * torch.exp(-delta[..., 6:7]),
            mu_f=post.mu_f + delta[..., 7:],
        )


__all__ = ["Refiner", "box_glimpses", "latent_vector", "GLIMPSE_CHANNELS", "BOX_MARGIN"]
