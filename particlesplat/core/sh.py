"""Real spherical harmonics up to degree 3 with the constants of 3DGS (and gsplat)."""

from __future__ import annotations

import math

import torch
from torch import Tensor

SH_C0 = 0.28209479177387814
SH_C1 = 0.4886025119029199
SH_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396)
SH_C3 = (
    -0.5900435899266435,
    2.890611442640554,
    -0.4570457994644658,
    0.3731763325901154,
    -0.4570457994644658,
    1.445305721320277,
    -0.5900435899266435,
)


def num_sh_bases(degree: int) -> int:
    """K = (degree + 1)^2 coefficients per colour channel."""
    if degree not in (0, 1, 2, 3):
        raise ValueError(f"SH degree must be 0..3, got {degree}")
    return (degree + 1) ** 2


def sh_degree_from_bases(k: int) -> int:
    """Inverse of :func:`num_sh_bases`; raises ValueError if ``k`` is not 1, 4, 9 or 16."""
    d = int(round(math.sqrt(k))) - 1
    if d not in (0, 1, 2, 3) or (d + 1) ** 2 != k:
        raise ValueError(f"{k} SH coefficients per channel is not (degree+1)^2 for a degree in 0..3")
    return d


def sh_basis(dirs: Tensor, degree: int) -> Tensor:
    """dirs: (..., 3) unit directions -> (..., K) basis values B_k (3DGS sign convention)."""
    x, y, z = dirs.unbind(-1)
    out = [torch.full_like(x, SH_C0)]
    if degree >= 1:
        out += [-SH_C1 * y, SH_C1 * z, -SH_C1 * x]
    if degree >= 2:
        xx, yy, zz, xy, yz, xz = x * x, y * y, z * z, x * y, y * z, x * z
        out += [SH_C2[0] * xy, SH_C2[1] * yz, SH_C2[2] * (2.0 * zz - xx - yy), SH_C2[3] * xz, SH_C2[4] * (xx - yy)]
    if degree >= 3:
        out += [
            SH_C3[0] * y * (3.0 * xx - yy),
            SH_C3[1] * xy * z,
            SH_C3[2] * y * (4.0 * zz - xx - yy),
            SH_C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy),
            SH_C3[4] * x * (4.0 * zz - xx - yy),
            SH_C3[5] * z * (xx - yy),
            SH_C3[6] * x * (xx - 3.0 * yy),
        ]
    return torch.stack(out, dim=-1)


def eval_sh_colors(sh: Tensor, dirs: Tensor) -> Tensor:
    """Colour = max(Σ_k B_k(dir) sh_k + 0.5, 0).

    sh: (N, K, 3) coefficients; dirs: (N, 3) unit view directions (camera -> Gaussian).
    Returns (N, 3).
    """
    degree = sh_degree_from_bases(sh.shape[-2])
    basis = sh_basis(dirs, degree)  # (N, K)
    return torch.clamp_min((basis[..., :, None] * sh).sum(-2) + 0.5, 0.0)


def rgb_to_sh_dc(rgb: Tensor) -> Tensor:
    """(..., 3) colour -> DC coefficient giving that colour for every direction."""
    return (rgb - 0.5) / SH_C0
