"""A scene with its world frame turned about z, in memory: the check that a model does not carry the world's
orientation in its weights (``particlesplat eval --turn DEG``).

Turning the world frame turns everything given in world coordinates (the cameras, the robot's base, the objects'
centres) and leaves the images, depths and masks as they are, so a model that reads its workspace from the views
should render the same pictures.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor

from particlesplat.core.panda_arm import ARM_STATE_DIMS, ARM_STATE_KEY


def turn_matrix(degrees: float) -> Tensor:
    """(4, 4) float64: a turn of ``degrees`` about the world's +z axis (counter-clockwise seen from above)."""
    a = math.radians(degrees)
    t = torch.eye(4, dtype=torch.float64)
    t[0, 0], t[0, 1], t[1, 0], t[1, 1] = math.cos(a), -math.sin(a), math.sin(a), math.cos(a)
    return t


def turn_item(item: dict, degrees: float, pose_key: str) -> dict:
    """A dataset item (:class:`particlesplat.data.SceneDataset`) with the world turned by ``degrees`` about z: its
    ``context_c2w`` and ``target_c2w`` (V, 4, 4), and its ``pose`` when it is the robot state (``pose_key``
    :data:`~particlesplat.core.panda_arm.ARM_STATE_KEY`, whose base pose turns; joint angles do not). A new dict."""
    out = dict(item)
    for key in ("context_c2w", "target_c2w"):
        c2w = item[key]
        out[key] = (turn_matrix(degrees).to(c2w.dtype) @ c2w).to(c2w.dtype)
    pose = item.get("pose")
    if pose is not None and pose_key == ARM_STATE_KEY and pose.numel() == ARM_STATE_DIMS:
        base = torch.eye(4, dtype=torch.float64)
        base[:3] = pose[7:19].double().reshape(3, 4)
        turned = pose.clone()
        turned[7:19] = (turn_matrix(degrees) @ base)[:3].reshape(-1).to(pose.dtype)
        out["pose"] = turned
    return out


def turn_points(points: np.ndarray | None, degrees: float) -> np.ndarray | None:
    """(N, 3) world points turned by ``degrees`` about z (None stays None)."""
    if points is None:
        return None
    return points @ turn_matrix(degrees)[:3, :3].numpy().T


__all__ = ["turn_item", "turn_matrix", "turn_points"]
