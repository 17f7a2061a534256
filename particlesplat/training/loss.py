"""The training objective: a batch's negative ELBO (:func:`training_loss`) over renders of its context and
target views (:func:`render_views`), with the foreground term (:func:`foreground_error`) where a static
background layer explains the rest, or where depth shows what stands on the table (``model.fg_evidence``)."""

from __future__ import annotations

import torch
from torch import Tensor
from torch.nn.parallel import DistributedDataParallel

from particlesplat.core.camera import Camera
from particlesplat.data.dataset import TrainingBatch
from particlesplat.model import ModelConfig, ParticleSplat, TrainConfig
from particlesplat.model.evidence import foreground_evidence
from particlesplat.model.losses import elbo, scene_kl, view_error
from particlesplat.model.support_map import support_map_image
from particlesplat.rendering.api import render_batch


def render_views(
    gaussians: list, K: Tensor, c2w: Tensor, size: int, background: Tensor, foreground: bool = False
) -> tuple[Tensor, Tensor, Tensor | None]:
    """Render B scenes in their views in one rasterizer pass.

    gaussians: B sets; K: (B, V, 3, 3); c2w: (B, V, 4, 4); background: (3,) RGB behind the Gaussians of every
    scene, (B, 3) one per scene (differentiable), or (B, V, H, W, 3) an image per view -> rgb (B, V, 3, H, W),
    depth (B, V, 1, H, W), and with ``foreground`` the particles' weight (B, V, 1, H, W) (else None).
    """
    B, V = K.shape[:2]
    views = [(g, Camera(K[b, v], c2w[b, v], size, size)) for b, g in enumerate(gaussians) for v in range(V)]
    per_scene = background.ndim > 1
    res = render_batch(views, background=background.new_zeros(3) if per_scene else background, foreground=foreground)
    rgb = torch.stack([r.rgb.permute(2, 0, 1) for r in res])
    if per_scene:  # over black, then each scene's colour or each view's image where the Gaussians leave it
        alpha = torch.stack([r.alpha[None] for r in res])  # (B*V, 1, H, W)
        behind = (
            background.flatten(0, 1).permute(0, 3, 1, 2)
            if background.ndim == 5
            else background.repeat_interleave(V, 0)[:, :, None, None]
        )
        rgb = rgb + (1.0 - alpha) * behind
    depth = torch.stack([r.depth[None] for r in res])
    fg = torch.stack([r.require_foreground()[None] for r in res]).reshape(B, V, 1, size, size) if foreground else None
    return rgb.reshape(B, V, 3, size, size), depth.reshape(B, V, 1, size, size), fg


def support_map_images(support_map: Tensor, colour: Tensor, K: Tensor, c2w: Tensor, size: int) -> Tensor:
    """What B scenes' views see behind their Gaussians with ``background.support_map``: each scene's map over its
    colour. support_map: (B, 4, N, N); colour: (3,) or (B, 3); K: (B, V, 3, 3); c2w: (B, V, 4, 4) ->
    (B, V, size, size, 3) (:func:`particlesplat.model.support_map.support_map_image`)."""
    B, V = K.shape[:2]
    colours = colour.expand(B, 3) if colour.ndim == 1 else colour
    images = [
        [support_map_image(support_map[b], colours[b], Camera(K[b, v], c2w[b, v], size, size)) for v in range(V)]
        for b in range(B)
    ]
    return torch.stack([torch.stack(row) for row in images])


def foreground_error(fg: Tensor, bg_error: Tensor, threshold: float) -> Tensor:
    """Squared error of the particles' weight against what the static background layer cannot explain.

    fg: (M, 1, H, W) rendered particle weight; bg_error: (M, 1, H, W) the layer's own error per pixel
    (:meth:`ParticleSplat.static_background_error` with ``block=1``). The target is 1 where that error is
    at least ``threshold`` (an object stands there) and 0 elsewhere. Returns (M,) per-view sums over the pixels.
    """
    target = (bg_error >= threshold).to(fg.dtype)
    return ((fg - target) ** 2).flatten(1).sum(1)


def evidence_error(fg: Tensor, evidence: Tensor, outside: float) -> Tensor:
    """The foreground term against the evidence of depth (``model.fg_evidence``): per view, the squared miss of the
    particles' weight where the evidence is, plus ``outside`` times its square where it is not.

    fg: (M, 1, H, W) rendered particle weight; evidence: (M, 1, H, W) in {0, 1}. Returns (M,) sums over the pixels.
    The particles must cover what stands on the table (the background cannot) and draw beyond it at ``outside`` of
    that weight: weighed alike, a box overhanging its object turns the particle off before it learns its object;
    not weighed at all, a few particles grow over the whole table.
    """
    return (((1.0 - fg) * evidence) ** 2 + outside * (fg * (1.0 - evidence)) ** 2).flatten(1).sum(1)


def training_loss(
    model: ParticleSplat | DistributedDataParallel,
    batch: TrainingBatch,
    tc: TrainConfig,
    size: int,
    cfg: ModelConfig,
    beta_fg: float | None = None,
) -> tuple[dict[str, Tensor], Tensor]:
    """Negative ELBO of a batch. ``beta_fg``: the foreground term's weight at this step (default
    ``tc.beta_fg``; 0 leaves the term out). Returns the loss parts and the target-view renders
    (B, T, 3, H, W) (or context renders when there are no targets)."""
    beta_fg = tc.beta_fg if beta_fg is None else beta_fg
    post, z, gaussians = model(
        batch.context_rgb, batch.context_depth, batch.context_K, batch.context_c2w, sample=True, pose=batch.pose
    )
    C = batch.context_rgb.shape[1]
    K = torch.cat([batch.context_K, batch.target_K], 1)
    c2w = torch.cat([batch.context_c2w, batch.target_c2w], 1)
    net = model.module if isinstance(model, DistributedDataParallel) else model
    behind = z.get("backdrop", z["bg_color"])
    if "support_map" in z:
        behind = support_map_images(z["support_map"], behind, K, c2w, size)
    rgb_hat, depth_hat, fg_hat = render_views(gaussians, K, c2w, size, behind, beta_fg > 0)
    gt_rgb = torch.cat([batch.context_rgb, batch.target_rgb], 1)
    gt_depth = torch.cat([batch.context_depth, batch.target_depth], 1)
    B, V = gt_rgb.shape[:2]
    sup = torch.cat([torch.ones_like(batch.context_depth), batch.target_supervision], 1)
    err = view_error(
        rgb_hat.flatten(0, 1),
        gt_rgb.flatten(0, 1),
        depth_hat.flatten(0, 1),
        gt_depth.flatten(0, 1),
        sup.flatten(0, 1),
        tc.lambda_depth,
    ).reshape(B, V)
    kl = scene_kl(post, z["z_t"], cfg, tc.beta_f)
    parts = elbo(err[:, :C], err[:, C:] if V > C else None, kl, z["z_t"], tc)
    if fg_hat is not None and cfg.fg_evidence:  # particles draw what stands on the table, and nothing else
        evidence = post.bg_error  # the context views' evidence, as the encoder computed it
        if V > C:
            arm = None if batch.pose is None else batch.pose.repeat_interleave(V - C, 0)
            tgt = foreground_evidence(
                batch.target_depth.flatten(0, 1), batch.target_K.flatten(0, 1), batch.target_c2w.flatten(0, 1), arm
            )
            evidence = torch.cat([evidence, tgt.reshape(B, V - C, 1, size, size)], 1)
        fg_err = evidence_error(fg_hat.flatten(0, 1), evidence.flatten(0, 1), tc.fg_outside).reshape(B, V)
        parts["fg"] = fg_err.reshape(B, V).sum(1).mean()
        parts["loss"] = parts["loss"] + beta_fg * parts["fg"]
    elif fg_hat is not None:  # particles cover what the floor layer cannot explain, and nothing else
        # the context views' error is the one the encoder computed (no depth on a step that drops it)
        bg_err = post.bg_error
        if V > C:
            rgb_t, depth_t, K_t, c2w_t = (
                t.flatten(0, 1) for t in (batch.target_rgb, batch.target_depth, batch.target_K, batch.target_c2w)
            )
            pose_t = None if batch.pose is None else batch.pose.repeat_interleave(V - C, 0)
            tgt_err = net.static_background_error(rgb_t, depth_t, K_t, c2w_t, block=1, pose=pose_t)
            tgt_err = tgt_err.reshape(B, V - C, 1, size, size)
            bg_err = torch.cat([bg_err, tgt_err], 1)
        fg_err = foreground_error(fg_hat.flatten(0, 1), bg_err.flatten(0, 1), tc.fg_threshold)
        parts["fg"] = fg_err.reshape(B, V).sum(1).mean()
        parts["loss"] = parts["loss"] + beta_fg * parts["fg"]
    shown = rgb_hat[:, C:] if V > C else rgb_hat
    target = gt_rgb[:, C:] if V > C else gt_rgb
    with torch.no_grad():
        parts["psnr"] = -10.0 * torch.log10(((shown.clamp(0, 1) - target) ** 2).mean().clamp_min(1e-10))
        parts["active"] = (z["z_t"] > cfg.bg_mask_threshold).float().sum(1).mean()
    return parts, shown
