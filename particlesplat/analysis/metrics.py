"""Image, depth and decomposition metrics: PSNR, SSIM (kornia), depth AbsRel, FG-ARI, mIoU, and the squared
error split by where it lies (object interiors and edges, the floor next to objects and away from them, that
far floor by height over the support surface)."""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from kornia.metrics import ssim as kornia_ssim
from torch import Tensor

from particlesplat.core.world import SUPPORT_Z


def psnr_of_mse(mse: float) -> float:
    """PSNR in dB of a mean squared error of [0, 1] images (floored at 1e-10: 100 dB)."""
    return -10.0 * math.log10(max(mse, 1e-10))


def psnr(pred: Tensor, target: Tensor, mask: Tensor | None = None) -> float:
    """PSNR in dB of images in [0, 1]. pred, target: (..., 3, H, W) or (H, W, 3); mask broadcastable."""
    err = (pred.clamp(0, 1) - target) ** 2
    if mask is not None:
        m = mask.expand_as(err).to(err.dtype)
        mse = (err * m).sum() / m.sum().clamp_min(1.0)
    else:
        mse = err.mean()
    return psnr_of_mse(float(mse))


def region_psnr(pred: Tensor, gt: Tensor, region: Tensor) -> float:
    """Mean over views of each view's PSNR (dB) on the pixels of ``region`` (T, H, W) bool; views with no such
    pixel are left out, and NaN when no view has one. pred, gt: (T, 3, H, W)."""
    scores = [psnr(pred[i], gt[i], region[i][None]) for i in range(len(gt)) if bool(region[i].any())]
    return sum(scores) / len(scores) if scores else float("nan")


OBJECT_HELD = 0.9  # an object pixel is held by its particles when their summed weight there is at least this


def object_pixels_held(particle_weight: Tensor, masks: Tensor, valid: Tensor | None = None) -> float:
    """Share of the true object pixels (masks (T, H, W) > 0, within ``valid`` (T, 1, H, W) when given) where the
    particles' summed weight ``particle_weight`` (T, H, W) is at least :data:`OBJECT_HELD`: the part of the objects
    their own particles draw opaquely, so that an edit carries it. NaN when the views show no object."""
    obj = masks > 0
    if valid is not None:
        obj &= valid[:, 0] > 0
    n = int(obj.sum())
    return float((particle_weight[obj] >= OBJECT_HELD).sum()) / n if n else float("nan")


def ssim(pred: Tensor, target: Tensor, window: int = 11) -> float:
    """Mean SSIM (kornia, Gaussian window). pred, target: (B, 3, H, W) in [0, 1]."""
    return float(kornia_ssim(pred.clamp(0, 1), target, window).mean())


def depth_abs_rel(pred: Tensor, target: Tensor) -> float:
    """Mean |pred − gt| / gt over pixels with ground truth (gt > 0). pred, target: (...) metres; NaN if none."""
    valid = target > 0
    if not bool(valid.any()):
        return float("nan")
    return float(((pred[valid] - target[valid]).abs() / target[valid]).mean())


SKIRT_OPACITY = 0.5  # an object Gaussian this opaque is part of the object's visible surface
SKIRT_MARGIN = 0.01  # metres below the support surface that count as "under" it


def below_support(means: Tensor, opacities: Tensor, owner: Tensor, support_z: float = SUPPORT_Z) -> float:
    """Share of the opaque object Gaussians (owner >= 0, opacity > ``SKIRT_OPACITY``) whose centre lies more
    than ``SKIRT_MARGIN`` below the support surface z = ``support_z`` (world metres, +z up): an object's
    "skirt" under the floor or table top. means: (N, 3); opacities, owner: (N,). NaN when none is opaque."""
    sel = (owner >= 0) & (opacities > SKIRT_OPACITY)
    n = int(sel.sum())
    if n == 0:
        return float("nan")
    return float((means[sel, 2] < support_z - SKIRT_MARGIN).sum()) / n


def _comb2(x: Tensor) -> Tensor:
    return x * (x - 1) / 2.0


def adjusted_rand_index(labels_true: Tensor, labels_pred: Tensor) -> float:
    """ARI of two labelings (N,) int (Hubert & Arabie), as scikit-learn defines it.

    Both labelings with a single cluster, or both with every point its own cluster, give 1.0.
    """
    if labels_true.numel() == 0:
        return float("nan")
    _, t = torch.unique(labels_true, return_inverse=True)
    _, p = torch.unique(labels_pred, return_inverse=True)
    nt, np_ = int(t.max()) + 1, int(p.max()) + 1
    n = labels_true.numel()
    if (nt == np_ == 1) or (nt == np_ == n):
        return 1.0
    table = torch.zeros(nt, np_, dtype=torch.float64)
    table.index_put_((t, p), torch.ones(n, dtype=torch.float64), accumulate=True)
    sum_comb = _comb2(table).sum()
    a = _comb2(table.sum(1)).sum()
    b = _comb2(table.sum(0)).sum()
    expected = a * b / _comb2(torch.tensor(float(n), dtype=torch.float64))
    max_index = 0.5 * (a + b)
    denom = max_index - expected
    if float(denom) == 0.0:
        return 1.0
    return float((sum_comb - expected) / denom)


def fg_ari(pred_seg: Tensor, gt_masks: Tensor) -> float:
    """FG-ARI: ARI restricted to ground-truth foreground pixels (gt > 0).

    pred_seg: (..., H, W) int predicted owner (-1 background); gt_masks: same shape, 0 = background.
    NaN when there is no foreground pixel.
    """
    fg = gt_masks > 0
    if not bool(fg.any()):
        return float("nan")
    return adjusted_rand_index(gt_masks[fg], pred_seg[fg])


def matched_miou(pred_seg: Tensor, gt_masks: Tensor) -> float:
    """Mean IoU over ground-truth objects, each matched one-to-one to a predicted segment (owner >= 0)
    greedily by descending IoU; an unmatched object scores 0. NaN when there is no object.

    pred_seg, gt_masks: (..., H, W) int.
    """
    gt_ids = [int(i) for i in torch.unique(gt_masks) if int(i) > 0]
    if not gt_ids:
        return float("nan")
    pred_ids = [int(i) for i in torch.unique(pred_seg) if int(i) >= 0]
    if not pred_ids:
        return 0.0
    iou = torch.zeros(len(gt_ids), len(pred_ids), dtype=torch.float64)
    for i, g in enumerate(gt_ids):
        gm = gt_masks == g
        for j, p in enumerate(pred_ids):
            pm = pred_seg == p
            inter = (gm & pm).sum()
            union = (gm | pm).sum()
            iou[i, j] = float(inter) / float(union) if int(union) else 0.0
    scores = torch.zeros(len(gt_ids), dtype=torch.float64)
    work = iou.clone()
    for _ in range(min(len(gt_ids), len(pred_ids))):
        flat = int(work.argmax())
        i, j = divmod(flat, work.shape[1])
        if float(work[i, j]) <= 0.0:
            break
        scores[i] = iou[i, j]
        work[i, :] = -1.0
        work[:, j] = -1.0
    return float(scores.mean())


REGIONS = ("object_interior", "object_edge", "floor_near_object", "floor_far")
# floor_far split by the height of each pixel's surface point (target depth) over the support surface, beyond
# SKIRT_MARGIN: the floor under a table, the table top or floor objects rest on, what stands above it (an arm)
FAR_HEIGHTS = ("floor_far_below_support", "floor_far_on_support", "floor_far_above_support")
# two more splits of the same pixels, each in two parts, laid over the REGIONS partition: where the particles draw
# (their summed weight above PARTICLES_DRAW in the render), on the true objects and off them, and which pixels a
# context view sees (their surface point is visible in one: data.views.supervision_mask) and which none does
OVERLAYS = ("particles_on_objects", "particles_off_objects", "seen_by_context", "unseen_by_context")
PARTICLES_DRAW = 0.5


def near_other_label(labels: Tensor, radius: int) -> Tensor:
    """Pixels with a pixel of another label within ``radius`` px (Chebyshev). labels: (M, 1, H, W) numbers
    (ids or a 0/1 target) -> (M, 1, H, W) bool; the image border does not count as another label."""
    x = labels.to(torch.float64)
    k = 2 * radius + 1
    return F.max_pool2d(x, k, 1, radius) != -F.max_pool2d(-x, k, 1, radius)


def mask_regions(masks: Tensor) -> dict[str, Tensor]:
    """Partition the pixels of instance masks into :data:`REGIONS`.

    masks: (V, H, W) int ids, 0 = background. An object pixel is on an edge when a pixel of another id
    (another object or the background) lies within 1 px (Chebyshev), else interior; a background pixel is
    near an object when an object pixel lies within 2 px, else far. Returns bool (V, H, W) per region.
    """
    edge = near_other_label(masks[:, None], 1)[:, 0]
    obj = masks > 0
    near = obj | near_other_label(obj[:, None], 2)[:, 0]
    return {
        "object_interior": obj & ~edge,
        "object_edge": obj & edge,
        "floor_near_object": ~obj & near,
        "floor_far": ~obj & ~near,
    }


def far_heights(far: Tensor, world_z: Tensor, support_z: float = SUPPORT_Z) -> dict[str, Tensor]:
    """Split the far-background pixels ``far`` (V, H, W) bool by the height ``world_z`` (V, H, W) world metres
    (NaN: no depth, in no band) of their surface point into :data:`FAR_HEIGHTS`: more than ``SKIRT_MARGIN``
    below ``support_z``, within it, more than it above."""
    lo, hi = support_z - SKIRT_MARGIN, support_z + SKIRT_MARGIN
    below, above = world_z < lo, world_z > hi
    on = (world_z >= lo) & (world_z <= hi)
    return dict(zip(FAR_HEIGHTS, (far & below, far & on, far & above), strict=True))


def region_errors(
    pred: Tensor,
    target: Tensor,
    masks: Tensor,
    valid: Tensor | None = None,
    world_z: Tensor | None = None,
    particle_weight: Tensor | None = None,
    seen: Tensor | None = None,
) -> dict[str, tuple[float, int]]:
    """Squared error per region (:func:`mask_regions`): (sum over pixels of the channel-mean squared error,
    pixel count). pred, target: (V, 3, H, W) in [0, 1]; masks: (V, H, W); valid: (V, 1, H, W) or None, only
    these pixels count (as in the eval PSNR). With ``world_z`` (V, H, W), the height (world metres, NaN where
    unknown) of each pixel's surface point, the :data:`FAR_HEIGHTS` parts of floor_far too (:func:`far_heights`).
    With ``particle_weight`` (V, H, W), the particles' summed rendered weight, and ``seen`` (V, H, W) bool, the
    :data:`OVERLAYS` too."""
    err = ((pred.clamp(0, 1) - target) ** 2).mean(1).double()
    keep = torch.ones_like(masks, dtype=torch.bool) if valid is None else valid[:, 0] > 0
    regions = mask_regions(masks)
    if world_z is not None:
        regions |= far_heights(regions["floor_far"], world_z)
    if particle_weight is not None:
        drawn = particle_weight > PARTICLES_DRAW
        regions |= {"particles_on_objects": drawn & (masks > 0), "particles_off_objects": drawn & (masks == 0)}
    if seen is not None:
        regions |= {"seen_by_context": seen, "unseen_by_context": ~seen}
    return {name: (float(err[r & keep].sum()), int((r & keep).sum())) for name, r in regions.items()}


def summarise_region_errors(parts: list[dict[str, tuple[float, int]]]) -> dict[str, dict[str, float]]:
    """Pool :func:`region_errors` of many scenes: per region its share of the pixels, its share of the squared
    error (both of the whole :data:`REGIONS` partition) and its PSNR (dB; NaN for a region with no pixel). The
    :data:`FAR_HEIGHTS` parts and the :data:`OVERLAYS` are pooled when every scene has them."""
    keys = list(REGIONS) + [k for k in (*FAR_HEIGHTS, *OVERLAYS) if all(k in p for p in parts)]
    err = {k: sum(p[k][0] for p in parts) for k in keys}
    n = {k: sum(p[k][1] for p in parts) for k in keys}
    total_err, total_n = sum(err[k] for k in REGIONS), sum(n[k] for k in REGIONS)
    return {
        k: {
            "pixel_share": n[k] / max(total_n, 1),
            "error_share": err[k] / total_err if total_err > 0 else 0.0,
            "psnr": psnr_of_mse(err[k] / n[k]) if n[k] else float("nan"),
        }
        for k in keys
    }
