"""Move particles rigidly in the world: the edit behind "drag an object".

A particle lives in its context view's image plane (``z_p``, ``z_s``) at a planar depth (``z_d``), so a
world translation is not one attribute: each particle of an object (one per context view that holds it,
see :mod:`particlesplat.editing.grouping`) gets a new position, depth and image-plane scale in its own view.
The particle's anchor (the point at ``z_p`` and depth d) moves by exactly ``delta``; the image-plane
scale shrinks by d / d' so the particle keeps its size in metres; the depth extent (metres) is kept.
Gaussians at other depths than the anchor move by ``delta`` up to a perspective error of
|delta_parallel| x |ζ - d| / d' (about 2 cm for a 0.3 m deep object moved 0.5 m sideways at 3.3 m).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor

from particlesplat.core.errors import UserError
from particlesplat.model.config import ModelConfig
from particlesplat.model.particles import Particles


class MoveError(UserError):
    """A move would take a particle outside the model's depth range, or so near its view that it fills it."""


def _anchor(particles: Particles, index: int, config: ModelConfig) -> tuple[Tensor, Tensor]:
    """World position (3,) metres of particle ``index``'s anchor (``z_p`` at depth d) and d (planar metres)."""
    cam = particles.cameras[int(particles.view[index])]
    size = torch.tensor([cam.width, cam.height], dtype=particles.z_p.dtype)
    d = config.depth_of(particles.z_d[index, 0])
    return cam.unproject((particles.z_p[index] + 1.0) * 0.5 * size, d), d


def anchor_points(particles: Particles, indices: Sequence[int], config: ModelConfig) -> Tensor:
    """World positions (len(indices), 3) metres of the particles' anchors: ``z_p`` at depth d."""
    return torch.stack([_anchor(particles, i, config)[0] for i in indices]) if len(indices) else torch.zeros(0, 3)


def translate(
    particles: Particles, indices: Sequence[int], delta: Sequence[float] | Tensor, config: ModelConfig
) -> dict[int, dict[str, tuple[float, ...]]]:
    """New ``z_p``, ``z_d``, ``z_s`` of each particle in ``indices`` moved by ``delta`` (3,) world metres.

    Returns {index: {"z_p": (x, y), "z_d": (d,), "z_s": (sx, sy)}} (absolute values, as edits files hold
    them). Raises :class:`MoveError` when an anchor would leave (d_min, d_max) or its image-plane scale
    would reach 1 (the particle would fill its view).
    """
    delta_t = torch.as_tensor(delta, dtype=particles.z_p.dtype).reshape(3)
    out: dict[int, dict[str, tuple[float, ...]]] = {}
    for i in indices:
        cam = particles.cameras[int(particles.view[i])]
        anchor, d_old = _anchor(particles, i, config)
        uv, d_new = cam.project(anchor + delta_t)
        if not config.d_min < float(d_new) < config.d_max:
            raise MoveError(
                f"particle {i}: the move puts it at depth {float(d_new):.2f} m from its view, outside "
                f"the model's range ({config.d_min}, {config.d_max}) m"
            )
        scale = torch.sigmoid(particles.z_s[i]) * d_old / d_new
        if bool((scale >= 1.0).any()):
            raise MoveError(f"particle {i}: the move brings it so close to its view that it would fill it")
        size = torch.tensor([cam.width, cam.height], dtype=uv.dtype)
        z_p = uv / size * 2.0 - 1.0
        out[int(i)] = {
            "z_p": tuple(float(v) for v in z_p),
            "z_d": (float(config.depth_logit(d_new)),),
            "z_s": tuple(float(v) for v in torch.logit(scale)),
        }
    return out


def stop_at_support(dz: float, bottom: float, support: float) -> float:
    """The vertical move (metres, +z up) allowed of a requested ``dz`` for an object whose lowest opaque point is
    at height ``bottom``, so that it stops at the support surface at height ``support``: any move up, a move down
    at most to the surface, none down if it is already under it."""
    return max(float(dz), min(0.0, float(support) - float(bottom)))
