"""``particlesplat eval``: reconstruction, depth and decomposition metrics of a model on a folder of scenes."""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any, NotRequired, TypedDict

import numpy as np
import torch
from PIL import Image
from torch import Tensor
from tqdm import tqdm

from particlesplat.analysis.metrics import (
    below_support,
    depth_abs_rel,
    fg_ari,
    matched_miou,
    object_pixels_held,
    psnr,
    region_errors,
    region_psnr,
    ssim,
    summarise_region_errors,
)
from particlesplat.analysis.particle_arrays import (
    localisation_summary,
    object_localisation,
    scene_object_centres,
)
from particlesplat.analysis.world_turn import turn_item, turn_points
from particlesplat.core import palette
from particlesplat.core.atomic import atomic_path
from particlesplat.core.camera import Camera
from particlesplat.core.choices import (
    DEFAULT_FIT,
    OBJECT_CENTRES,
    EvalProtocol,
    check_protocol,
)
from particlesplat.core.errors import OptionError, UserError
from particlesplat.data.scene_meta import scene_pose
from particlesplat.data.views import supervision_mask
from particlesplat.editing.grouping import arm_state, particle_objects, robot_particles
from particlesplat.model.fit import fit_particles
from particlesplat.rendering.api import render

if TYPE_CHECKING:
    from particlesplat.model.particlesplat import ParticleSplat

PRUNE_Z_T = (0.0, 0.3, 0.5, 0.7)
PRUNE_OPACITY = (0.0, 0.05, 0.2, 0.5)
PRUNE_PER_PARTICLE = (2, 4, 8, 16)  # the rows keeping 1/2, 1/4, ... of each particle's Gaussians (most opaque first)


def _cameras(K: Tensor, c2w: Tensor, size: int) -> list[Camera]:
    """K: (V, 3, 3), c2w: (V, 4, 4) -> V cameras of size x size."""
    return [Camera(K[i], c2w[i], size, size) for i in range(K.shape[0])]


def _ms(t0: float, device: torch.device) -> float:
    """Milliseconds since ``t0``, once the work queued on ``device`` is done (a GPU runs asynchronously)."""
    if device.type == "cuda":
        torch.cuda.synchronize(device)
    return (time.perf_counter() - t0) * 1000.0


class ViewRenders(TypedDict):
    """What :func:`render_views` returns: the renders of V views of H x W pixels and the time per view."""

    rgb: Tensor  # (V, 3, H, W)
    depth: Tensor  # (V, 1, H, W)
    seg: Tensor  # (V, H, W) particle index per pixel
    particle_weight: Tensor  # (V, H, W) the particles' summed weight per pixel (Σ T·α of owners >= 0)
    render_ms: float  # per view
    seg_objects: NotRequired[Tensor]  # (V, H, W) object label per pixel, when render_views is given objects


def render_views(
    gaussians,
    cameras: list[Camera],
    num_owners: int,
    background: Tensor | tuple[float, float, float] | list[Tensor] = (0.0, 0.0, 0.0),
    objects: Tensor | None = None,
) -> ViewRenders:
    """Render ``gaussians`` in each camera over ``background`` ((3,), or a list of one (3,) or (H, W, 3) per
    camera): rgb (V, 3, H, W), depth (V, 1, H, W),
    seg (V, H, W) per particle, particle_weight (V, H, W), and with ``objects`` ((num_owners,) object label per
    particle) seg_objects (V, H, W) per object; ms per view. The renders are on the CPU, whatever device
    ``gaussians`` are on."""
    rgb, depth, seg, seg_obj, weight = [], [], [], [], []
    t0 = time.perf_counter()
    backs = background if isinstance(background, list) else [background] * len(cameras)
    for cam, back in zip(cameras, backs, strict=True):
        r = render(gaussians, cam, background=back, owner_weights=True, num_owners=num_owners)
        rgb.append(r.rgb.permute(2, 0, 1))
        depth.append(r.depth[None])
        seg.append(r.segmentation())
        weight.append(r.require_owner_weights().sum(0))
        if objects is not None:
            seg_obj.append(r.segmentation(objects))
    ms = _ms(t0, gaussians.means.device) / max(len(cameras), 1)
    out: ViewRenders = {
        "rgb": torch.stack(rgb).cpu(),
        "depth": torch.stack(depth).cpu(),
        "seg": torch.stack(seg).cpu(),
        "particle_weight": torch.stack(weight).cpu(),
        "render_ms": ms,
    }
    if objects is not None:
        out["seg_objects"] = torch.stack(seg_obj).cpu()
    return out


def surface_heights(cameras: list[Camera], depth: Tensor) -> Tensor:
    """World height z (V, H, W) metres of each pixel's surface point, from planar depth (V, 1, H, W) (0 = none:
    NaN) seen by V cameras."""
    out = []
    for cam, d in zip(cameras, depth[:, 0], strict=True):
        z = cam.unproject(cam.pixel_centers(), d.to(cam.dtype))[..., 2]
        out.append(torch.where(d > 0, z, torch.full_like(z, float("nan"))))
    return torch.stack(out).to(depth.dtype)


def views_mean(metric, seg: Tensor, masks: Tensor) -> float:
    """Mean over views (NaN-skipping) of ``metric(seg[i], masks[i])``. seg, masks: (V, H, W)."""
    return float(np.nanmean([metric(s, m) for s, m in zip(seg, masks, strict=True)]))


def view_psnr(pred: Tensor, gt: Tensor, sup: Tensor | None) -> float:
    """Mean over views of each view's PSNR (dB). pred, gt: (T, 3, H, W); sup: (T, 1, H, W) or None."""
    return float(np.mean([psnr(pred[i], gt[i], None if sup is None else sup[i]) for i in range(len(gt))]))


@torch.no_grad()
def evaluate_item(
    model: ParticleSplat,
    item: dict[str, Tensor],
    use_depth: bool = True,
    prune: bool = False,
    fit_steps: int = 0,
    fit_lr: float = 0.02,
    fit_latents: tuple[str, ...] = DEFAULT_FIT,
    z_t_threshold: float | None = None,
    true_centres: np.ndarray | None = None,
) -> dict:
    """Metrics of one dataset item (see :class:`particlesplat.data.SceneDataset`): encode its context
    views (then, with ``fit_steps`` > 0, fit the particles to them: :func:`particlesplat.model.fit.fit_particles`),
    decode all particles and the background, render its target views.

    Returns scalars (psnr; psnr_seen and psnr_unseen, on the target pixels a context view sees and those none
    does (NaN without context depth, or where no pixel is in the region); object_held
    (:func:`object_pixels_held`); ssim, depth_abs_rel, fg_ari, miou, fg_ari_particles, miou_particles,
    active_particles, objects, gaussians, encode_ms, fit_ms, decode_ms, render_ms), the renders under "renders",
    the target views' squared error per region (:func:`particlesplat.analysis.metrics.region_errors`) under
    "region_errors" when the item has masks, and "pruning" rows when ``prune`` (z_t and opacity thresholds, and
    each particle's most opaque Gaussians kept). fg_ari and miou score the
    segmentation into objects (particles grouped by :func:`particlesplat.editing.grouping.particle_objects`); the
    ``_particles`` keys score the plain per-particle argmax. With ``true_centres`` (N, 3) world metres,
    "localisation" holds, per object centre method, the distance from each true centre to the nearest object
    centre (:func:`particlesplat.analysis.particle_arrays.object_localisation`).
    """
    size = model.config.resolution
    ctx_cams = _cameras(item["context_K"], item["context_c2w"], size)
    tgt_cams = _cameras(item["target_K"], item["target_c2w"], size)
    depth = item["context_depth"] if use_depth and bool((item["context_depth"] > 0).any()) else None
    device = next(model.parameters()).device
    t0 = time.perf_counter()
    pose = item.get("pose")
    particles = model.encode(item["context_rgb"], depth, ctx_cams, pose)
    enc_ms = _ms(t0, device)
    t0 = time.perf_counter()
    particles = fit_particles(model, particles, item["context_rgb"], depth, fit_steps, fit_lr, latents=fit_latents)
    fit_ms = _ms(t0, device)
    t0 = time.perf_counter()
    gaussians = model.decode(particles, z_t_threshold=z_t_threshold)  # None: the particles that draw
    dec_ms = _ms(t0, device)
    objects = particle_objects(gaussians, particles.num)
    # the robot's particles are in no object: their pixels count as background in FG-ARI and mIoU
    robot = robot_particles(particles, gaussians, arm_state(model, particles))
    objects = torch.where(robot, torch.full_like(objects, -1), objects)
    bg = [model.backdrop_image(particles, cam) for cam in tgt_cams]
    out = render_views(gaussians, tgt_cams, particles.num, bg, objects)
    active = (particles.z_t[:, 0] >= model.config.bg_mask_threshold).cpu()  # the particles that draw (decode)
    sup = item.get("target_supervision")
    gt = item["target_rgb"]
    ctx_depth = item["context_depth"]
    seen = (
        supervision_mask(item["target_depth"], tgt_cams, ctx_depth, ctx_cams)[:, 0] > 0
        if bool((ctx_depth > 0).any())
        else None
    )
    keep = torch.ones_like(gt[:, 0], dtype=torch.bool) if sup is None else sup[:, 0] > 0
    res: dict[str, Any] = {
        "psnr": view_psnr(out["rgb"], gt, sup),
        "psnr_seen": float("nan") if seen is None else region_psnr(out["rgb"], gt, seen & keep),
        "psnr_unseen": float("nan") if seen is None else region_psnr(out["rgb"], gt, ~seen & keep),
        "ssim": ssim(out["rgb"], gt),
        "depth_abs_rel": depth_abs_rel(out["depth"], item["target_depth"]),
        "active_particles": int(active.sum()),
        "objects": len(torch.unique(objects[active & ~robot])),
        "robot_particles": int((active & robot).sum()),
        "gaussians": len(gaussians),
        "below_support": below_support(gaussians.means, gaussians.opacities, gaussians.owner),
        "encode_ms": enc_ms,
        "fit_ms": fit_ms,
        "decode_ms": dec_ms,
        "render_ms": out["render_ms"],
    }
    obj_masks = item.get("target_masks")
    res["object_held"] = (
        float("nan") if obj_masks is None else object_pixels_held(out["particle_weight"], obj_masks, sup)
    )
    for seg, suffix in ((out["seg_objects"], ""), (out["seg"], "_particles")):
        if "target_masks" in item:
            masks = item["target_masks"]
            res["fg_ari" + suffix] = views_mean(fg_ari, seg, masks)
            res["miou" + suffix] = views_mean(matched_miou, seg, masks)
        else:
            res["fg_ari" + suffix] = res["miou" + suffix] = float("nan")
    if "target_masks" in item:
        world_z = surface_heights(tgt_cams, item["target_depth"])
        res["region_errors"] = region_errors(
            out["rgb"], gt, item["target_masks"], sup, world_z, out["particle_weight"], seen
        )
    res["renders"] = out
    res["particles"] = particles
    if true_centres is not None:
        res["localisation"] = object_localisation(model, particles, gaussians, true_centres, objects)
    if prune:
        G = model.config.gaussians_per_particle
        settings = [(zt, op, G) for zt in PRUNE_Z_T for op in PRUNE_OPACITY]
        settings += [(model.config.bg_mask_threshold, 0.0, G // d) for d in PRUNE_PER_PARTICLE if G // d >= 1]
        target_masks = item.get("target_masks")
        rows = []
        for zt, op, k in settings:
            g = model.decode(particles, z_t_threshold=zt, opacity_threshold=op, max_per_particle=k)
            r = render_views(g, tgt_cams, particles.num, bg, objects)
            ari = float("nan") if target_masks is None else views_mean(fg_ari, r["seg_objects"], target_masks)
            rows.append(
                {
                    "z_t_threshold": zt,
                    "opacity_threshold": op,
                    "max_per_particle": k,
                    "psnr": view_psnr(r["rgb"], gt, sup),
                    "fg_ari": ari,
                    "gaussians": len(g),
                    "render_ms": r["render_ms"],
                }
            )
        res["pruning"] = rows
    return res


SCALARS = (
    "psnr",
    "psnr_seen",
    "psnr_unseen",
    "object_held",
    "ssim",
    "depth_abs_rel",
    "fg_ari",
    "miou",
    "fg_ari_particles",
    "miou_particles",
    "active_particles",
    "objects",
    "robot_particles",
    "gaussians",
    "below_support",
    "encode_ms",
    "fit_ms",
    "decode_ms",
    "render_ms",
)


def _nanmean(values: list[float]) -> float:
    v = [x for x in values if x is not None and not (isinstance(x, float) and math.isnan(x))]
    return float(np.mean(v)) if v else float("nan")


FIGURE_ROWS = ("context", "target", "render", "depth", "objects")  # the rows of save_figure, labelled on the left
FIGURE_LABEL_WIDTH = 56  # pixels of the label column


def save_figure(path: Path, item: dict[str, Tensor], res: dict) -> list[float]:
    """PNG grid, each row labelled in a column on the left (:data:`FIGURE_ROWS`): row 1 context views, row 2 target
    ground truth, row 3 renders with each view's PSNR (dB) written under it, row 4 depth (black = 0 m, white = the
    98th percentile, its metres in the row's label), row 5 segmentation into objects in the shared palette
    (:mod:`particlesplat.core.palette`: the colours of ``render --mode objects`` and the viewer). Returns the
    per-view PSNRs written."""

    def img(t: Tensor) -> np.ndarray:
        return (t.clamp(0, 1).permute(1, 2, 0).cpu().numpy() * 255).astype(np.uint8)

    r = res["renders"]
    T = r["rgb"].shape[0]
    H = W = r["rgb"].shape[-1]
    d = r["depth"][:, 0]
    dmax = float(torch.quantile(d[d > 0], 0.98)) if bool((d > 0).any()) else 1.0
    cols = max(T, item["context_rgb"].shape[0])
    grid = np.zeros((5 * H, cols * W, 3), np.uint8)
    for i in range(item["context_rgb"].shape[0]):
        grid[0:H, i * W : (i + 1) * W] = img(item["context_rgb"][i])
    for i in range(T):
        grid[H : 2 * H, i * W : (i + 1) * W] = img(item["target_rgb"][i])
        grid[2 * H : 3 * H, i * W : (i + 1) * W] = img(r["rgb"][i])
        grid[3 * H : 4 * H, i * W : (i + 1) * W] = (np.clip(d[i].cpu().numpy() / dmax, 0, 1) * 255).astype(np.uint8)[
            ..., None
        ]
        s = r["seg_objects"][i].cpu().numpy()
        grid[4 * H : 5 * H, i * W : (i + 1) * W] = np.round(palette.colour_map(s) * 255.0).astype(np.uint8)
    from PIL import ImageDraw

    out = Image.new("RGB", (FIGURE_LABEL_WIDTH + grid.shape[1], grid.shape[0]), (0, 0, 0))
    out.paste(Image.fromarray(grid), (FIGURE_LABEL_WIDTH, 0))
    draw = ImageDraw.Draw(out)
    for row, label in enumerate(FIGURE_ROWS):
        draw.text((4, row * H + H // 2 - 6), label, fill=(235, 235, 235))
    draw.text((4, 3 * H + H // 2 + 6), f"0-{dmax:.2f} m", fill=(235, 235, 235))
    scores = [psnr(r["rgb"][i], item["target_rgb"][i].to(r["rgb"].device)) for i in range(T)]
    for i, score in enumerate(scores):  # under each render, on a dark band
        x, y = FIGURE_LABEL_WIDTH + i * W + 2, 3 * H - 12
        draw.rectangle([x - 2, y - 1, x + 6 * 7 + 2, y + 10], fill=(0, 0, 0))
        draw.text((x, y), f"{score:.1f} dB", fill=(255, 255, 255))
    with atomic_path(path) as tmp:
        out.save(tmp, format="PNG")
    return scores


def evaluate_dataset(
    model: ParticleSplat,
    data_dir: str | Path,
    context: int = 2,
    limit: int | None = None,
    figures: Path | None = None,
    num_figures: int = 4,
    prune: bool = False,
    use_depth: bool = True,
    seed: int = 0,
    progress_bar: bool = True,
    fit_steps: int = 0,
    fit_lr: float = 0.02,
    fit_latents: tuple[str, ...] = DEFAULT_FIT,
    z_t_threshold: float | None = None,
    turn: float = 0.0,
    protocol: EvalProtocol = "sampled",
) -> dict:
    """Evaluate on every scene of ``data_dir`` (a split folder). Returns {"scenes": [...], "mean": {...}}.
    ``protocol``: which views are encoded and scored (:data:`particlesplat.core.choices.EVAL_PROTOCOLS`; "paper"
    needs two context views and scenes of at least 15 frames).
    ``z_t_threshold``: particles drawn (None: the model's, :meth:`ParticleSplat.decode`; 0: every one).
    ``turn``: degrees by which every scene's world frame is turned about z first (:mod:`.world_turn`)."""
    from particlesplat.core.atomic import check_writable
    from particlesplat.core.errors import blame
    from particlesplat.core.gaussians import BadGaussiansError
    from particlesplat.data import SceneDataset

    if limit is not None and limit < 1:
        raise OptionError(f"--limit must be >= 1 (or absent for every scene), got {limit}")
    check_protocol(protocol, context)
    if figures is not None and num_figures > 0:
        check_writable(Path(figures) / "figure.png")  # before the work, not after it
    ds = SceneDataset(
        data_dir,
        resolution=model.config.resolution,
        mode="multi" if context == 2 else "single",
        deterministic=True,
        seed=seed,
        progress=1.0,
        protocol=protocol,
    )
    n = len(ds) if limit is None else min(limit, len(ds))
    scenes, prune_rows, regions = [], [], []
    located: dict[str, list[float]] = {m: [] for m in OBJECT_CENTRES}
    cfg = model.config
    for i in tqdm(range(n), desc="eval", disable=not progress_bar):
        item = ds[i]
        pose = scene_pose(ds.scenes[i], cfg.bg_static_pose, cfg.bg_static_pose_dims, model.input_ranges)
        if pose is not None:
            item["pose"] = pose
        true_centres = scene_object_centres(ds.scenes[i])
        if turn:
            item = turn_item(item, turn, cfg.bg_static_pose)
            true_centres = turn_points(true_centres, turn)
        if protocol == "sampled" and set(item["target_index"].tolist()) <= set(item["context_index"].tolist()):
            raise UserError(
                f"{ds.scenes[i]}: {ds.raw(i).num_frames} frame(s): no target view apart from the "
                f"{context} context view(s); evaluation needs at least {context + 1} frames"
            )
        with blame(str(ds.scenes[i]), BadGaussiansError):  # the renderer's refusal, naming the scene
            res = evaluate_item(
                model,
                item,
                use_depth=use_depth,
                prune=prune,
                fit_steps=fit_steps,
                fit_lr=fit_lr,
                fit_latents=fit_latents,
                true_centres=true_centres,
                z_t_threshold=z_t_threshold,
            )
        if figures is not None and i < num_figures:
            save_figure(Path(figures) / f"{ds.scenes[i].name}.png", item, res)
        row = {"scene": ds.scenes[i].name, **{k: res[k] for k in SCALARS}}
        if "localisation" in res:
            row["localisation_m"] = res["localisation"]
            for m, d in res["localisation"].items():
                located[m] += d
        scenes.append(row)
        if "region_errors" in res:
            regions.append(res["region_errors"])
        if prune:
            prune_rows.append(res["pruning"])
    mean = {k: _nanmean([s[k] for s in scenes]) for k in SCALARS}
    out = {
        "data": str(data_dir),
        "context": context,
        "depth": use_depth,
        "protocol": protocol,
        "scenes": scenes,
        "mean": mean,
    }
    if turn:
        out["turn_deg"] = turn
    if located[OBJECT_CENTRES[0]]:  # scenes whose generator recorded the object centres
        out["localisation"] = {m: localisation_summary(d) for m, d in located.items()}
    if regions:  # where the squared error of the target views lies, pooled over the scenes
        out["error_regions"] = summarise_region_errors(regions)
    if prune:
        table = []
        for j, row in enumerate(prune_rows[0]):
            table.append(
                {
                    "z_t_threshold": row["z_t_threshold"],
                    "opacity_threshold": row["opacity_threshold"],
                    "max_per_particle": row["max_per_particle"],
                    **{
                        k: _nanmean([rows[j][k] for rows in prune_rows])
                        for k in ("psnr", "fg_ari", "gaussians", "render_ms")
                    },
                }
            )
        out["pruning"] = table
    return out


def json_safe(value):
    """``value`` with every NaN or infinite float replaced by None (JSON ``null``: bare NaN is not JSON)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    return value
