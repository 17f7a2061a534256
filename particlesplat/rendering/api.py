"""``render``: the differentiable torch reference rasterizer (3DGS / gsplat rules)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import torch
from torch import Tensor

from particlesplat.core.camera import Camera
from particlesplat.core.gaussians import Gaussians, quats_to_rotations
from particlesplat.core.sh import eval_sh_colors
from particlesplat.rendering.budget import check_pass
from particlesplat.rendering.choice import resolve_rasterizer
from particlesplat.rendering.fused import rasterize_fused
from particlesplat.rendering.fused_projection import project_views_fused
from particlesplat.rendering.measured import set_workload_renderer
from particlesplat.rendering.projection import footprint_extents, project_views
from particlesplat.rendering.rasterize import RasterizeFunction, bin_gaussians, pair_inputs, tiles_to_images


def object_segmentation(owner_weights: Tensor, background_weight: Tensor, objects: Tensor) -> Tensor:
    """Per-pixel argmax over objects: the weights of each object's particles are summed first.

    owner_weights: (P, H, W) Σ T·α per particle; background_weight: (H, W) Σ T·α of the background
    plus the empty remainder; objects: (P,) int64 object label per particle
    (:func:`particlesplat.editing.grouping.particle_objects` or :func:`~particlesplat.editing.grouping.dense_objects`),
    < 0 for a particle in no object (its weight counts as background).
    Returns (H, W) int64 object label, -1 where the background weighs most.
    """
    P = owner_weights.shape[0]
    if tuple(objects.shape) != (P,):
        raise ValueError(f"objects must have shape ({P},), got {tuple(objects.shape)}")
    objects = objects.to(owner_weights.device)
    some = objects >= 0
    summed = torch.zeros_like(owner_weights).index_add_(0, objects[some], owner_weights[some])
    background = background_weight + owner_weights[~some].sum(0)
    scores = torch.cat([background[None], summed], dim=0)  # (1 + P, H, W)
    return scores.argmax(0) - 1


@dataclass
class RenderResult:
    """One rendered view.

    Attributes:
        rgb: (H, W, 3) colour composited over the background.
        alpha: (H, W) accumulated opacity Σ T·α.
        depth: (H, W) expected planar camera z, Σ T·α·z / alpha, metres; 0 where alpha is 0.
        owner_weights: (P, H, W) Σ T·α of the Gaussians of each owner 0..P-1, or None.
            Not differentiable.
        background_weight: (H, W) Σ T·α of the background Gaussians (owner -1), or None.
        foreground: (H, W) Σ T·α of the Gaussians with an owner >= 0 (the particles), differentiable, or
            None.
    """

    rgb: Tensor
    alpha: Tensor
    depth: Tensor
    owner_weights: Tensor | None = None
    background_weight: Tensor | None = None
    foreground: Tensor | None = None

    def require_owner_weights(self) -> Tensor:
        """(P, H, W) :attr:`owner_weights` of a render made with ``owner_weights=True`` (else a ValueError)."""
        if self.owner_weights is None:
            raise ValueError("require_owner_weights() needs render(..., owner_weights=True)")
        return self.owner_weights

    def require_foreground(self) -> Tensor:
        """(H, W) :attr:`foreground` of a render made with ``foreground=True`` (else a ValueError)."""
        if self.foreground is None:
            raise ValueError("require_foreground() needs render(..., foreground=True)")
        return self.foreground

    def segmentation(self, objects: Tensor | None = None) -> Tensor:
        """(H, W) int64 argmax owner per pixel; -1 where the background (Gaussians of owner -1
        plus the empty remainder 1 - alpha) weighs most.

        objects: (P,) int64 object label per owner (:func:`particlesplat.editing.grouping.particle_objects`):
        the weights of the owners of one object are summed and the pixel gets the object's label.
        """
        if self.owner_weights is None or self.background_weight is None:
            raise ValueError("segmentation() needs render(..., owner_weights=True)")
        bg = (self.background_weight + (1.0 - self.alpha)).detach()
        if objects is None:
            objects = torch.arange(self.owner_weights.shape[0], device=self.owner_weights.device)
        return object_segmentation(self.owner_weights, bg, objects)


def behind(background: Sequence[float] | Tensor, size: tuple[int, ...], dtype: torch.dtype, device) -> Tensor:
    """``background`` as what a render of ``size`` (H, W) composites over: (1, 1, 3) for a colour, (H, W, 3)
    for an image of that size; ValueError for anything else."""
    bg = torch.as_tensor(background, dtype=dtype, device=device)
    if bg.numel() == 3:
        return bg.reshape(1, 1, 3)
    if tuple(bg.shape) != (*size, 3):
        raise ValueError(f"render: background must be (3,) or {(*size, 3)}, got {tuple(bg.shape)}")
    return bg


def render(
    gaussians: Gaussians,
    camera: Camera,
    *,
    background: Sequence[float] | Tensor = (0.0, 0.0, 0.0),
    near: float = 0.01,
    far: float = 1e10,
    owner_weights: bool = False,
    num_owners: int | None = None,
    foreground: bool = False,
    rasterizer: str | None = None,
) -> RenderResult:
    """Render ``gaussians`` seen by ``camera``.

    Rules (3DGS/gsplat): EWA projection with the Jacobian's x/z and y/z clamped to the field of
    view + 30 %; + 0.3 px² on the 2D covariance diagonal; α = min(0.99, o·exp(−½dᵀΣ⁻¹d)) and a
    Gaussian contributes exactly where α ≥ 1/255; front to back by camera z, ties broken by
    index; a pixel stops before the Gaussian that would take its transmittance to ≤ 1e-4;
    Gaussians outside near < z < far are culled. Colours come from the SH evaluated along the
    direction camera centre → mean.

    Raises ValueError (naming the field and the Gaussian) for a non-finite value, a negative scale or
    opacity, or an owner outside -1..MAX_OWNER (:meth:`Gaussians.check`).

    Differentiable with respect to means, quats, scales, opacities and sh. Works in the
    dtype and on the device of ``gaussians`` (the camera is converted).

    Args:
        background: (3,) colour behind everything, or (H, W, 3) one per pixel.
        owner_weights: also return per-owner weight maps (for masks and segmentation).
        num_owners: P for the owner maps (default: max owner + 1); owners outside 0..P-1
            count as background.
        foreground: also return the differentiable weight of the Gaussians with an owner >= 0.
        rasterizer: 'fused', 'torch' or 'auto' (default: the process's choice,
            :mod:`particlesplat.rendering.choice`): the same image to float32 rounding either way.
    """
    return render_batch(
        [(gaussians, camera)],
        background=background,
        near=near,
        far=far,
        owner_weights=owner_weights,
        num_owners=num_owners,
        foreground=foreground,
        rasterizer=rasterizer,
    )[0]


def render_batch(
    views: Sequence[tuple[Gaussians, Camera]],
    *,
    background: Sequence[float] | Tensor = (0.0, 0.0, 0.0),
    near: float = 0.01,
    far: float = 1e10,
    owner_weights: bool = False,
    num_owners: int | None = None,
    foreground: bool = False,
    rasterizer: str | None = None,
    backgrounds: Sequence[Tensor] | None = None,
) -> list[RenderResult]:
    """Render several (Gaussians, camera) pairs in one pass; same rules and results as :func:`render`.

    ``background``: (3,) colour or (H, W, 3) image behind every view; ``backgrounds``, one of them per view
    instead.

    ``foreground``: also return the differentiable weight of the particles' Gaussians (owner >= 0) per
    pixel (``RenderResult.foreground``), one more feature column of the same pass.

    All views share one tile list and one set of rasterizer chunks, which amortises the
    per-call overhead when training renders many small views. The Gaussians of all views must
    share dtype, device and SH degree. Inside :func:`particlesplat.rendering.budget.render_budget` a pass whose
    estimated memory is over the limit raises BudgetError before its pairs are built.
    """
    if not views:
        return []
    # each distinct Gaussian set once (training renders one set into several views), then one instance per
    # (view, Gaussian): the projection and colours of all views are computed together
    set_of: dict[int, int] = {}
    sets: list[Gaussians] = []
    for i, (gaussians, _) in enumerate(views):
        if id(gaussians) not in set_of:  # NaN would spread to every pixel and, through clipping, every gradient
            gaussians.check(f"render: view {i}" if len(views) > 1 else "render")
            set_of[id(gaussians)] = len(sets)
            sets.append(gaussians)
    dtype, device = views[0][0].means.dtype, views[0][0].means.device
    if backgrounds is not None and len(backgrounds) != len(views):
        raise ValueError(f"render: {len(backgrounds)} backgrounds for {len(views)} views")
    bgs = [background] * len(views) if backgrounds is None else list(backgrounds)
    g = sets[0] if len(sets) == 1 else Gaussians.cat(sets)
    first = [0]
    for s in sets[:-1]:
        first.append(first[-1] + len(s))
    rows = torch.cat(
        [torch.arange(len(gs), device=device) + first[set_of[id(gs)]] for gs, _ in views]
    )  # instance -> row of g
    view = torch.cat([torch.full((len(gs),), v, dtype=torch.int64, device=device) for v, (gs, _) in enumerate(views)])
    cams = [camera.to(device=device, dtype=dtype) for _, camera in views]
    sizes = [(cam.width, cam.height) for cam in cams]
    grad = torch.is_grad_enabled() and any(t.requires_grad for t in (g.means, g.quats, g.scales, g.opacities, g.sh))
    fused = resolve_rasterizer(rasterizer, device, grad) == "fused"
    project = project_views_fused if fused else project_views
    proj = project(g.means, quats_to_rotations(g.quats), g.scales, rows, view, cams, near, far)
    rows = rows.index_select(0, proj.index)
    view = view.index_select(0, proj.index)
    opac = g.opacities.index_select(0, rows)
    radius = footprint_extents(proj, opac)
    P = 0
    if owner_weights:
        P = int(num_owners) if num_owners is not None else (int(g.owner.max()) + 1 if len(g) else 0)
    # inside a job's render_budget: refused here, before the pairs are built, when they would not fit
    check_pass(proj.means2d, radius, view, sizes, P + 1 if owner_weights else 0, grad)
    centres = torch.stack([cam.center for cam in cams])
    dirs = torch.nn.functional.normalize(g.means.index_select(0, rows) - centres.index_select(0, view), dim=-1)
    colors = eval_sh_colors(g.sh.index_select(0, rows), dirs)
    owner = g.owner.index_select(0, rows)
    # per-Gaussian feature columns: colour, depth, then the extras that ride along in the same pass (so α and T are
    # computed once): the per-owner weights as one-hot columns (slot 0 = background, 1..P = owners) and the
    # particles' weight; the rasterizer appends Σ w (alpha) as the last column
    columns = [colors, proj.depths[:, None]]
    if owner_weights:
        slot = torch.where((owner >= 0) & (owner < P), owner + 1, torch.zeros_like(owner))
        columns.append(torch.nn.functional.one_hot(slot, P + 1).to(colors.dtype))
    if foreground:
        columns.append((owner >= 0).to(colors.dtype)[:, None])
    features = torch.cat(columns, dim=-1)  # (M, C)
    if fused:
        tiles, grids = rasterize_fused(proj.means2d, proj.conics, opac, features, radius, proj.depths, view, sizes)
    else:
        bins = bin_gaussians(proj.means2d, proj.conics, opac, radius, proj.depths, view, sizes)
        tiles = RasterizeFunction.apply(*pair_inputs(bins, proj.means2d, proj.conics, opac, features), bins)
        grids = bins.grids
    results = []
    for acc, back in zip(tiles_to_images(tiles, grids, sizes), bgs, strict=True):
        alpha = acc[..., -1]
        rgb = acc[..., :3] + (1.0 - alpha)[..., None] * behind(back, acc.shape[:2], dtype, device)
        depth = torch.where(alpha > 0, acc[..., 3] / alpha.clamp_min(1e-12), torch.zeros_like(alpha))
        result = RenderResult(rgb, alpha, depth)
        if foreground:
            result.foreground = acc[..., -2]
        if owner_weights:
            maps = acc[..., 4 : 4 + P + 1].detach()
            result.owner_weights = maps[..., 1:].permute(2, 0, 1).contiguous()
            result.background_weight = maps[..., 0].contiguous()
        results.append(result)
    return results


set_workload_renderer(render_batch)  # the rasterizer measurement times this renderer (rendering.measured)
