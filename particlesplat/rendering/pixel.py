"""One pixel composited as :func:`particlesplat.rendering.api.render` composites it, without rendering the image.

A pick (which object is under this pixel?) needs one pixel. Rendering the whole frame costs what every Gaussian
in it costs; :func:`pixel_weights` costs what the Gaussians reaching the pixel cost. Tests compare it with
``render(..., owner_weights=True)`` at every pixel of a frame.
"""

from __future__ import annotations

import torch
from torch import Tensor

from particlesplat.core.camera import Camera
from particlesplat.core.gaussians import Gaussians
from particlesplat.rendering.projection import ALPHA_MAX, ALPHA_MIN, project_gaussians
from particlesplat.rendering.rasterize import EXP_FLOOR, T_MIN


def pixel_weights(
    gaussians: Gaussians, camera: Camera, pixel: tuple[int, int], near: float = 0.01, far: float = 1e10
) -> tuple[Tensor, Tensor]:
    """The Gaussians that weigh at the centre of ``pixel`` (x, y) and their weights, by the rules of
    :func:`~particlesplat.rendering.api.render`: α = min(0.99, o·exp(−½dᵀΣ⁻¹d)), zero below 1/255; front to back
    by camera z, ties by index; the pixel stops before the Gaussian that would take its transmittance to ≤ 1e-4.

    Returns (K,) int64 indices into ``gaussians``, front to back, and (K,) weights w = α·T (the dtype of the
    Gaussians); 1 − Σw is what the background colour gets.
    """
    dtype, device = gaussians.means.dtype, gaussians.means.device
    proj = project_gaussians(gaussians, camera.to(device=device, dtype=dtype), near, far)
    centre = torch.tensor([pixel[0] + 0.5, pixel[1] + 0.5], dtype=torch.float64, device=device)
    dx, dy = (centre - proj.means2d).to(proj.conics.dtype).unbind(-1)
    a, b, c = proj.conics.unbind(-1)
    log_o = torch.log(gaussians.opacities[proj.index].clamp_min(1e-30))
    alpha = (log_o - 0.5 * (a * dx * dx + 2.0 * b * dx * dy + c * dy * dy)).clamp_min(EXP_FLOOR).exp()
    alpha = alpha.clamp_max(ALPHA_MAX)
    hit = alpha >= ALPHA_MIN
    index, alpha = proj.index[hit], alpha[hit]
    order = torch.sort(proj.depths[hit], stable=True).indices
    index, alpha = index[order], alpha[order]
    one_minus = 1.0 - alpha
    t_incl = torch.cumprod(one_minus, dim=0)
    weights = (t_incl / one_minus - t_incl) * (t_incl > T_MIN)
    kept = weights > 0
    return index[kept], weights[kept]
