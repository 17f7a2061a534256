"""Fused CPU EWA projection: the twin of :func:`particlesplat.rendering.projection.project_views` as one numba
kernel per direction, with the analytic backward.

Per instance (Gaussian ``rows[k]`` seen by camera ``view[k]``), all in float64: camera point p = W m + t, pixel
centre (fx x/z + cx, fy y/z + cy), the Jacobian's x/z and y/z clamped to the field of view + 30 %, A = J W R S with
rows a₀, a₁, the dilated 2D covariance [[a₀·a₀ + ε, a₀·a₁], [a₀·a₁, a₁·a₁ + ε]] and its determinant without
cancellation, |cof(S) Rᵀ Wᵀ (j₀ × j₁)|² + ε tr + ε², whose inverse is the conic. The backward walks the same
formulas in reverse (clamped x/z and y/z pass no gradient to the centre, as in the twin) and returns per-instance
gradients of the mean, the rotation matrix and the scales, which the caller sums per Gaussian.
"""

from __future__ import annotations

import numba
import numpy as np
import torch
from torch import Tensor

from particlesplat.rendering.fused_kernels import jit, parallel_kernel, scatter_add_rows
from particlesplat.rendering.projection import DILATION, FOV_MARGIN, Projected


@jit
def _camera_depths(means, rows, view, w2c, z):
    """z[k] = camera z of instance k, metres (float64)."""
    for k in range(rows.shape[0]):
        r, v = rows[k], view[k]
        z[k] = w2c[v, 2, 0] * means[r, 0] + w2c[v, 2, 1] * means[r, 1] + w2c[v, 2, 2] * means[r, 2] + w2c[v, 2, 3]


@jit
def _vec_mat(v0, v1, v2, M):
    """(v M)_j = Σ_i v_i M_ij for a 3 × 3 array M (a row vector times a matrix), as a tuple."""
    return (
        v0 * M[0, 0] + v1 * M[1, 0] + v2 * M[2, 0],
        v0 * M[0, 1] + v1 * M[1, 1] + v2 * M[2, 1],
        v0 * M[0, 2] + v1 * M[1, 2] + v2 * M[2, 2],
    )


@jit
def _mat_vec(M, v0, v1, v2):
    """(M v)_i = Σ_j M_ij v_j for a 3 × 3 array M, as a tuple."""
    return (
        M[0, 0] * v0 + M[0, 1] * v1 + M[0, 2] * v2,
        M[1, 0] * v0 + M[1, 1] * v1 + M[1, 2] * v2,
        M[2, 0] * v0 + M[2, 1] * v1 + M[2, 2] * v2,
    )


@jit
def _setup(means, rotations, scales, r, Kv, Wv, size):
    """The shared forward quantities of one instance (scalars and 3-tuples; no allocation)."""
    fx, fy, cx, cy = Kv[0, 0], Kv[1, 1], Kv[0, 2], Kv[1, 2]
    m0, m1, m2 = means[r, 0], means[r, 1], means[r, 2]
    x = Wv[0, 0] * m0 + Wv[0, 1] * m1 + Wv[0, 2] * m2 + Wv[0, 3]
    y = Wv[1, 0] * m0 + Wv[1, 1] * m1 + Wv[1, 2] * m2 + Wv[1, 3]
    z = Wv[2, 0] * m0 + Wv[2, 1] * m1 + Wv[2, 2] * m2 + Wv[2, 3]
    tan_x, tan_y = 0.5 * size[0] / fx, 0.5 * size[1] / fy
    lox, hix = -(cx / fx + FOV_MARGIN * tan_x), (size[0] - cx) / fx + FOV_MARGIN * tan_x
    loy, hiy = -(cy / fy + FOV_MARGIN * tan_y), (size[1] - cy) / fy + FOV_MARGIN * tan_y
    xz = min(max(x / z, lox), hix)
    yz = min(max(y / z, loy), hiy)
    free = (lox < x / z < hix, loy < y / z < hiy)
    # rows t0, t1 of J W, and q = jc W with jc = j0 × j1 = kk (xz, yz, 1)
    ax, bx = fx / z, -fx * xz / z
    ay, by = fy / z, -fy * yz / z
    t0 = (ax * Wv[0, 0] + bx * Wv[2, 0], ax * Wv[0, 1] + bx * Wv[2, 1], ax * Wv[0, 2] + bx * Wv[2, 2])
    t1 = (ay * Wv[1, 0] + by * Wv[2, 0], ay * Wv[1, 1] + by * Wv[2, 1], ay * Wv[1, 2] + by * Wv[2, 2])
    kk = fx * fy / (z * z)
    q = (
        kk * (xz * Wv[0, 0] + yz * Wv[1, 0] + Wv[2, 0]),
        kk * (xz * Wv[0, 1] + yz * Wv[1, 1] + Wv[2, 1]),
        kk * (xz * Wv[0, 2] + yz * Wv[1, 2] + Wv[2, 2]),
    )
    R = rotations[r]
    u0 = _vec_mat(t0[0], t0[1], t0[2], R)  # t R; a = (t R) ∘ s are the rows of A = J W R S
    u1 = _vec_mat(t1[0], t1[1], t1[2], R)
    cross = _vec_mat(q[0], q[1], q[2], R)
    s0, s1, s2 = scales[r, 0], scales[r, 1], scales[r, 2]
    a0 = (u0[0] * s0, u0[1] * s1, u0[2] * s2)
    a1 = (u1[0] * s0, u1[1] * s1, u1[2] * s2)
    # the 2D covariance A Aᵀ before dilation: [[sxx, sxy], [sxy, syy]]
    cov = (
        a0[0] * a0[0] + a0[1] * a0[1] + a0[2] * a0[2],
        a1[0] * a1[0] + a1[1] * a1[1] + a1[2] * a1[2],
        a0[0] * a1[0] + a0[1] * a1[1] + a0[2] * a1[2],
    )
    cof = (s1 * s2, s0 * s2, s0 * s1)  # the cofactors of S
    return x, y, z, xz, yz, free, t0, t1, q, kk, u0, u1, cross, a0, a1, cov, cof


@parallel_kernel
def project_forward(means, rotations, scales, rows, view, K, w2c, sizes, means2d, conics, cov_diag, depths):
    """Fill means2d (M, 2) float64, conics (M, 3), cov_diag (M, 2) and depths (M,) of the M kept instances.

    means (N, 3), rotations (N, 3, 3), scales (N, 3): Gaussians; rows, view (M,) int64; K (V, 3, 3), w2c (V, 4, 4)
    float64; sizes (V, 2) int64 (width, height).
    """
    eps = DILATION
    for k in numba.prange(rows.shape[0]):
        r, v = rows[k], view[k]
        Kv = K[v]
        x, y, z, _, _, _, _, _, _, _, _, _, cross, _, _, cov, cof = _setup(
            means, rotations, scales, r, Kv, w2c[v], sizes[v]
        )
        means2d[k, 0] = Kv[0, 0] * x / z + Kv[0, 2]
        means2d[k, 1] = Kv[1, 1] * y / z + Kv[1, 2]
        sxx, syy, sxy = cov
        c0, c1, c2 = cross[0] * cof[0], cross[1] * cof[1], cross[2] * cof[2]
        det = c0 * c0 + c1 * c1 + c2 * c2 + eps * (sxx + syy) + eps * eps
        conics[k, 0] = (syy + eps) / det
        conics[k, 1] = -sxy / det
        conics[k, 2] = (sxx + eps) / det
        cov_diag[k, 0] = sxx + eps
        cov_diag[k, 1] = syy + eps
        depths[k] = z


@parallel_kernel
def project_backward(means, rotations, scales, rows, view, K, w2c, sizes, g2d, gcon, gz, d_mean, d_rot, d_scale):
    """Per-instance gradients d_mean (M, 3), d_rot (M, 3, 3), d_scale (M, 3) from those of means2d (M, 2),
    conics (M, 3) and depths (M,)."""
    eps = DILATION
    for k in numba.prange(rows.shape[0]):
        r, v = rows[k], view[k]
        Kv, Wv = K[v], w2c[v]
        fx, fy = Kv[0, 0], Kv[1, 1]
        x, y, z, xz, yz, free, t0, t1, q, kk, u0, u1, cross, a0, a1, cov, cof = _setup(
            means, rotations, scales, r, Kv, Wv, sizes[v]
        )
        s0, s1, s2 = scales[r, 0], scales[r, 1], scales[r, 2]
        sxx, syy, sxy = cov
        cc = (cross[0] * cof[0], cross[1] * cof[1], cross[2] * cof[2])
        det = cc[0] * cc[0] + cc[1] * cc[1] + cc[2] * cc[2] + eps * (sxx + syy) + eps * eps
        A, C = sxx + eps, syy + eps
        # conic = (C, -sxy, A) / det
        gA, gB, gC = gcon[k, 0], gcon[k, 1], gcon[k, 2]
        d_det = (-gA * C + gB * sxy - gC * A) / (det * det)
        d_sxx = gC / det + eps * d_det
        d_syy = gA / det + eps * d_det
        d_sxy = -gB / det
        da0 = (2 * d_sxx * a0[0] + d_sxy * a1[0], 2 * d_sxx * a0[1] + d_sxy * a1[1], 2 * d_sxx * a0[2] + d_sxy * a1[2])
        da1 = (2 * d_syy * a1[0] + d_sxy * a0[0], 2 * d_syy * a1[1] + d_sxy * a0[1], 2 * d_syy * a1[2] + d_sxy * a0[2])
        du0 = (da0[0] * s0, da0[1] * s1, da0[2] * s2)
        du1 = (da1[0] * s0, da1[1] * s1, da1[2] * s2)
        dcross = (2 * cc[0] * cof[0] * d_det, 2 * cc[1] * cof[1] * d_det, 2 * cc[2] * cof[2] * d_det)
        dcof = (2 * cc[0] * cross[0] * d_det, 2 * cc[1] * cross[1] * d_det, 2 * cc[2] * cross[2] * d_det)
        d_scale[k, 0] = da0[0] * u0[0] + da1[0] * u1[0] + dcof[1] * s2 + dcof[2] * s1
        d_scale[k, 1] = da0[1] * u0[1] + da1[1] * u1[1] + dcof[0] * s2 + dcof[2] * s0
        d_scale[k, 2] = da0[2] * u0[2] + da1[2] * u1[2] + dcof[0] * s1 + dcof[1] * s0
        R = rotations[r]
        for i in range(3):
            for j in range(3):
                d_rot[k, i, j] = t0[i] * du0[j] + t1[i] * du1[j] + q[i] * dcross[j]
        dt0 = _mat_vec(R, du0[0], du0[1], du0[2])
        dt1 = _mat_vec(R, du1[0], du1[1], du1[2])
        dq = _mat_vec(R, dcross[0], dcross[1], dcross[2])
        # q_i = kk (xz W_0i + yz W_1i + W_2i); t0 = (fx/z) W_0 + (-fx xz/z) W_2; t1 likewise with fy, yz, W_1
        d_kk = d_xz = d_yz = d_ax = d_bx = d_ay = d_by = 0.0
        for i in range(3):
            d_kk += dq[i] * (xz * Wv[0, i] + yz * Wv[1, i] + Wv[2, i])
            d_xz += dq[i] * kk * Wv[0, i]
            d_yz += dq[i] * kk * Wv[1, i]
            d_ax += dt0[i] * Wv[0, i]
            d_bx += dt0[i] * Wv[2, i]
            d_ay += dt1[i] * Wv[1, i]
            d_by += dt1[i] * Wv[2, i]
        z2 = z * z
        d_xz += -fx / z * d_bx
        d_yz += -fy / z * d_by
        d_z = gz[k] - 2.0 * kk / z * d_kk
        d_z += -fx / z2 * d_ax + fx * xz / z2 * d_bx - fy / z2 * d_ay + fy * yz / z2 * d_by
        d_x = g2d[k, 0] * fx / z
        d_y = g2d[k, 1] * fy / z
        d_z += -g2d[k, 0] * fx * x / z2 - g2d[k, 1] * fy * y / z2
        if free[0]:  # a clamped x/z passes no gradient to the centre
            d_x += d_xz / z
            d_z += -x / z2 * d_xz
        if free[1]:
            d_y += d_yz / z
            d_z += -y / z2 * d_yz
        for c in range(3):
            d_mean[k, c] = Wv[0, c] * d_x + Wv[1, c] * d_y + Wv[2, c] * d_z


class FusedProjection(torch.autograd.Function):
    """(means (N, 3), rotations (N, 3, 3), scales (N, 3)) -> means2d (M, 2) float64, conics (M, 3),
    depths (M,) and cov2d_diag (M, 2) (not differentiable) of the kept instances ``rows``/``view``."""

    @staticmethod
    def forward(ctx, means, rotations, scales, rows, view, K64, w2c64, sizes):
        dtype = means.dtype
        M = rows.shape[0]
        arrays = [t.detach().double().contiguous() for t in (means, rotations, scales)]
        means2d = torch.empty(M, 2, dtype=torch.float64)
        c_con, c_cov, c_dep = (np.empty((M, 3)), np.empty((M, 2)), np.empty(M))
        if M:
            project_forward(
                *(a.numpy() for a in arrays),
                rows.numpy(),
                view.numpy(),
                K64.numpy(),
                w2c64.numpy(),
                sizes.numpy(),
                means2d.numpy(),
                c_con,
                c_cov,
                c_dep,
            )
        conics, cov, depths = (torch.from_numpy(a).to(dtype) for a in (c_con, c_cov, c_dep))
        ctx.save_for_backward(*arrays, rows, view, K64, w2c64, sizes)
        ctx.dtypes = (means.dtype, rotations.dtype, scales.dtype)
        ctx.mark_non_differentiable(cov)
        return means2d, conics, depths, cov

    @staticmethod
    def backward(ctx, g2d, gcon, gz, _gcov):
        means, rotations, scales, rows, view, K64, w2c64, sizes = ctx.saved_tensors
        M = rows.shape[0]
        d_mean, d_rot, d_scale = np.zeros((M, 3)), np.zeros((M, 3, 3)), np.zeros((M, 3))
        zeros = torch.zeros
        g2d = zeros(M, 2, dtype=torch.float64) if g2d is None else g2d.double().contiguous()
        gcon = zeros(M, 3, dtype=torch.float64) if gcon is None else gcon.double().contiguous()
        gz = zeros(M, dtype=torch.float64) if gz is None else gz.double().contiguous()
        if M:
            project_backward(
                means.numpy(),
                rotations.numpy(),
                scales.numpy(),
                rows.numpy(),
                view.numpy(),
                K64.numpy(),
                w2c64.numpy(),
                sizes.numpy(),
                g2d.numpy(),
                gcon.numpy(),
                gz.numpy(),
                d_mean,
                d_rot,
                d_scale,
            )
        N = means.shape[0]
        dm, dr, ds = (torch.zeros(N, *a.shape[1:], dtype=torch.float64) for a in (d_mean, d_rot, d_scale))
        for summed, per_instance in ((dm, d_mean), (dr, d_rot), (ds, d_scale)):
            if M:  # per instance -> per Gaussian: index_add_ along rows, bit for bit
                scatter_add_rows(rows.numpy(), per_instance.reshape(M, -1), summed.numpy().reshape(N, -1))
        tm, tr, ts = ctx.dtypes
        return dm.to(tm), dr.to(tr), ds.to(ts), None, None, None, None, None


def project_views_fused(
    means: Tensor, rotations: Tensor, scales: Tensor, rows: Tensor, view: Tensor, cameras, near: float, far: float
) -> Projected:
    """:func:`~particlesplat.rendering.projection.project_views` on the fused kernels (CPU tensors); the same
    arguments, results to float32 rounding, and gradients with respect to means, rotations and scales."""
    K64 = torch.stack([c.K for c in cameras]).to(torch.float64).contiguous()
    w2c64 = torch.stack([c.w2c for c in cameras]).to(torch.float64).contiguous()
    sizes = torch.tensor([[c.width, c.height] for c in cameras], dtype=torch.int64)
    z = np.empty(rows.shape[0])
    _camera_depths(means.detach().double().contiguous().numpy(), rows.numpy(), view.numpy(), w2c64.numpy(), z)
    index = torch.from_numpy(np.nonzero((z > near) & (z < far))[0].astype(np.int64))
    kept_rows, kept_view = rows.index_select(0, index).contiguous(), view.index_select(0, index).contiguous()
    means2d, conics, depths, cov = FusedProjection.apply(
        means, rotations, scales, kept_rows, kept_view, K64, w2c64, sizes
    )
    return Projected(index, means2d, conics, cov, depths)
