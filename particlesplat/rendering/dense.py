"""Naive dense renderer: every pixel against every Gaussian at once (the benchmark's baseline).

Written independently of the tiled path (own projection with the plain 2×2 inverse, plain
autograd), it follows the same rules as :func:`particlesplat.render`. Memory is
O(H·W·N): use it only for small cases (the benchmark checks the size first).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor

from particlesplat.core.camera import Camera
from particlesplat.core.gaussians import Gaussians, quats_to_rotations
from particlesplat.core.sh import eval_sh_colors


def render_dense(
    gaussians: Gaussians,
    camera: Camera,
    *,
    background: Sequence[float] | Tensor = (0.0, 0.0, 0.0),
    near: float = 0.01,
    far: float = 1e10,
    pixel_chunk: int | None = None,
) -> tuple[Tensor, Tensor, Tensor]:
    """Returns rgb (H, W, 3), alpha (H, W), depth (H, W) in the dtype of ``gaussians``.

    ``pixel_chunk`` evaluates that many pixels at a time (for a memory-bounded forward-only
    reference; under autograd every chunk's graph is still kept).
    """
    dt, dev = gaussians.means.dtype, gaussians.means.device
    cam = camera.to(device=dev, dtype=dt)
    w2c = cam.w2c
    p = gaussians.means @ w2c[:3, :3].T + w2c[:3, 3]
    keep = (p[:, 2] > near) & (p[:, 2] < far)
    p = p[keep]
    order = torch.sort(p[:, 2].detach(), stable=True).indices
    p = p[order]
    sel = torch.nonzero(keep).squeeze(1)[order]
    x, y, z = p.unbind(-1)
    fx, fy, cx, cy = cam.K[0, 0], cam.K[1, 1], cam.K[0, 2], cam.K[1, 2]
    W, H = cam.width, cam.height
    lim = lambda c, f, n: (-(c / f + 0.3 * 0.5 * n / f), (n - c) / f + 0.3 * 0.5 * n / f)  # noqa: E731
    lx, ly = lim(cx, fx, W), lim(cy, fy, H)
    tx = torch.clamp(x / z, float(lx[0]), float(lx[1])) * z
    ty = torch.clamp(y / z, float(ly[0]), float(ly[1])) * z
    J = torch.zeros(len(z), 2, 3, dtype=dt, device=dev)
    J[:, 0, 0], J[:, 0, 2] = fx / z, -fx * tx / (z * z)
    J[:, 1, 1], J[:, 1, 2] = fy / z, -fy * ty / (z * z)
    R = quats_to_rotations(gaussians.quats[sel])
    S = R * gaussians.scales[sel][:, None, :]
    T = J @ w2c[:3, :3] @ S
    cov = T @ T.transpose(1, 2) + 0.3 * torch.eye(2, dtype=dt, device=dev)
    conic = torch.linalg.inv(cov)
    mean2d = torch.stack([fx * x / z + cx, fy * y / z + cy], dim=-1)
    v, u = torch.meshgrid(torch.arange(H, dtype=dt, device=dev), torch.arange(W, dtype=dt, device=dev), indexing="ij")
    pixels = torch.stack([u + 0.5, v + 0.5], dim=-1).reshape(-1, 1, 2)
    opac = gaussians.opacities[sel]
    dirs = torch.nn.functional.normalize(gaussians.means[sel] - cam.center, dim=-1)
    colors = eval_sh_colors(gaussians.sh[sel], dirs)
    bg = torch.as_tensor(background, dtype=dt, device=dev)
    step = pixels.shape[0] if pixel_chunk is None else max(1, int(pixel_chunk))
    outs = []
    for i in range(0, pixels.shape[0], step):
        d = pixels[i : i + step] - mean2d[None]  # (p, N, 2)
        q = torch.einsum("pni,nij,pnj->pn", d, conic, d)
        a = opac[None] * torch.exp(-0.5 * q)
        a = torch.where(a >= 1.0 / 255.0, a.clamp(max=0.99), torch.zeros_like(a))
        t_incl = torch.cumprod(1.0 - a, dim=-1)
        t_excl = torch.cat([torch.ones_like(t_incl[:, :1]), t_incl[:, :-1]], dim=-1)
        w = a * t_excl * (t_incl > 1e-4)
        alpha = w.sum(-1)
        rgb = w @ colors + (1.0 - alpha)[:, None] * bg
        depth = torch.where(alpha > 0, (w @ z) / alpha.clamp_min(1e-12), torch.zeros_like(alpha))
        outs.append(torch.cat([rgb, alpha[:, None], depth[:, None]], dim=-1))
    out = torch.cat(outs).reshape(H, W, 5)
    return out[..., :3], out[..., 3], out[..., 4]
