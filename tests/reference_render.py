"""Float64 brute-force per-pixel Gaussian splatting: the independent truth for the rasterizer tests.

Written from the rules of 3DGS/gsplat, sharing no code with ``particlesplat.render``,
``particlesplat.core.sh`` or kornia: every pixel is composited against every Gaussian, front to back,
in a plain loop over the depth-sorted Gaussians. Small N and small images only.

Rules implemented:
    * camera coordinates ``p = w2c · mean``; a Gaussian is kept iff ``near < z < far``; kept
      Gaussians are sorted by ``z``, ties by original index.
    * ``Σ = R diag(s²) Rᵀ`` with ``R`` from the normalised wxyz quaternion (zero quaternion =
      identity rotation, zero gradient).
    * EWA: ``J = [[fx/z, 0, -fx·tx/z], [0, fy/z, -fy·ty/z]]`` with ``tx = clamp(x/z, -(cx/fx +
      0.3·tanx), (W-cx)/fx + 0.3·tanx)``, ``tanx = 0.5·W/fx`` (likewise ``ty``);
      ``Σ2D = J Rw Σ Rwᵀ Jᵀ + 0.3·I``; ``mean2D = (fx·x/z + cx, fy·y/z + cy)`` unclamped.
    * pixel centre ``(u+0.5, v+0.5)``; ``α = min(0.99, o·exp(-½ dᵀ Σ2D⁻¹ d))``; skipped if
      ``α < 1/255``.
    * front to back: ``next_T = T(1-α)``; if ``next_T <= 1e-4`` the pixel stops before this
      Gaussian; else ``w = α·T`` and ``T = next_T``.
    * colour ``max(Σ_k B_k(dir)·sh_k + 0.5, 0)``, ``dir = normalize(mean - camera centre)``.
    * ``rgb = Σ w·c + T·background``, ``alpha = Σ w``, ``depth = Σ w·z / alpha`` (0 where alpha
      is 0), ``owner_weights[p] = Σ w`` over Gaussians owned by ``p``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

ALPHA_MIN = 1.0 / 255.0
ALPHA_MAX = 0.99
T_STOP = 1e-4
DILATION = 0.3
FOV_MARGIN = 0.3

_PI = math.pi
# Real SH normalisation constants from their closed forms (3DGS sign convention below).
_C0 = 0.5 * math.sqrt(1.0 / _PI)
_C1 = math.sqrt(3.0 / (4.0 * _PI))
_C2 = (
    0.5 * math.sqrt(15.0 / _PI),
    -0.5 * math.sqrt(15.0 / _PI),
    0.25 * math.sqrt(5.0 / _PI),
    -0.5 * math.sqrt(15.0 / _PI),
    0.25 * math.sqrt(15.0 / _PI),
)
_C3 = (
    -0.25 * math.sqrt(35.0 / (2.0 * _PI)),
    0.5 * math.sqrt(105.0 / _PI),
    -0.25 * math.sqrt(21.0 / (2.0 * _PI)),
    0.25 * math.sqrt(7.0 / _PI),
    -0.25 * math.sqrt(21.0 / (2.0 * _PI)),
    0.25 * math.sqrt(105.0 / _PI),
    -0.25 * math.sqrt(35.0 / (2.0 * _PI)),
)


@dataclass
class ReferenceResult:
    """Brute-force render. rgb (H, W, 3), alpha (H, W), depth (H, W), transmittance (H, W)
    (final T), owner_weights (P, H, W), background_weight (H, W) (Σ w of owner -1)."""

    rgb: Tensor
    alpha: Tensor
    depth: Tensor
    transmittance: Tensor
    owner_weights: Tensor
    background_weight: Tensor

    def segmentation(self) -> Tensor:
        """(H, W) argmax owner; -1 where background Gaussians plus the empty remainder T weigh most."""
        scores = torch.cat([(self.background_weight + self.transmittance)[None], self.owner_weights], dim=0)
        return scores.argmax(0) - 1


def sh_basis_reference(dirs: Tensor, degree: int) -> Tensor:
    """dirs: (N, 3) unit vectors -> (N, (degree+1)²) real SH values in the 3DGS convention."""
    x, y, z = dirs[:, 0], dirs[:, 1], dirs[:, 2]
    cols = [torch.full_like(x, _C0)]
    if degree >= 1:
        cols += [-_C1 * y, _C1 * z, -_C1 * x]
    if degree >= 2:
        cols += [
            _C2[0] * x * y,
            _C2[1] * y * z,
            _C2[2] * (2 * z * z - x * x - y * y),
            _C2[3] * x * z,
            _C2[4] * (x * x - y * y),
        ]
    if degree >= 3:
        cols += [
            _C3[0] * y * (3 * x * x - y * y),
            _C3[1] * x * y * z,
            _C3[2] * y * (4 * z * z - x * x - y * y),
            _C3[3] * z * (2 * z * z - 3 * x * x - 3 * y * y),
            _C3[4] * x * (4 * z * z - x * x - y * y),
            _C3[5] * z * (x * x - y * y),
            _C3[6] * x * (x * x - 3 * y * y),
        ]
    return torch.stack(cols, dim=-1)


def quat_to_rotmat_reference(quats: Tensor) -> Tensor:
    """quats: (N, 4) wxyz, any norm -> (N, 3, 3) rotation; a zero quaternion gives the identity."""
    sq = (quats * quats).sum(-1, keepdim=True)
    zero = sq == 0
    inv = torch.where(zero, torch.zeros_like(sq), torch.rsqrt(torch.where(zero, torch.ones_like(sq), sq)))
    w, x, y, z = (quats * inv).unbind(-1)
    rows = [
        1 - 2 * (y * y + z * z),
        2 * (x * y - w * z),
        2 * (x * z + w * y),
        2 * (x * y + w * z),
        1 - 2 * (x * x + z * z),
        2 * (y * z - w * x),
        2 * (x * z - w * y),
        2 * (y * z + w * x),
        1 - 2 * (x * x + y * y),
    ]
    return torch.stack(rows, dim=-1).reshape(-1, 3, 3)


def covariance_reference(quats: Tensor, scales: Tensor) -> Tensor:
    """quats (N, 4) wxyz, scales (N, 3) -> (N, 3, 3) R diag(s²) Rᵀ."""
    R = quat_to_rotmat_reference(quats)
    S2 = torch.diag_embed(scales * scales)
    return R @ S2 @ R.transpose(-1, -2)


def project_reference(
    means: Tensor, quats: Tensor, scales: Tensor, K: Tensor, w2c: Tensor, width: int, height: int
) -> tuple[Tensor, Tensor, Tensor]:
    """EWA projection. means (N, 3), quats (N, 4), scales (N, 3), K (3, 3), w2c (4, 4).

    Returns mean2D (N, 2) pixels, Σ2D (N, 2, 2) px² (dilated by 0.3), camera z (N,).
    """
    Rw, t = w2c[:3, :3], w2c[:3, 3]
    p = means @ Rw.T + t
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    tanx, tany = 0.5 * width / fx, 0.5 * height / fy
    tx = torch.minimum(torch.maximum(x / z, -(cx / fx + FOV_MARGIN * tanx)), (width - cx) / fx + FOV_MARGIN * tanx)
    ty = torch.minimum(torch.maximum(y / z, -(cy / fy + FOV_MARGIN * tany)), (height - cy) / fy + FOV_MARGIN * tany)
    zero = torch.zeros_like(z)
    J = torch.stack(
        [torch.stack([fx / z, zero, -fx * tx / z], -1), torch.stack([zero, fy / z, -fy * ty / z], -1)], dim=-2
    )  # (N, 2, 3)
    cov_cam = Rw @ covariance_reference(quats, scales) @ Rw.T
    cov2d = J @ cov_cam @ J.transpose(-1, -2) + DILATION * torch.eye(2, dtype=means.dtype)
    mean2d = torch.stack([fx * x / z + cx, fy * y / z + cy], dim=-1)
    return mean2d, cov2d, z


def reference_render(
    gaussians,
    camera,
    *,
    background=(0.0, 0.0, 0.0),
    near: float = 0.01,
    far: float = 1e10,
    num_owners: int | None = None,
    t_stop: float = T_STOP,
) -> ReferenceResult:
    """Render ``gaussians`` (any object with means/quats/scales/opacities/sh/owner tensors) seen by
    ``camera`` (any object with K (3,3), c2w (4,4), width, height) in float64 by brute force.

    The inputs are converted with ``.double()`` so autograd flows back to float64 leaves.
    ``t_stop`` moves the termination threshold (only to bracket exact ties in tests).
    """
    dt = torch.float64
    means, quats, scales = gaussians.means.double(), gaussians.quats.double(), gaussians.scales.double()
    opac, sh, owner = gaussians.opacities.double(), gaussians.sh.double(), gaussians.owner.long()
    K, c2w = camera.K.detach().to(dt), camera.c2w.detach().to(dt)
    W, H = int(camera.width), int(camera.height)
    w2c = torch.linalg.inv(c2w)
    bg = torch.as_tensor(background, dtype=dt)
    P = num_owners if num_owners is not None else (int(owner.max()) + 1 if owner.numel() else 0)
    P = max(P, 0)

    # cull first (on z alone), so culled Gaussians never enter a division and keep zero gradients
    zs = (means.detach() @ w2c[:3, :3].T + w2c[:3, 3])[:, 2].tolist()
    kept = [i for i in range(means.shape[0]) if near < zs[i] < far]
    kept.sort(key=lambda i: (zs[i], i))
    idx = torch.tensor(kept, dtype=torch.long)
    mean2d, cov2d, z = project_reference(means[idx], quats[idx], scales[idx], K, w2c, W, H)

    degree = int(round(math.sqrt(sh.shape[1]))) - 1
    dirs = means[idx] - c2w[:3, 3]
    dirs = dirs / dirs.norm(dim=-1, keepdim=True)
    colors = torch.clamp_min((sh_basis_reference(dirs, degree)[:, :, None] * sh[idx]).sum(1) + 0.5, 0.0)
    opac, owner = opac[idx], owner[idx]

    v, u = torch.meshgrid(torch.arange(H, dtype=dt), torch.arange(W, dtype=dt), indexing="ij")
    pu, pv = (u + 0.5).reshape(-1), (v + 0.5).reshape(-1)
    T = torch.ones(H * W, dtype=dt)
    done = torch.zeros(H * W, dtype=torch.bool)
    rgb = torch.zeros(H * W, 3, dtype=dt)
    acc = torch.zeros(H * W, dtype=dt)
    dep = torch.zeros(H * W, dtype=dt)
    own = [torch.zeros(H * W, dtype=dt) for _ in range(P)]
    own_bg = torch.zeros(H * W, dtype=dt)
    for i in range(len(kept)):
        a, b, c = cov2d[i, 0, 0], cov2d[i, 0, 1], cov2d[i, 1, 1]
        det = a * c - b * b
        dx, dy = pu - mean2d[i, 0], pv - mean2d[i, 1]
        power = -0.5 * (c * dx * dx - 2 * b * dx * dy + a * dy * dy) / det
        alpha = torch.clamp(opac[i] * torch.exp(power), max=ALPHA_MAX)
        use = (~done) & (alpha >= ALPHA_MIN)
        next_T = T * (1 - alpha)
        stop = use & (next_T <= t_stop)
        done = done | stop
        use = use & ~stop
        w = torch.where(use, alpha * T, torch.zeros_like(T))
        T = torch.where(use, next_T, T)
        rgb = rgb + w[:, None] * colors[i]
        acc = acc + w
        dep = dep + w * z[i]
        if 0 <= int(owner[i]) < P:
            own[int(owner[i])] = own[int(owner[i])] + w
        elif int(owner[i]) < 0:
            own_bg = own_bg + w
    rgb = rgb + T[:, None] * bg
    has = acc > 0
    depth = torch.where(has, dep / torch.where(has, acc, torch.ones_like(acc)), torch.zeros_like(acc))
    owner_w = torch.stack(own).reshape(P, H, W) if P else torch.zeros(0, H, W, dtype=dt)
    return ReferenceResult(
        rgb.reshape(H, W, 3), acc.reshape(H, W), depth.reshape(H, W), T.reshape(H, W), owner_w, own_bg.reshape(H, W)
    )
