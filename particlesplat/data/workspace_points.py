"""The fixed part of a scene family, found in its training data without labels: the surfaces most scenes share.

Scenes of one family share a workspace (the robot family's table, arm, floor and walls; the tabletop family's
floor) while the objects move from scene to scene. Back-projecting every view's depth and counting, for each
voxel of the world, the scenes in which it is occupied separates the two: a workspace voxel is occupied in most
scenes, an object voxel only in the few whose objects stood there. No instance masks are read.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from particlesplat.data.scene import read_scene

NEAR_VOXEL = 0.02  # metres: voxel edge within NEAR_RADIUS of the origin (where the objects are)
FAR_VOXEL = 0.06  # metres: voxel edge beyond it (walls and floor, seen small)
NEAR_RADIUS = 0.7  # metres, horizontal distance from the world origin


@dataclass(frozen=True)
class WorkspacePoints:
    """Voxel centres of the shared workspace: ``points`` (N, 3) world metres, ``colours`` (N, 3) in [0, 1],
    ``sizes`` (N,) voxel edge in metres, ``share`` (N,) fraction of the scenes in which the voxel is occupied."""

    points: np.ndarray
    colours: np.ndarray
    sizes: np.ndarray
    share: np.ndarray


def _voxel_keys(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(M, 3) points -> int64 keys (M,) of their voxels and each voxel's edge (M,) in metres."""
    near = np.hypot(p[:, 0], p[:, 1]) <= NEAR_RADIUS
    size = np.where(near, NEAR_VOXEL, FAR_VOXEL)
    q = np.floor(p / size[:, None]).astype(np.int64) + (1 << 19)
    return (near.astype(np.int64) << 62) | (q[:, 0] << 41) | (q[:, 1] << 21) | q[:, 2], size


def workspace_points(
    scene_dirs: list[Path], max_points: int, min_share: float = 0.3, resolution: int = 64
) -> WorkspacePoints:
    """The voxels occupied in at least ``min_share`` of ``scene_dirs`` (every view back-projected at
    ``resolution`` pixels), the ``max_points`` most shared first; colour is the mean over every hit.

    Raises SceneFormatError (a user error naming the folder and the model key) when no scene has depth.
    """
    counts: dict[int, int] = {}
    colour_sum: dict[int, np.ndarray] = {}
    hits: dict[int, int] = {}
    centre: dict[int, np.ndarray] = {}
    edge: dict[int, float] = {}
    used = 0
    for folder in scene_dirs:
        scene = read_scene(folder).select(None, resolution)
        if scene.depth is None:
            continue
        used += 1
        pts, cols = [], []
        for v, cam in enumerate(scene.cameras):
            d = scene.depth[v, 0]
            ok = d > 0
            if not bool(ok.any()):
                continue
            vs, us = torch.nonzero(ok, as_tuple=True)
            pix = torch.stack([us.double() + 0.5, vs.double() + 0.5], -1)
            K, c2w = cam.K.double(), cam.c2w.double()
            x = (pix[:, 0] - K[0, 2]) / K[0, 0]
            y = (pix[:, 1] - K[1, 2]) / K[1, 1]
            cam_pts = torch.stack([x, y, torch.ones_like(x)], -1) * d[ok].double()[:, None]
            pts.append((cam_pts @ c2w[:3, :3].T + c2w[:3, 3]).numpy())
            cols.append(scene.rgb[v][:, ok].T.double().numpy())
        if not pts:
            continue
        p, c = np.concatenate(pts), np.concatenate(cols)
        keys, size = _voxel_keys(p)
        uniq, inv = np.unique(keys, return_inverse=True)
        csum = np.zeros((len(uniq), 3))
        np.add.at(csum, inv, c)
        n = np.bincount(inv, minlength=len(uniq))
        psum = np.zeros((len(uniq), 3))
        np.add.at(psum, inv, p)
        first = np.zeros(len(uniq), dtype=np.int64)
        first[inv[::-1]] = np.arange(len(inv))[::-1]
        for i, k in enumerate(uniq.tolist()):
            counts[k] = counts.get(k, 0) + 1
            hits[k] = hits.get(k, 0) + int(n[i])
            colour_sum[k] = colour_sum.get(k, 0.0) + csum[i]
            if k not in centre:
                s = float(size[first[i]])
                centre[k] = (np.floor(psum[i] / n[i] / s) + 0.5) * s
                edge[k] = s
    if used == 0:
        from particlesplat.data.scene import SceneFormatError

        raise SceneFormatError(
            f"{scene_dirs[0].parent if scene_dirs else '?'}: none of its first {len(scene_dirs)} scenes has depth "
            "(depth_file_path), which model.background.static_points needs to place the workspace layer; give "
            "scenes with depth or set model.background.static_points to 0"
        )
    kept = [k for k, n in counts.items() if n >= min_share * used]  # voxel keys, most often seen first
    kept.sort(key=lambda k: (-counts[k], k))
    kept = kept[:max_points]
    return WorkspacePoints(
        points=np.array([centre[k] for k in kept], dtype=np.float32).reshape(-1, 3),
        colours=np.array([colour_sum[k] / hits[k] for k in kept], dtype=np.float32).reshape(-1, 3).clip(0, 1),
        sizes=np.array([edge[k] for k in kept], dtype=np.float32),
        share=np.array([counts[k] / used for k in kept], dtype=np.float32),
    )
