"""EWA projection of 3D Gaussians to screen-space conics (the 3DGS / gsplat rules).

Everything here is plain differentiable torch; the rasterizer consumes its output.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import torch
from torch import Tensor

from particlesplat.core.camera import Camera
from particlesplat.core.gaussians import Gaussians, quats_to_rotations

DILATION = 0.3  # px², added to the 2D covariance diagonal
ALPHA_MIN = 1.0 / 255.0  # a Gaussian contributes exactly where alpha >= ALPHA_MIN
ALPHA_MAX = 0.99
FOV_MARGIN = 0.3  # the Jacobian's x/z, y/z are clamped to the field of view + 30 %


@dataclass
class Projected:
    """The M Gaussians in front of the camera, in their original order.

    Attributes:
        index: (M,) int64 index into the input Gaussians.
        means2d: (M, 2) float64 pixel coordinates of the centres (pixel u spans [u, u+1)).
        conics: (M, 3) inverse 2D covariance (a, b, c) of [[a, b], [b, c]], px⁻².
        cov2d_diag: (M, 2) diagonal of the dilated 2D covariance, px².
        depths: (M,) planar camera z, metres.
    """

    index: Tensor
    means2d: Tensor
    conics: Tensor
    cov2d_diag: Tensor
    depths: Tensor


def project_gaussians(gaussians: Gaussians, camera: Camera, near: float = 0.01, far: float = 1e10) -> Projected:
    """Project the Gaussians with near < z < far (strict) by EWA splatting (:func:`project_views` with one
    view)."""
    n = len(gaussians)
    rows = torch.arange(n, device=gaussians.means.device)
    return project_views(
        gaussians.means,
        quats_to_rotations(gaussians.quats),
        gaussians.scales,
        rows,
        torch.zeros_like(rows),
        [camera],
        near,
        far,
    )


def project_views(
    means: Tensor,
    rotations: Tensor,
    scales: Tensor,
    rows: Tensor,
    view: Tensor,
    cameras: Sequence[Camera],
    near: float = 0.01,
    far: float = 1e10,
) -> Projected:
    """Project Gaussians into several views at once: instance i is Gaussian ``rows[i]`` seen by
    ``cameras[view[i]]``; those with near < z < far (strict) are kept, in instance order.

    means: (N, 3) world metres; rotations: (N, 3, 3) (of the quaternions: a Gaussian's rotation is computed once,
    however many views see it); scales: (N, 3); rows, view: (I,) int64. ``Projected.index`` indexes the
    instances. The cameras must have the dtype and device of ``means``.

    The determinant of the dilated 2D covariance is computed without cancellation:
    det(AAᵀ + εI) = |cof(S) Rᵀ (t₀ × t₁)|² + ε tr(AAᵀ) + ε², with A = J W R S and tₖ the rows
    of J W, so needles and edge-on discs keep full float32 precision.
    """
    dtype, device = means.dtype, means.device
    K64 = torch.stack([c.K for c in cameras]).to(torch.float64)  # (V, 3, 3)
    w2c64 = torch.stack([c.w2c for c in cameras]).to(torch.float64)  # (V, 4, 4)
    # Centres are projected in float64 (a per-Gaussian cost): in float32, camera coordinates of
    # a point 3 m away carry ~3e-7 m of rounding, ~1e-4 px at 512², which α would feel.
    m64 = means.to(torch.float64).index_select(0, rows)
    W64 = w2c64.index_select(0, view)  # (I, 4, 4)
    p64_all = W64[:, :3, 0] * m64[:, :1] + W64[:, :3, 1] * m64[:, 1:2] + W64[:, :3, 2] * m64[:, 2:] + W64[:, :3, 3]
    z_all = p64_all[:, 2]
    index = torch.nonzero((z_all > near) & (z_all < far)).squeeze(1)
    p64 = p64_all.index_select(0, index)
    v = view.index_select(0, index)
    Kv = K64.index_select(0, v)  # (M, 3, 3)
    means2d = torch.stack(
        [Kv[:, 0, 0] * p64[:, 0] / p64[:, 2] + Kv[:, 0, 2], Kv[:, 1, 1] * p64[:, 1] / p64[:, 2] + Kv[:, 1, 2]], dim=-1
    )
    Rw = W64.index_select(0, index)[:, :3, :3].to(dtype)  # (M, 3, 3) world -> camera
    x, y, z = p64.to(dtype).unbind(-1)
    Kd = Kv.to(dtype)
    fx, fy, cx, cy = Kd[:, 0, 0], Kd[:, 1, 1], Kd[:, 0, 2], Kd[:, 1, 2]
    size = torch.tensor([[c.width, c.height] for c in cameras], dtype=dtype, device=device).index_select(0, v)
    W, H = size[:, 0], size[:, 1]
    tan_x, tan_y = 0.5 * W / fx, 0.5 * H / fy
    xz = torch.minimum(torch.maximum(x / z, -(cx / fx + FOV_MARGIN * tan_x)), (W - cx) / fx + FOV_MARGIN * tan_x)
    yz = torch.minimum(torch.maximum(y / z, -(cy / fy + FOV_MARGIN * tan_y)), (H - cy) / fy + FOV_MARGIN * tan_y)
    # rows of J W (M, 3): J's rows are (fx/z, 0, -fx xz/z) and (0, fy/z, -fy yz/z)
    t0 = (fx / z)[:, None] * Rw[:, 0] + (-fx * xz / z)[:, None] * Rw[:, 2]
    t1 = (fy / z)[:, None] * Rw[:, 1] + (-fy * yz / z)[:, None] * Rw[:, 2]
    kept = rows.index_select(0, index)
    R = rotations.index_select(0, kept)  # (M, 3, 3)
    s = scales.index_select(0, kept)
    a0 = (t0[:, None, :] @ R).squeeze(1) * s  # rows of A = J W R S
    a1 = (t1[:, None, :] @ R).squeeze(1) * s
    sxx, syy, sxy = (a0 * a0).sum(-1), (a1 * a1).sum(-1), (a0 * a1).sum(-1)
    # (J W) rows cross product, analytically: t0 x t1 = Wᵀ (j0 x j1), j0 x j1 = fx fy / z² (x/z, y/z, 1)
    jcross = (fx * fy / (z * z))[:, None] * torch.stack([xz, yz, torch.ones_like(z)], dim=-1)
    cross = ((jcross[:, None, :] @ Rw) @ R).squeeze(1)  # Rᵀ Wᵀ (j0 x j1) as a row vector, (M, 3)
    cof = torch.stack([s[:, 1] * s[:, 2], s[:, 0] * s[:, 2], s[:, 0] * s[:, 1]], dim=-1)
    det_raw = ((cross * cof) ** 2).sum(-1)
    a, c = sxx + DILATION, syy + DILATION
    det = det_raw + DILATION * (sxx + syy) + DILATION * DILATION
    conics = torch.stack([c / det, -sxy / det, a / det], dim=-1)
    return Projected(index, means2d, conics, torch.stack([a, c], dim=-1), z)


def footprint_radius_sq(opacities: Tensor) -> Tensor:
    """(M,) squared Mahalanobis radius inside which o·exp(-½ r²) >= 1/255: 2 ln(255 o); < 0 if never."""
    return 2.0 * torch.log(opacities.clamp_min(1e-30) * 255.0)


def footprint_extents(projected: Projected, opacities: Tensor) -> Tensor:
    """(M, 2) half extents (pixels) of the box around each projected centre outside which α < 1/255; -1 where a
    Gaussian reaches 1/255 nowhere. opacities: (M,) of the projected Gaussians (``opacities[projected.index]``).

    The ellipse dᵀΣ⁻¹d <= r² spans r·sqrt(Σ_xx), r·sqrt(Σ_yy); a hair of margin keeps float rounding from dropping
    a boundary pixel."""
    r2 = footprint_radius_sq(opacities.detach())
    return torch.where(
        r2[:, None] >= 0,
        torch.sqrt(r2.clamp_min(0))[:, None] * projected.cov2d_diag.detach().sqrt() * (1 + 1e-5) + 1e-3,
        torch.full_like(projected.cov2d_diag, -1.0),
    )
