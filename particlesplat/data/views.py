"""The paper's view sampler (appendix, "view sampling"), the monocular supervision mask, and flips.

Multi-view (after MVSplat's bounded sampler): two context views whose index gap is drawn from a
range that grows linearly from [1, 4] at the start of training to [5, 20] halfway through, then
stays; four targets are drawn from the indices between them (ends included).
Single-view: the front frame (10 of 21) is the only context; two targets are drawn at an index
gap from it that grows from [1, 2] to [5, 10] the same way.
"""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType

import torch
from torch import Tensor

from particlesplat.core.camera import Camera
from particlesplat.core.choices import PAPER_CONTEXT_FRAMES, PAPER_TARGET_FRAMES

GAP_SCHEDULES: Mapping[str, tuple[tuple[int, int], tuple[int, int]]] = MappingProxyType(
    {
        "multi": ((1, 4), (5, 20)),
        "single": ((1, 2), (5, 10)),
    }
)
NUM_TARGETS: Mapping[str, int] = MappingProxyType({"multi": 4, "single": 2})
WARMUP = 0.5  # fraction of training after which the gap range is at its maximum


def gap_range(
    progress: float, mode: str, schedule: tuple[tuple[int, int], tuple[int, int]] | None = None, warmup: float = WARMUP
) -> tuple[int, int]:
    """The (min, max) index gap allowed at ``progress`` in [0, 1] of training (linear, then flat)."""
    (a0, b0), (a1, b1) = schedule or GAP_SCHEDULES[mode]
    s = min(max(float(progress), 0.0) / warmup, 1.0) if warmup > 0 else 1.0
    return round(a0 + (a1 - a0) * s), round(b0 + (b1 - b0) * s)


def _randint(lo: int, hi: int, generator: torch.Generator | None) -> int:
    """Uniform integer in [lo, hi]."""
    return int(torch.randint(lo, hi + 1, (1,), generator=generator))


def _choose(candidates: Tensor, count: int, generator: torch.Generator | None) -> Tensor:
    """``count`` entries of ``candidates`` (N,), distinct when N >= count, sorted."""
    if len(candidates) >= count:
        pick = torch.randperm(len(candidates), generator=generator)[:count]
    else:
        pick = torch.randint(len(candidates), (count,), generator=generator)
    return candidates[pick].sort().values


def sample_views(
    num_frames: int,
    progress: float,
    mode: str = "multi",
    generator: torch.Generator | None = None,
    *,
    num_targets: int | None = None,
    schedule: tuple[tuple[int, int], tuple[int, int]] | None = None,
    front: int | None = None,
    warmup: float = WARMUP,
) -> tuple[Tensor, Tensor]:
    """Pick context and target frame indices of one scene.

    Args:
        num_frames: frames in trajectory order.
        progress: fraction of training done, in [0, 1].
        mode: "multi" (2 context, targets between them) or "single" (front frame as context).
        generator: torch RNG (None = the global one).
        num_targets: default 4 (multi) or 2 (single).
        schedule: ((start_min, start_max), (end_min, end_max)) gaps; default the paper's.
        front: the single-view context frame; default ``num_frames // 2`` (10 of 21).

    Returns:
        context (C,) int64 sorted, target (T,) int64 sorted. Gaps are clipped to what fits.
        Multi-view targets are distinct when the range between the contexts holds enough frames.
    """
    if mode not in GAP_SCHEDULES:
        raise ValueError(f"mode must be 'multi' or 'single', got {mode!r}")
    count = NUM_TARGETS[mode] if num_targets is None else int(num_targets)
    lo, hi = gap_range(progress, mode, schedule, warmup)
    if mode == "multi":
        if num_frames < 2:
            raise ValueError(f"multi-view sampling needs at least 2 frames, got {num_frames}")
        hi = min(hi, num_frames - 1)
        lo = min(lo, hi)
        gap = _randint(lo, hi, generator)
        left = _randint(0, num_frames - 1 - gap, generator)
        context = torch.tensor([left, left + gap])
        targets = _choose(torch.arange(left, left + gap + 1), count, generator)
        return context, targets
    if num_frames < 2:
        raise ValueError(f"single-view sampling needs at least 2 frames, got {num_frames}")
    f = num_frames // 2 if front is None else int(front)
    if not 0 <= f < num_frames:
        raise ValueError(f"front frame {f} out of range for {num_frames} frames")
    offsets = torch.cat([-torch.arange(lo, hi + 1), torch.arange(lo, hi + 1)]) + f
    candidates = offsets[(offsets >= 0) & (offsets < num_frames)]
    if len(candidates) == 0:  # short trajectory: the farthest frames that exist
        candidates = torch.tensor([i for i in (0, num_frames - 1) if i != f])
    return torch.tensor([f]), _choose(candidates, count, generator)


def protocol_views(protocol: str, num_frames: int, context: Tensor, targets: Tensor) -> tuple[Tensor, Tensor]:
    """The context and target frame indices an evaluation ``protocol`` scores (:data:`core.choices.EVAL_PROTOCOLS`).

    Args:
        protocol: "sampled" keeps the sampler's ``context`` (C,) and ``targets`` (T,); "inputs" scores the context
            views themselves (targets = context); "paper" takes the paper's fixed frames (context 6 and 14,
            targets 6, 8, 10, 12, 14), whatever the sampler chose.
        num_frames: frames of the scene in trajectory order.

    Returns:
        context (C,) int64, targets (T,) int64. Raises ValueError for a scene too short for "paper" (it needs
        frames 0-14) or an unknown protocol.
    """
    if protocol == "sampled":
        return context, targets
    if protocol == "inputs":
        return context, context.clone()
    if protocol == "paper":
        need = max(PAPER_CONTEXT_FRAMES + PAPER_TARGET_FRAMES) + 1
        if num_frames < need:
            raise ValueError(
                f"{num_frames} frame(s): the paper's protocol (context frames {PAPER_CONTEXT_FRAMES[0]} and "
                f"{PAPER_CONTEXT_FRAMES[1]}, targets {', '.join(map(str, PAPER_TARGET_FRAMES))}) needs at least {need}"
            )
        return torch.tensor(PAPER_CONTEXT_FRAMES), torch.tensor(PAPER_TARGET_FRAMES)
    raise ValueError(f"unknown evaluation protocol {protocol!r}")


def supervision_mask(
    target_depth: Tensor,
    target_cams: list[Camera],
    context_depth: Tensor,
    context_cams: list[Camera],
    rel_tol: float = 0.01,
    abs_tol: float = 0.01,
) -> Tensor:
    """Splatt3R-style mask of target pixels that the context views can see.

    A target pixel is supervised (1) when its surface point, unprojected with the target depth,
    projects inside some context image and is not hidden there: its depth in that context
    camera is at most ``context_depth * (1 + rel_tol) + abs_tol`` at the nearest pixel. A
    pixel with no depth (0: beyond the floor, "at infinity") is supervised when its direction
    falls inside some context image where the context depth is also 0. Otherwise it is 0.

    Args:
        target_depth: (T, 1, H, W) planar metres, 0 = none.
        context_depth: (C, 1, H', W') planar metres, 0 = none.

    Returns:
        (T, 1, H, W) float32 in {0, 1}.
    """
    out = []
    for t, tcam in enumerate(target_cams):
        d = target_depth[t, 0].double()
        cam_t = tcam.to(dtype=torch.float64)
        _, dirs = cam_t.rays()
        finite = d > 0
        points = cam_t.center + dirs * d[..., None]
        seen = torch.zeros_like(finite)
        for c, ccam in enumerate(context_cams):
            cam_c = ccam.to(dtype=torch.float64)
            cd = context_depth[c, 0].double()
            uv, z = cam_c.project(points)
            # points at infinity: the direction only (rotation, no translation)
            dir_c = dirs @ cam_c.R
            inf_uv = dir_c[..., :2] / dir_c[..., 2:].clamp_min(1e-12) * torch.stack([cam_c.fx, cam_c.fy]) + torch.stack(
                [cam_c.cx, cam_c.cy]
            )
            uv = torch.where(finite[..., None], uv, inf_uv)
            front = torch.where(finite, z > 1e-6, dir_c[..., 2] > 1e-6)
            u, v = uv[..., 0].floor(), uv[..., 1].floor()
            inside = front & (u >= 0) & (u < cam_c.width) & (v >= 0) & (v < cam_c.height)
            ui = u.clamp(0, cam_c.width - 1).long()
            vi = v.clamp(0, cam_c.height - 1).long()
            seen_d = cd[vi, ui]
            visible_finite = (seen_d > 0) & (z <= seen_d * (1 + rel_tol) + abs_tol)
            visible = torch.where(finite, visible_finite, seen_d == 0)
            seen |= inside & visible
        out.append(seen)
    return torch.stack(out)[:, None].float()


def flip_horizontal(rgb: Tensor, cameras: list[Camera], *extra: Tensor) -> tuple[Tensor, list[Camera], list[Tensor]]:
    """Mirror the world in x and flip every image left-right, consistently.

    Pixel ``u`` of the flipped image shows what the old image showed at ``W - u``; the new
    camera is ``M c2w F`` (``M = diag(-1, 1, 1)`` mirrors the world, ``F`` flips the camera's x
    axis, keeping a proper rotation) with ``cx' = W - cx``. Depth is unchanged.

    Args:
        rgb: (V, 3, H, W); extra: tensors (V, ..., W) flipped along their last axis (depth, masks).
    """
    mirror = torch.diag(torch.tensor([-1.0, 1.0, 1.0, 1.0]))
    cams = []
    for cam in cameras:
        m = mirror.to(cam.c2w)
        K = cam.K.clone()
        K[0, 2] = cam.width - K[0, 2]
        cams.append(Camera(K, m @ cam.c2w @ m, cam.width, cam.height))
    return rgb.flip(-1), cams, [e.flip(-1) for e in extra]
