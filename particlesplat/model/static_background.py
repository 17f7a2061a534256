"""The static background layer: flat Gaussians on the ground plane, learned over the whole dataset.

The tabletop family (``docs/dataset.md``) shares one world frame (+z up, floor plane z = 0) and one
floor in every scene. The per-view background can only draw what a context view saw, so wide-baseline
targets show holes where neither view framed the floor. This layer covers the floor everywhere: a
``grid`` × ``grid`` lattice of flat discs over the square |x|, |y| <= ``extent`` on z = 0, each with a
learned colour and opacity (a learned texture of the plane, shared by all scenes; beyond the floor's edge
a disc learns the colour behind it or to be transparent). Its Gaussians are background (owner -1).
"""

from __future__ import annotations

import math

import torch
from torch import Tensor, nn

from particlesplat.core.sh import num_sh_bases, rgb_to_sh_dc
from particlesplat.model.config import ModelConfig

DISC_SIGMA = 0.6  # in-plane standard deviation of a disc, in grid cells (neighbours overlap smoothly)
DISC_FLATNESS = 0.05  # out-of-plane standard deviation relative to the in-plane one


class StaticBackground(nn.Module):
    """``bg_static_grid``² flat Gaussians on z = 0 with learned colour (SH DC) and opacity logits."""

    # buffers, not saved (the config rebuilds them): means (N, 3) world metres, scales (N, 3) metres, quats (N, 4)
    means: Tensor
    scales: Tensor
    quats: Tensor

    def __init__(self, cfg: ModelConfig):
        super().__init__()
        n, ext = cfg.bg_static_grid, cfg.bg_static_extent
        cell = 2.0 * ext / n
        ar = (torch.arange(n, dtype=torch.float32) + 0.5) * cell - ext
        gy, gx = torch.meshgrid(ar, ar, indexing="ij")
        self.register_buffer("means", torch.stack([gx, gy, torch.zeros_like(gx)], -1).reshape(-1, 3), persistent=False)
        self.register_buffer(
            "scales",
            torch.tensor([DISC_SIGMA, DISC_SIGMA, DISC_SIGMA * DISC_FLATNESS]).mul(cell).expand(n * n, 3).clone(),
            persistent=False,
        )
        self.register_buffer(
            "quats", torch.tensor([1.0, 0.0, 0.0, 0.0]).expand(n * n, 4).clone(), persistent=False
        )  # identity: the discs lie in the plane
        self.num_bases = num_sh_bases(cfg.sh_degree)
        self.sh_dc = nn.Parameter(rgb_to_sh_dc(torch.full((n * n, 3), 0.6)))  # mid grey
        self.opacity_logit = nn.Parameter(torch.full((n * n,), 4.0))

    @property
    def num(self) -> int:
        return self.means.shape[0]

    def forward(self) -> dict[str, Tensor]:
        """Gaussian fields of the layer: means (N, 3) world metres, quats (N, 4), scales (N, 3) metres,
        opacities (N,), sh (N, K, 3) (degree > 0 bases are zero: the colour is view-independent)."""
        sh = torch.cat([self.sh_dc[:, None], self.sh_dc.new_zeros(self.num, self.num_bases - 1, 3)], dim=1)
        return {
            "means": self.means,
            "quats": self.quats,
            "scales": self.scales,
            "opacities": torch.sigmoid(self.opacity_logit),
            "sh": sh,
        }


WORKSPACE_STEP = 0.05  # metres a unit of a workspace Gaussian's position offset moves it (Adam steps of ~lr units)
WORKSPACE_SCALE = 0.6  # initial standard deviation of a workspace Gaussian, in voxel edges
WORKSPACE_MAX_SCALE = 0.15  # metres: the largest standard deviation a workspace Gaussian may grow to
POSE_STEP = 0.3  # metres per pose unit (radian) a unit of a pose Jacobian entry moves a workspace Gaussian (at
# lr_background 0.01: 3 mm/rad a step, the rate of the measurement on the layer alone, docs/robot-model.md)


class WorkspaceBackground(nn.Module):
    """``bg_static_points`` free 3D Gaussians of the workspace every scene of a family shares (table, arm, floor,
    walls), learned over the whole dataset like the floor layer above but anywhere in space.

    Positions start at the voxels :func:`particlesplat.data.workspace_points.workspace_points` finds in the
    training data (:meth:`initialise`, once, before the first step); until then every Gaussian is transparent.
    The anchors are stored in the checkpoint with the learned offsets, scales, rotations, colours and opacities.

    With ``bg_static_pose_dims`` D > 0 the layer follows a per-scene pose (a robot's joint angles, the scene key
    ``bg_static_pose``): each Gaussian's mean moves by its learned 3 x D Jacobian times the scene's pose minus
    ``pose_mean`` (the training scenes' mean, set by :meth:`set_pose_mean`). That is the first-order motion of a
    point on an articulated body about that pose (its error grows with the square of the joint offsets), learned
    without a kinematic model. Rotations, scales and colours stay shared.
    """

    anchor: Tensor  # (N, 3) world metres, a buffer
    pose_mean: Tensor  # (D,) the pose the anchors and offsets hold at, a buffer

    def __init__(self, cfg: ModelConfig):
        super().__init__()
        n = cfg.bg_static_points
        self.num_bases = num_sh_bases(cfg.sh_degree)
        self.register_buffer("anchor", torch.zeros(n, 3))
        self.offset = nn.Parameter(torch.zeros(n, 3))
        self.log_scale = nn.Parameter(torch.full((n, 3), math.log(0.01)))
        self.quat = nn.Parameter(torch.tensor([1.0, 0.0, 0.0, 0.0]).expand(n, 4).clone())
        self.sh_dc = nn.Parameter(rgb_to_sh_dc(torch.full((n, 3), 0.6)))
        self.opacity_logit = nn.Parameter(torch.full((n,), -12.0))
        d = cfg.bg_static_pose_dims
        self.register_buffer("pose_mean", torch.zeros(d), persistent=d > 0)  # checkpoints without a pose load
        self.pose_jacobian = nn.Parameter(torch.zeros(n, 3, d)) if d > 0 else None

    @property
    def num(self) -> int:
        return self.anchor.shape[0]

    @property
    def pose_dims(self) -> int:
        """D: the length of the pose the layer follows (0: a layer every scene shares as is)."""
        return self.pose_mean.shape[0]

    @torch.no_grad()
    def set_pose_mean(self, poses: Tensor) -> None:
        """poses (S, D) of the training scenes: the layer holds its anchors and offsets at their mean."""
        if poses.ndim != 2 or poses.shape[1] != self.pose_dims or poses.shape[0] == 0:
            raise ValueError(f"workspace background: poses must be (S>0, {self.pose_dims}), got {tuple(poses.shape)}")
        self.pose_mean.copy_(poses.mean(0).to(self.pose_mean))

    @torch.no_grad()
    def initialise(self, points: Tensor, colours: Tensor, sizes: Tensor) -> None:
        """points (N', 3) world metres, colours (N', 3) in [0, 1], sizes (N',) voxel edges in metres; N' <= num.
        Gaussians beyond N' stay transparent at the first point."""
        k = min(int(points.shape[0]), self.num)
        if k == 0:
            raise ValueError("workspace background: no points to start from")
        self.anchor.zero_()
        self.anchor[:] = points[0].to(self.anchor)
        self.anchor[:k] = points[:k].to(self.anchor)
        self.offset.zero_()
        self.log_scale[:k] = torch.log(sizes[:k].to(self.anchor) * WORKSPACE_SCALE)[:, None].expand(k, 3)
        self.sh_dc[:k] = rgb_to_sh_dc(colours[:k].to(self.anchor))
        self.opacity_logit.fill_(-12.0)
        self.opacity_logit[:k] = 3.0

    def forward(self, pose: Tensor | None = None) -> dict[str, Tensor]:
        """Gaussian fields: means (N, 3) world metres, quats (N, 4), scales (N, 3) metres, opacities (N,),
        sh (N, K, 3) (view-independent colour): the layer at ``pose_mean``. With ``pose`` (B, D), the layer of B
        scenes: every field (B, N, ·), the means moved by the pose Jacobian."""
        sh = torch.cat([self.sh_dc[:, None], self.sh_dc.new_zeros(self.num, self.num_bases - 1, 3)], dim=1)
        means = self.anchor + WORKSPACE_STEP * self.offset
        fields = {
            "means": means,
            "quats": self.quat / self.quat.norm(dim=-1, keepdim=True).clamp_min(1e-8),
            "scales": self.log_scale.exp().clamp(max=WORKSPACE_MAX_SCALE),
            "opacities": torch.sigmoid(self.opacity_logit),
            "sh": sh,
        }
        if pose is None:
            return fields
        if pose.ndim != 2 or pose.shape[1] != self.pose_dims:
            raise ValueError(f"workspace background: pose must be (B, {self.pose_dims}), got {tuple(pose.shape)}")
        batched = {k: v[None].expand(pose.shape[0], *v.shape) for k, v in fields.items()}
        if self.pose_jacobian is not None:
            delta = pose.to(means) - self.pose_mean
            batched["means"] = means + POSE_STEP * torch.einsum("ncd,bd->bnc", self.pose_jacobian, delta)
        return batched
