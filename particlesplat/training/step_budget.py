"""Whether a training step's render pass fits the memory limit, checked once before a run starts."""

from __future__ import annotations

import torch

from particlesplat.data.dataset import TrainingBatch
from particlesplat.model import ModelConfig, ParticleSplat, TrainConfig
from particlesplat.training.schedules import training_selection


def check_step_renders(
    model: ParticleSplat, cfg: ModelConfig, tc: TrainConfig, train_sets: dict, device: torch.device, config_source: str
) -> None:
    """BudgetError before the run starts when a training step's render pass would not fit the memory limit
    (:mod:`particlesplat.rendering.budget`): the first training scene is encoded once without the refinement
    (which renders; no gradients, the random state kept), its Gaussians priced in the scene's context and target
    views at ``model.resolution`` with gradients, times ``train.batch_size`` (one pass renders the batch,
    :func:`particlesplat.training.loss.render_views`). The refinement's pass (context views only, at most as many
    pixels and Gaussians, no gradients) and a validation render (one view) are smaller."""
    from particlesplat.core.camera import Camera
    from particlesplat.core.limits import check_memory
    from particlesplat.rendering.budget import candidate_pairs, pass_memory

    ds = train_sets[max(train_sets)]  # the most context views: the most particles
    devices = [device] if device.type == "cuda" else []
    with torch.random.fork_rng(devices=devices), torch.no_grad(), training_selection(cfg, tc):
        item = TrainingBatch.collate([ds[0]]).to(device)
        refine, model.refine_enabled = model.refine_enabled, False
        try:
            _, _, gaussians = model(
                item.context_rgb, item.context_depth, item.context_K, item.context_c2w, sample=False, pose=item.pose
            )
        finally:
            model.refine_enabled = refine
        K = torch.cat([item.context_K, item.target_K], 1)[0]
        c2w = torch.cat([item.context_c2w, item.target_c2w], 1)[0]
        size = cfg.resolution
        pairs = tc.batch_size * sum(
            candidate_pairs(gaussians[0], Camera(K[v], c2w[v], size, size)) for v in range(len(K))
        )
        keys = cfg.render_keys("train.particles_per_view" if tc.particles_per_view else "model.particles_per_view")
    views = tc.batch_size * len(K)
    check_memory(
        pass_memory(pairs, views * size * size, grad=True),
        f"{config_source}: a training step renders {tc.batch_size} scene(s) x {len(K)} views "
        f"(train.batch_size {tc.batch_size}; {max(train_sets)} context + train.target_views "
        f"{tc.target_views}) at {size}x{size} with gradients ({keys}): {len(gaussians[0]):,} Gaussians a scene "
        f"(the first training scene's) covering {pairs:,} (tile, Gaussian) pairs",
    )


__all__ = ["check_step_renders"]
