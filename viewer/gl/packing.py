"""What the splat renderer's shaders read, laid out on the CPU: the Gaussians packed into texels (one texture row
holds :func:`row_for` Gaussians of :func:`texels_for` texels each; the layout is ``shaders/project.frag``'s) and a
camera's projection uniforms. numpy and torch only: no GL call."""

from __future__ import annotations

import numpy as np
import torch

from particlesplat.core.camera import Camera
from particlesplat.core.gaussians import Gaussians
from particlesplat.rendering.projection import FOV_MARGIN

ROW = 512  # Gaussians per row of the data and projection textures (fewer if the texture size needs it)


def row_for(texels: int, max_texture_size: int) -> int:
    """Gaussians per data texture row: ``ROW``, or fewer when ``ROW * texels`` exceeds the texture size."""
    return max(1, min(ROW, max_texture_size // texels))


def texels_for(sh_bases: int) -> int:
    """Texels per Gaussian for ``sh_bases`` SH coefficients per channel (one texel each)."""
    return 4 + sh_bases


def pack_gaussians(g: Gaussians, texels: int | None = None) -> np.ndarray:
    """Pack Gaussians into texels: (N, texels, 4) float32 (layout in ``shaders/project.frag``).

    Rotations come from :meth:`Gaussians.rotations` (the torch renderer's quaternion rules).
    """
    g = g.detach().to("cpu", torch.float64)
    n, k = g.num, g.sh.shape[1]
    texels = max(texels or 0, texels_for(k))
    out = np.zeros((n, texels, 4), dtype=np.float32)
    rot = g.rotations().numpy() if n else np.zeros((0, 3, 3))
    out[:, 0, :3] = g.means.numpy()
    out[:, 0, 3] = g.opacities.numpy()
    out[:, 1:4, :3] = rot
    out[:, 1:4, 3] = g.scales.numpy()
    out[:, 4 : 4 + k, :3] = g.sh.numpy()
    out[:, 4, 3] = g.owner.numpy().astype(np.float32)
    return out


def camera_uniforms(camera: Camera) -> dict[str, tuple]:
    """The projection uniforms of ``project.frag`` for ``camera`` (float64 maths, float32 out)."""
    c2w = camera.c2w.detach().to("cpu", torch.float64).numpy()
    w2c = np.linalg.inv(c2w)
    K = camera.K.detach().to("cpu", torch.float64).numpy()
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    w, h = camera.width, camera.height
    tan_x, tan_y = 0.5 * w / fx, 0.5 * h / fy
    lim = (
        -(cx / fx + FOV_MARGIN * tan_x),
        (w - cx) / fx + FOV_MARGIN * tan_x,
        -(cy / fy + FOV_MARGIN * tan_y),
        (h - cy) / fy + FOV_MARGIN * tan_y,
    )
    return {
        "w2c": tuple(w2c.T.reshape(-1)),  # GLSL matrices are column-major
        "cam_center": tuple(c2w[:3, 3]),
        "intr": (fx, fy, cx, cy),
        "lim": lim,
        "size": (float(w), float(h)),
    }
