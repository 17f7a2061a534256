"""Move and scale particles in the world: the edits behind "drag an object" and "scale an object".

A particle lives in its context view's image plane (``z_p``, ``z_s``) at a planar depth (``z_d``), so a
world translation is not one attribute: each particle of an object (one per context view that holds it,
see :mod:`particlesplat.editing.grouping`) gets a new position, depth and image-plane scale in its own view.
The particle's anchor (the point at ``z_p`` and depth d) moves by exactly ``delta``; the image-plane
scale shrinks by d / d' so the particle keeps its size in metres; the depth extent (metres) is kept.
Gaussians at other depths than the anchor move by ``delta`` up to a perspective error of
|delta_parallel| x |ζ - d| / d' (about 2 cm for a 0.3 m deep object moved 0.5 m sideways at 3.3 m).

Scaling an object by F about a point moves each anchor to pivot + F (anchor - pivot) and grows each particle's
size in metres F times: its image-plane scale (``z_s``, by F d / d') and its depth extent (``z_e``), the latents
the paper's figure on latent control scales.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

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


def _placed(
    particles: Particles, i: int, config: ModelConfig, to: Callable[[Tensor], Tensor], factor: float = 1.0
) -> dict[str, tuple[float, ...]]:
    """New ``z_p``, ``z_d``, ``z_s`` (and ``z_e`` when ``factor`` != 1) of particle ``i`` whose anchor goes to
    ``to(anchor)`` (3,) world metres and whose size in metres grows ``factor`` times. Raises MoveError."""
    cam = particles.cameras[int(particles.view[i])]
    anchor, d_old = _anchor(particles, i, config)
    uv, d_new = cam.project(to(anchor))
    if not config.d_min < float(d_new) < config.d_max:
        raise MoveError(
            f"particle {i}: the move puts it at depth {float(d_new):.2f} m from its view, outside "
            f"the model's range ({config.d_min}, {config.d_max}) m"
        )
    size = torch.sigmoid(particles.z_s[i]) if factor == 1.0 else torch.sigmoid(particles.z_s[i]) * factor
    scale = size * d_old / d_new
    if bool((scale >= 1.0).any()):
        raise MoveError(f"particle {i}: the move brings it so close to its view that it would fill it")
    pixels = torch.tensor([cam.width, cam.height], dtype=uv.dtype)
    z_p = uv / pixels * 2.0 - 1.0
    out = {
        "z_p": tuple(float(v) for v in z_p),
        "z_d": (float(config.depth_logit(d_new)),),
        "z_s": tuple(float(v) for v in torch.logit(scale)),
    }
    if factor != 1.0:
        extent = torch.sigmoid(particles.z_e[i]) * factor
        if bool((extent >= 1.0).any()):
            raise MoveError(
                f"particle {i}: {factor:g} times as deep it would outgrow the model's depth range "
                f"({config.d_min}, {config.d_max}) m"
            )
        out["z_e"] = tuple(float(v) for v in torch.logit(extent))
    if not all(math.isfinite(v) for values in out.values() for v in values):
        raise MoveError(f"particle {i}: {factor:g} times its size is beyond what its latents can hold")
    return out


def translate(
    particles: Particles, indices: Sequence[int], delta: Sequence[float] | Tensor, config: ModelConfig
) -> dict[int, dict[str, tuple[float, ...]]]:
    """New ``z_p``, ``z_d``, ``z_s`` of each particle in ``indices`` moved by ``delta`` (3,) world metres.

    Returns {index: {"z_p": (x, y), "z_d": (d,), "z_s": (sx, sy)}} (absolute values, as edits files hold
    them). Raises :class:`MoveError` when an anchor would leave (d_min, d_max) or its image-plane scale
    would reach 1 (the particle would fill its view).
    """
    delta_t = torch.as_tensor(delta, dtype=particles.z_p.dtype).reshape(3)
    return {int(i): _placed(particles, i, config, lambda a: a + delta_t) for i in indices}


def scale(
    particles: Particles, indices: Sequence[int], factor: float, pivot: Sequence[float] | Tensor, config: ModelConfig
) -> dict[int, dict[str, tuple[float, ...]]]:
    """New ``z_p``, ``z_d``, ``z_s``, ``z_e`` of each particle in ``indices`` scaled ``factor`` times about
    ``pivot`` (3,) world metres: each anchor goes to pivot + factor (anchor - pivot) (the particles' spread), each
    particle's image-plane scale grows ``factor`` times in metres (``z_s``: its width and height) and so does its
    depth extent (``z_e``), so its Gaussians spread ``factor`` times as far about its anchor in every direction.
    Raises :class:`MoveError` (a particle would leave the depth range, fill its view, or outgrow the depth range).
    """
    if not (math.isfinite(factor) and factor > 0.0):
        raise MoveError(f"scale: expected a factor in (0, inf), got {factor!r}")
    p = torch.as_tensor(pivot, dtype=particles.z_p.dtype).reshape(3)
    return {int(i): _placed(particles, i, config, lambda a: p + factor * (a - p), factor) for i in indices}


def stop_at_support(dz: float, bottom: float, support: float) -> float:
    """The vertical move (metres, +z up) allowed of a requested ``dz`` for an object whose lowest opaque point is
    at height ``bottom``, so that it stops at the support surface at height ``support``: any move up, a move down
    at most to the surface, none down if it is already under it."""
    return max(float(dz), min(0.0, float(support) - float(bottom)))
