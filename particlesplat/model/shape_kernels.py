"""Numba kernels of :func:`~particlesplat.model.geometry.covariance_to_quat_scale` on the CPU, forward and backward.

The torch path factors Σ = M Mᵀ of every Gaussian with about a hundred elementwise ops over the batch (the
closed-form :func:`~particlesplat.model.eigh3.eigh3`, then kornia's quaternion of the eigenvectors), and its backward
as many again: on a full-resolution training step's 131,072 background Gaussians, about a tenth of the step. These
kernels do the same per Gaussian in one pass each, in float64, with the same formulas and branches: the closed-form
eigendecomposition (eigenvalues ascending, eigenvectors signed to a rotation), kornia's branch for the quaternion
(``eps`` 1e-12), scales ``sqrt(max(λ, 1e-20))``; the backward is the analytic derivative of that branch, then
:class:`~particlesplat.model.geometry._SafeEigh`'s damped eigenvector derivative, then Σ = M Mᵀ. The torch path
stays their twin, and the path on other devices; tests compare the two.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from numba import prange
from torch import Tensor

from particlesplat.rendering.fused_kernels import jit, parallel_kernel

QUAT_EPS = 1e-12  # kornia's radicand floor, as covariance_to_quat_scale asks for it
LAM_FLOOR = 1e-20  # the least variance a scale is taken from


@jit
def _sym_times(a00, a11, a22, a01, a02, a12, x):
    """The symmetric matrix [[a00, a01, a02], [a01, a11, a12], [a02, a12, a22]] times the 3-tuple x."""
    return (
        a00 * x[0] + a01 * x[1] + a02 * x[2],
        a01 * x[0] + a11 * x[1] + a12 * x[2],
        a02 * x[0] + a12 * x[1] + a22 * x[2],
    )


@jit
def _eigh3(S: np.ndarray, lam: np.ndarray, U: np.ndarray) -> None:
    """:func:`~particlesplat.model.eigh3.eigh3` of one symmetric 3 × 3 matrix S, op for op: lam (3,) ascending,
    U (3, 3) eigenvectors in its columns, a rotation. S is read before U is written, so U may be S."""
    a00, a11, a22, a01, a02, a12 = S[0, 0], S[1, 1], S[2, 2], S[0, 1], S[0, 2], S[1, 2]
    m = max(max(abs(a00), abs(a11)), abs(a22))
    m = max(m, max(max(abs(a01), abs(a02)), abs(a12)))
    m = max(m, 1e-300)
    inv = 1.0 / m
    a00, a11, a22, a01, a02, a12 = a00 * inv, a11 * inv, a22 * inv, a01 * inv, a02 * inv, a12 * inv
    q = (a00 + a11 + a22) / 3
    b00, b11, b22 = a00 - q, a11 - q, a22 - q
    p = math.sqrt((b00 * b00 + b11 * b11 + b22 * b22 + 2 * (a01 * a01 + a02 * a02 + a12 * a12)) / 6)
    det_b = b00 * (b11 * b22 - a12 * a12) - a01 * (a01 * b22 - a12 * a02) + a02 * (a01 * a12 - b11 * a02)
    r = min(max(det_b / max(2 * p * p * p, 1e-300), -1.0), 1.0)
    phi = math.acos(r) / 3
    top = q + 2 * p * math.cos(phi)
    bottom = q + 2 * p * math.cos(phi + 2 * math.pi / 3)
    middle = 3 * q - top - bottom
    top_apart = (top - middle) >= (middle - bottom)
    lam0 = top if top_apart else bottom
    r0 = (a00 - lam0, a01, a02)
    r1 = (a01, a11 - lam0, a12)
    r2 = (a02, a12, a22 - lam0)
    c01 = (r0[1] * r1[2] - r0[2] * r1[1], r0[2] * r1[0] - r0[0] * r1[2], r0[0] * r1[1] - r0[1] * r1[0])
    c02 = (r0[1] * r2[2] - r0[2] * r2[1], r0[2] * r2[0] - r0[0] * r2[2], r0[0] * r2[1] - r0[1] * r2[0])
    c12 = (r1[1] * r2[2] - r1[2] * r2[1], r1[2] * r2[0] - r1[0] * r2[2], r1[0] * r2[1] - r1[1] * r2[0])
    n01 = c01[0] * c01[0] + c01[1] * c01[1] + c01[2] * c01[2]
    n02 = c02[0] * c02[0] + c02[1] * c02[1] + c02[2] * c02[2]
    n12 = c12[0] * c12[0] + c12[1] * c12[1] + c12[2] * c12[2]
    v = c01 if n01 >= n02 else c02
    nv = max(n01, n02)
    v = v if nv >= n12 else c12
    nv = max(nv, n12)
    if nv > 1e-300:
        k = 1.0 / math.sqrt(max(nv, 1e-300))
        v0 = (v[0] * k, v[1] * k, v[2] * k)
    else:
        v0 = (1.0, 0.0, 0.0)
    if abs(v0[0]) > abs(v0[2]):
        u = (-v0[1], v0[0], 0.0)
    else:
        u = (0.0, -v0[2], v0[1])
    k = 1.0 / math.sqrt(u[0] * u[0] + u[1] * u[1] + u[2] * u[2])
    u = (u[0] * k, u[1] * k, u[2] * k)
    w = (v0[1] * u[2] - v0[2] * u[1], v0[2] * u[0] - v0[0] * u[2], v0[0] * u[1] - v0[1] * u[0])
    au = _sym_times(a00, a11, a22, a01, a02, a12, u)
    aw = _sym_times(a00, a11, a22, a01, a02, a12, w)
    a = u[0] * au[0] + u[1] * au[1] + u[2] * au[2]
    b = u[0] * aw[0] + u[1] * aw[1] + u[2] * aw[2]
    c = w[0] * aw[0] + w[1] * aw[1] + w[2] * aw[2]
    theta = 0.5 * math.atan2(2 * b, a - c)
    cos, sin = math.cos(theta), math.sin(theta)
    e_hi = (cos * u[0] + sin * w[0], cos * u[1] + sin * w[1], cos * u[2] + sin * w[2])
    e_lo = (sin * u[0] - cos * w[0], sin * u[1] - cos * w[1], sin * u[2] - cos * w[2])
    half = math.sqrt(0.25 * (a - c) * (a - c) + b * b)
    lam_hi, lam_lo = 0.5 * (a + c) + half, 0.5 * (a + c) - half
    av0 = _sym_times(a00, a11, a22, a01, a02, a12, v0)
    lam_v0 = v0[0] * av0[0] + v0[1] * av0[1] + v0[2] * av0[2]
    if top_apart:
        cols, vals = (e_lo, e_hi, v0), (lam_lo, lam_hi, lam_v0)
    else:
        cols, vals = (v0, e_lo, e_hi), (lam_v0, lam_lo, lam_hi)
    for j in range(3):
        lam[j] = vals[j] * m
        for i in range(3):
            U[i, j] = cols[j][i]


@jit
def _quat_branch(R: np.ndarray) -> int:
    """Which of kornia's four formulas gives the quaternion of R: 0 (trace > 0), else 1, 2 or 3 (the largest
    diagonal entry's axis), as ``rotation_matrix_to_quaternion`` picks them."""
    if R[0, 0] + R[1, 1] + R[2, 2] > 0.0:
        return 0
    if R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        return 1
    return 2 if R[1, 1] > R[2, 2] else 3


# per branch: the sign of each diagonal entry in the radicand, and the off-diagonal pairs (i, j, sign of (j, i)) of
# the three other components in the order of their slots (w, x, y, z without the branch's own)
_RADICAND = np.array([[1.0, 1.0, 1.0], [1.0, -1.0, -1.0], [-1.0, 1.0, -1.0], [-1.0, -1.0, 1.0]])
# for component c (0 w, 1 x, 2 y, 3 z) of branch k: (i, j, s) with numerator R[i, j] + s R[j, i]; the branch's own
# component has i = -1
_PAIRS = np.array(
    [
        [[-1, -1, 0], [2, 1, -1], [0, 2, -1], [1, 0, -1]],
        [[2, 1, -1], [-1, -1, 0], [0, 1, 1], [0, 2, 1]],
        [[0, 2, -1], [0, 1, 1], [-1, -1, 0], [1, 2, 1]],
        [[1, 0, -1], [0, 2, 1], [1, 2, 1], [-1, -1, 0]],
    ],
    dtype=np.int64,
)


@jit
def _quaternion(R: np.ndarray, q: np.ndarray) -> None:
    """kornia's ``rotation_matrix_to_quaternion(R, eps=QUAT_EPS)`` of one rotation, wxyz into q (4,)."""
    k = _quat_branch(R)
    r = 1.0 + _RADICAND[k, 0] * R[0, 0] + _RADICAND[k, 1] * R[1, 1] + _RADICAND[k, 2] * R[2, 2]
    sq = 2.0 * math.sqrt(r) if r > QUAT_EPS else 2.0 * math.sqrt(QUAT_EPS)
    for c in range(4):
        i, j, s = _PAIRS[k, c, 0], _PAIRS[k, c, 1], _PAIRS[k, c, 2]
        q[c] = 0.25 * sq if i < 0 else (R[i, j] + s * R[j, i]) / sq  # sq >= 2e-6: kornia's guard never acts


@jit
def _quaternion_grad(R: np.ndarray, g_q: np.ndarray, g_R: np.ndarray) -> None:
    """The gradient of :func:`_quaternion` with respect to R, for the upstream g_q (4,): into g_R (3, 3)."""
    k = _quat_branch(R)
    r = 1.0 + _RADICAND[k, 0] * R[0, 0] + _RADICAND[k, 1] * R[1, 1] + _RADICAND[k, 2] * R[2, 2]
    live = r > QUAT_EPS  # below the floor sq is a constant
    sq = 2.0 * math.sqrt(r) if live else 2.0 * math.sqrt(QUAT_EPS)  # >= 2e-6: kornia's division guard never acts
    g_sq = 0.0
    for a in range(3):
        for b in range(3):
            g_R[a, b] = 0.0
    for c in range(4):
        i, j, s = _PAIRS[k, c, 0], _PAIRS[k, c, 1], _PAIRS[k, c, 2]
        if i < 0:
            g_sq += 0.25 * g_q[c]
        else:
            g_R[i, j] += g_q[c] / sq
            g_R[j, i] += s * g_q[c] / sq
            g_sq -= g_q[c] * (R[i, j] + s * R[j, i]) / (sq * sq)
    if live:
        g_r = g_sq / math.sqrt(r)  # d(2 sqrt r)/dr
        for a in range(3):
            g_R[a, a] += _RADICAND[k, a] * g_r


@parallel_kernel
def shapes_forward(M, quats, scales, lam, U):
    """Per Gaussian n: Σ = M[n] M[n]ᵀ, its eigenvalues lam[n] (ascending) and eigenvectors U[n] (columns, a
    rotation), quats[n] (wxyz) and scales[n] = sqrt(max(lam, 1e-20)). M: (N, 3, 3) float64; the rest written."""
    for n in prange(M.shape[0]):
        S = U[n]  # Σ, then its eigenvectors in place: _eigh3 reads S before it writes U
        for i in range(3):
            for j in range(3):
                S[i, j] = M[n, i, 0] * M[n, j, 0] + M[n, i, 1] * M[n, j, 1] + M[n, i, 2] * M[n, j, 2]
        _eigh3(S, lam[n], U[n])
        _quaternion(U[n], quats[n])
        for j in range(3):
            scales[n, j] = math.sqrt(max(lam[n, j], LAM_FLOOR))


SCRATCH_CHUNK = 256  # Gaussians that share one scratch allocation in the backward (one each cost 1.6x the time)


@parallel_kernel
def shapes_backward(M, lam, U, g_quats, g_scales, g_M):
    """The gradient of :func:`shapes_forward`'s quats and scales with respect to M, into g_M (N, 3, 3).

    g_quats (N, 4), g_scales (N, 3) the upstream gradients (float64). The eigenvector part is damped as
    :class:`~particlesplat.model.geometry._SafeEigh` damps it: F_ij = d / (d² + ε), d = λj − λi,
    ε = (1e-6 max|λ|)² + 1e-30."""
    N = M.shape[0]
    for chunk in prange((N + SCRATCH_CHUNK - 1) // SCRATCH_CHUNK):
        work = np.empty((4, 3, 3))
        g_U, inner, G, g_lam = work[0], work[1], work[2], work[3, 0]
        for n in range(chunk * SCRATCH_CHUNK, min(N, (chunk + 1) * SCRATCH_CHUNK)):
            _quaternion_grad(U[n], g_quats[n], g_U)
            for j in range(3):
                # clamp_min passes the gradient where lam >= the floor; sqrt's is 1 / (2 sqrt)
                g_lam[j] = g_scales[n, j] * 0.5 / math.sqrt(lam[n, j]) if lam[n, j] >= LAM_FLOOR else 0.0
            eps = (1e-6 * max(max(abs(lam[n, 0]), abs(lam[n, 1])), abs(lam[n, 2]))) ** 2 + 1e-30
            for i in range(3):  # inner = diag(g_lam) + F ∘ (Uᵀ g_U)
                for j in range(3):
                    d = lam[n, j] - lam[n, i]
                    utg = U[n, 0, i] * g_U[0, j] + U[n, 1, i] * g_U[1, j] + U[n, 2, i] * g_U[2, j]
                    inner[i, j] = g_lam[i] if i == j else d / (d * d + eps) * utg
            for a in range(3):  # G = U inner Uᵀ
                for b in range(3):
                    acc = 0.0
                    for i in range(3):
                        for j in range(3):
                            acc += U[n, a, i] * inner[i, j] * U[n, b, j]
                    G[a, b] = acc
            # g_Σ = (G + Gᵀ) / 2; Σ = M Mᵀ gives g_M = (g_Σ + g_Σᵀ) M = (G + Gᵀ) M
            for a in range(3):
                for c in range(3):
                    acc = 0.0
                    for b in range(3):
                        acc += (G[a, b] + G[b, a]) * M[n, b, c]
                    g_M[n, a, c] = acc


class FusedShapes(torch.autograd.Function):
    """M (..., 3, 3) -> quats (..., 4) wxyz, scales (..., 3) in M's dtype: ``covariance_to_quat_scale`` on the
    kernels above (CPU tensors)."""

    @staticmethod
    def forward(ctx, M: Tensor):  # noqa: D102
        lead = M.shape[:-2]
        m64 = M.detach().to(torch.float64).reshape(-1, 3, 3).contiguous()
        N = m64.shape[0]
        quats, scales = torch.empty(N, 4, dtype=torch.float64), torch.empty(N, 3, dtype=torch.float64)
        lam, U = torch.empty(N, 3, dtype=torch.float64), torch.empty(N, 3, 3, dtype=torch.float64)
        if N:
            shapes_forward(m64.numpy(), quats.numpy(), scales.numpy(), lam.numpy(), U.numpy())
        ctx.save_for_backward(m64, lam, U)
        ctx.lead, ctx.dtype = lead, M.dtype
        return quats.to(M.dtype).reshape(*lead, 4), scales.to(M.dtype).reshape(*lead, 3)

    @staticmethod
    def backward(ctx, g_quats: Tensor | None, g_scales: Tensor | None):  # noqa: D102
        m64, lam, U = ctx.saved_tensors
        N = m64.shape[0]
        gq, gs = (
            torch.zeros(N, k, dtype=torch.float64) if g is None else g.reshape(N, k).double().contiguous()
            for g, k in ((g_quats, 4), (g_scales, 3))
        )
        g_M = torch.empty(N, 3, 3, dtype=torch.float64)
        if N:
            shapes_backward(m64.numpy(), lam.numpy(), U.numpy(), gq.numpy(), gs.numpy(), g_M.numpy())
        return g_M.to(ctx.dtype).reshape(*ctx.lead, 3, 3)
