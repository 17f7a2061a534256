"""Foreground evidence from depth: which pixels of an RGB-D view show something standing on the support surface
that is not the robot.

A robot workspace's objects rest on the table top (the support surface z = :data:`SUPPORT_Z`, +z up; the world
frame of docs/dataset.md). Lifting a view's depth into the world, a pixel is *evidence of an object* when its
point stands more than :data:`MIN_HEIGHT` above the surface, lies over the surface (within the disc the visible
table top spans about the world's z axis), and lies outside the room the arm takes, which the arm's joint angles,
base pose and gripper give (:mod:`particlesplat.core.panda_arm`). Nothing is learned and nothing is memorised: the
rule reads the view and what the robot knows about itself, so it holds on workspaces the model never saw, and a
turn of the world about z leaves it unchanged.

The model uses it three ways (``model.fg_evidence``): the keypoint proposals go where it is, the per-view
background does not see it (so it cannot copy objects), and training asks the particles to draw it in the
target views.

The robot state a scene carries reaches it packed (:func:`particlesplat.core.panda_arm.pack_arm_state`).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

from particlesplat.core.panda_arm import capsule_distance, state_capsules
from particlesplat.core.world import SUPPORT_Z

MIN_HEIGHT = 0.012
"""Metres above the support surface a point must stand to count as an object's."""
MAX_HEIGHT = 0.6
"""Metres above the support surface beyond which nothing counts (lamps, walls' tops)."""
SURFACE_BAND = 0.006
"""Metres about the support surface within which a point counts as the table top."""
FOOTPRINT_MARGIN = 0.03
"""Metres added to the radius the visible table top spans."""


def arm_capsules_of(state: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """state: (ARM_STATE_DIMS,) packed (:func:`particlesplat.core.panda_arm.pack_arm_state`) -> capsule starts
    (N, 3), ends (N, 3), radii (N,) on its device."""
    starts, ends, radii = state_capsules(state.detach().double().cpu().numpy())
    return tuple(torch.as_tensor(a, dtype=state.dtype, device=state.device) for a in (starts, ends, radii))  # type: ignore[return-value]


def world_points(depth: Tensor, K: Tensor, c2w: Tensor) -> Tensor:
    """depth: (M, 1, H, W) planar metres; K: (M, 3, 3); c2w: (M, 4, 4) OpenCV -> (M, H, W, 3) world points at
    the pixel centres."""
    M, _, H, W = depth.shape
    v, u = torch.meshgrid(
        torch.arange(H, device=depth.device, dtype=depth.dtype) + 0.5,
        torch.arange(W, device=depth.device, dtype=depth.dtype) + 0.5,
        indexing="ij",
    )
    x = (u[None] - K[:, 0, 2, None, None]) / K[:, 0, 0, None, None]
    y = (v[None] - K[:, 1, 2, None, None]) / K[:, 1, 1, None, None]
    cam = torch.stack([x, y, torch.ones_like(x)], dim=-1) * depth[:, 0, ..., None]  # (M, H, W, 3)
    return cam @ c2w[:, None, :3, :3].transpose(-1, -2) + c2w[:, None, None, :3, 3]


def foreground_evidence(depth: Tensor, K: Tensor, c2w: Tensor, arm: Tensor | None = None) -> Tensor:
    """Which pixels show an object standing on the support surface (module docstring).

    depth: (M, 1, H, W) planar metres (0 = missing); K: (M, 3, 3); c2w: (M, 4, 4); arm: (M, ARM_STATE_DIMS) each view's
    robot state (:func:`particlesplat.core.panda_arm.pack_arm_state`) or None (no arm is left out).
    Returns (M, 1, H, W) in {0, 1}.
    """
    with torch.no_grad():
        pts = world_points(depth, K, c2w)
        valid = depth[:, 0] > 0
        height = pts[..., 2] - SUPPORT_Z
        radius = pts[..., :2].norm(dim=-1)
        table = valid & (height.abs() < SURFACE_BAND)
        # the disc the visible table top spans (per view); a view that sees no table top keeps nothing
        footprint = torch.zeros(depth.shape[0], dtype=depth.dtype, device=depth.device)
        for m in range(depth.shape[0]):
            r = radius[m][table[m]]
            if r.numel() > 0:
                footprint[m] = torch.quantile(r, 0.98) + FOOTPRINT_MARGIN
        ev = valid & (height > MIN_HEIGHT) & (height < MAX_HEIGHT) & (radius < footprint[:, None, None])
        if arm is not None:
            for m in range(depth.shape[0]):
                starts, ends, radii = arm_capsules_of(arm[m])
                candidates = ev[m].nonzero(as_tuple=True)
                inside = capsule_distance(pts[m][candidates], starts, ends, radii) < 0
                ev[m][candidates] = ~inside
        return ev[:, None].to(depth.dtype)


def canonical_turn(c2w: Tensor) -> Tensor:
    """The turn about world z that faces the context cameras' mean forward direction along +x.

    c2w: (B, V, 4, 4) OpenCV (camera z forward) -> (B, 4, 4): a rotation about z (through the origin) per scene.
    Applied to the cameras (``turn @ c2w``), it gives the network inputs a world frame that turning the scene
    about z does not change.
    """
    fwd = c2w[..., :2, 2].mean(dim=1)  # (B, 2)
    angle = -torch.atan2(fwd[:, 1], fwd[:, 0])
    c, s = torch.cos(angle), torch.sin(angle)
    turn = torch.zeros(c2w.shape[0], 4, 4, dtype=c2w.dtype, device=c2w.device)
    turn[:, 0, 0], turn[:, 0, 1], turn[:, 1, 0], turn[:, 1, 1] = c, -s, s, c
    turn[:, 2, 2] = turn[:, 3, 3] = 1.0
    return turn


def dilate(mask: Tensor, pixels: int) -> Tensor:
    """mask: (M, 1, H, W) in [0, 1] -> the same grown by ``pixels`` (a square max filter)."""
    if pixels <= 0:
        return mask
    return F.max_pool2d(mask, 2 * pixels + 1, stride=1, padding=pixels)


__all__ = [
    "arm_capsules_of",
    "canonical_turn",
    "dilate",
    "foreground_evidence",
    "world_points",
]
