"""Random Gaussian sets for benchmarks and tests (reproducible from a seed)."""

from __future__ import annotations

import math

import torch

from particlesplat.core.gaussians import Gaussians
from particlesplat.core.sh import rgb_to_sh_dc


def random_gaussians(
    n: int, *, seed: int = 0, sh_degree: int = 3, num_owners: int = 8, extent: float = 1.0, pixel_scale: float = 0.02
) -> Gaussians:
    """``n`` Gaussians in a cube of half-size ``extent`` metres about the origin.

    Scales are log-uniform around ``pixel_scale * extent * (20000 / n)^(1/3)`` metres so the
    screen coverage stays similar for any ``n``; opacities in [0.05, 1]; random rotations; SH
    up to ``sh_degree`` with a random DC colour and small higher bands; owners uniform in
    ``-1 .. num_owners - 1`` (-1 = background).
    """
    gen = torch.Generator().manual_seed(seed)
    r = lambda *s: torch.rand(*s, generator=gen)  # noqa: E731
    k = (sh_degree + 1) ** 2
    base = pixel_scale * extent * (20000.0 / max(n, 1)) ** (1.0 / 3.0)
    scales = base * torch.exp((r(n, 3) - 0.5) * 2.0 * math.log(3.0))
    sh = torch.randn(n, k, 3, generator=gen) * 0.15
    sh[:, 0] = rgb_to_sh_dc(r(n, 3))
    return Gaussians(
        means=(r(n, 3) * 2.0 - 1.0) * extent,
        quats=torch.nn.functional.normalize(torch.randn(n, 4, generator=gen), dim=-1),
        scales=scales,
        opacities=0.05 + 0.95 * r(n),
        sh=sh,
        owner=torch.randint(-1, num_owners, (n,), generator=gen),
    )
