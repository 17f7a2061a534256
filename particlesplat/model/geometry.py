"""Batched camera geometry for the decoder: rays, lifting, covariances, SH rotation.

Conventions follow :class:`particlesplat.core.camera.Camera`: OpenCV axes, pixel ``(u, v)`` has its
centre at ``(u + 0.5, v + 0.5)``, rays ``R K^-1 [x, y, 1]`` have camera-z component 1.
"""

from __future__ import annotations

import torch
from kornia.geometry.conversions import quaternion_to_rotation_matrix, rotation_matrix_to_quaternion
from torch import Tensor

from particlesplat.core.camera import Camera
from particlesplat.model.eigh3 import eigh3


def stack_cameras(cameras: list[Camera], device=None, dtype=torch.float32) -> tuple[Tensor, Tensor]:
    """cameras (V) -> K (V, 3, 3), c2w (V, 4, 4)."""
    K = torch.stack([c.K.to(device=device, dtype=dtype) for c in cameras])
    c2w = torch.stack([c.c2w.to(device=device, dtype=dtype) for c in cameras])
    return K, c2w


def ray_dirs(pix: Tensor, K: Tensor, c2w: Tensor) -> Tensor:
    """Unnormalised world ray directions through continuous pixel coordinates.

    pix: (..., N, 2) pixels; K: (..., 3, 3); c2w: (..., 4, 4) -> (..., N, 3) with camera z = 1.
    """
    fx, fy = K[..., 0, 0, None], K[..., 1, 1, None]
    cx, cy = K[..., 0, 2, None], K[..., 1, 2, None]
    x = (pix[..., 0] - cx) / fx
    y = (pix[..., 1] - cy) / fy
    d_cam = torch.stack([x, y, torch.ones_like(x)], dim=-1)
    return d_cam @ c2w[..., :3, :3].transpose(-1, -2)


def plucker_at(pix: Tensor, K: Tensor, c2w: Tensor) -> Tensor:
    """pix: (..., N, 2) pixels -> (..., N, 6) Plücker coordinates (unit d, o x d)."""
    d = torch.nn.functional.normalize(ray_dirs(pix, K, c2w), dim=-1)
    o = c2w[..., None, :3, 3].expand_as(d)
    return torch.cat([d, torch.cross(o, d, dim=-1)], dim=-1)


def plucker_map(K: Tensor, c2w: Tensor, height: int, width: int) -> Tensor:
    """K: (B, 3, 3), c2w: (B, 4, 4) -> (B, 6, H, W) Plücker ray map at pixel centres."""
    v, u = torch.meshgrid(
        torch.arange(height, device=K.device, dtype=K.dtype) + 0.5,
        torch.arange(width, device=K.device, dtype=K.dtype) + 0.5,
        indexing="ij",
    )
    pix = torch.stack([u, v], dim=-1).reshape(1, -1, 2).expand(K.shape[0], -1, -1)
    return plucker_at(pix, K, c2w).transpose(1, 2).reshape(K.shape[0], 6, height, width)


class _SafeEigh(torch.autograd.Function):
    """Symmetric 3x3 eigendecomposition (closed form, :func:`.eigh3`) whose backward damps 1/(λj-λi) for
    near-equal eigenvalues."""

    @staticmethod
    def forward(ctx, A: Tensor):  # noqa: D102
        lam, U = eigh3(A)
        ctx.save_for_backward(lam, U)
        return lam, U

    @staticmethod
    def backward(ctx, g_lam: Tensor, g_U: Tensor):  # noqa: D102
        lam, U = ctx.saved_tensors
        diff = lam[..., None, :] - lam[..., :, None]  # λj - λi
        eps = (1e-6 * lam.abs().amax(-1, keepdim=True)[..., None]) ** 2 + 1e-30
        F = diff / (diff * diff + eps)
        F = F - torch.diag_embed(torch.diagonal(F, dim1=-2, dim2=-1))
        inner = torch.diag_embed(g_lam) + F * (U.transpose(-1, -2) @ g_U)
        G = U @ inner @ U.transpose(-1, -2)
        return 0.5 * (G + G.transpose(-1, -2))


def covariance_to_quat_scale(M: Tensor, fused: bool | None = None) -> tuple[Tensor, Tensor]:
    """Factor Σ = M Mᵀ as R(q) diag(s²) R(q)ᵀ.

    M: (..., 3, 3) -> quats (..., 4) wxyz, scales (..., 3) (standard deviations).
    Differentiable; the eigendecomposition runs in float64. ``fused`` (default: on the CPU) runs it in the numba
    kernels of :mod:`.shape_kernels`, the same formulas per Gaussian; False: the torch ops below, their twin.
    """
    if (M.device.type == "cpu") if fused is None else fused:
        from particlesplat.model.shape_kernels import FusedShapes

        return FusedShapes.apply(M)
    dtype = M.dtype
    M64 = M.to(torch.float64)
    cov = M64 @ M64.transpose(-1, -2)
    lam, U = _SafeEigh.apply(cov)  # U is a rotation (eigh3 signs its columns so)
    q = rotation_matrix_to_quaternion(U.contiguous(), eps=1e-12)
    scales = torch.sqrt(lam.clamp_min(1e-20))
    return q.to(dtype), scales.to(dtype)


def camera_covariance_factor(quat_raw: Tensor, scales: Tensor, jacobian: Tensor) -> Tensor:
    """M = J R(q) diag(s): the factor of Σ = M Mᵀ in the camera-aligned frame.

    quat_raw: (..., 4) unnormalised wxyz; scales: (..., 3); jacobian: (..., 3) diagonal of J
    (metres per canonical unit). Returns (..., 3, 3).
    """
    q = quat_raw / (quat_raw.norm(dim=-1, keepdim=True) + 1e-8)
    Rq = quaternion_to_rotation_matrix(q)
    return jacobian[..., :, None] * Rq * scales[..., None, :]


def rotate_sh_to_world(sh: Tensor, R: Tensor) -> Tensor:
    """Rotate SH coefficients from a camera frame into the world (degree 0 or 1).

    sh: (..., K, 3) with K in {1, 4}; R: (..., 3, 3) camera-to-world rotation broadcastable to sh's
    leading dims. A colour evaluated along camera direction d equals the rotated coefficients'
    colour along R d.
    """
    if sh.shape[-2] == 1:
        return sh
    if sh.shape[-2] != 4:
        raise ValueError(f"rotate_sh_to_world supports SH degree 0 or 1, got {sh.shape[-2]} coefficients")
    c1, c2, c3 = sh[..., 1, :], sh[..., 2, :], sh[..., 3, :]
    a = torch.stack([-c3, -c1, c2], dim=-2)  # (..., 3 xyz, 3 rgb): colour_band1 = C1 * aᵀ d
    a_w = R @ a
    band = torch.stack([-a_w[..., 1, :], a_w[..., 2, :], -a_w[..., 0, :]], dim=-2)
    return torch.cat([sh[..., :1, :], band], dim=-2)


__all__ = [
    "stack_cameras",
    "ray_dirs",
    "plucker_at",
    "plucker_map",
    "covariance_to_quat_scale",
    "camera_covariance_factor",
    "rotate_sh_to_world",
]
