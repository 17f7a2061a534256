"""What training changes: the model's particle selection while it trains, and over the steps the view-gap
curriculum of the data sampler and the learning rate."""

from __future__ import annotations

import math
from collections.abc import Iterator
from contextlib import contextmanager

from particlesplat.data.views import WARMUP
from particlesplat.model import ModelConfig, TrainConfig


@contextmanager
def training_selection(cfg: ModelConfig, tc: TrainConfig) -> Iterator[None]:
    """Inside: the model keeps ``tc.particles_per_view`` particles per view, ``tc.kp_min_separation`` apart (0 keeps
    the model's values); outside, the model config (what inference and checkpoints use) is unchanged."""
    saved = (cfg.particles_per_view, cfg.kp_min_separation)
    cfg.particles_per_view = tc.particles_per_view or cfg.particles_per_view
    cfg.kp_min_separation = tc.kp_min_separation or cfg.kp_min_separation
    try:
        yield
    finally:
        cfg.particles_per_view, cfg.kp_min_separation = saved


def gap_progress(step: int, tc: TrainConfig) -> float:
    """The data sampler's progress at ``step``: its view-gap range grows linearly to the full range over the
    first ``gap_warmup`` of the steps (0: full from the start)."""
    done = 1.0 if tc.gap_warmup == 0 else min(step / (tc.steps * tc.gap_warmup), 1.0)
    return 1.0 if done >= 1.0 else done * WARMUP


def lr_factor(step: int, tc: TrainConfig) -> float:
    """Learning-rate multiplier of optimiser step ``step`` (0-based): a cosine from 1 at step 0 to
    ``lr_final`` at the last step (``lr_final`` 1: constant)."""
    t = min(step / max(tc.steps - 1, 1), 1.0)
    return tc.lr_final + (1.0 - tc.lr_final) * 0.5 * (1.0 + math.cos(math.pi * t))


__all__ = ["gap_progress", "lr_factor", "training_selection"]
