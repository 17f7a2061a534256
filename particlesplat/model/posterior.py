"""The encoder's output as typed records: the particle posteriors q(z_p, z_s, z_d, z_e, z_t, z_f | views) and the
scene posterior that adds the per-view background.

Particle latents (DLP names): z_p = kp + offset (N(mu_o, e^lv_o)), z_s ~ N(mu_s, e^lv_s), z_d ~ N(mu_d, e^lv_d),
z_e ~ N(mu_e, e^lv_e), z_t ~ Beta(beta_a, beta_b), z_f ~ N(mu_f, e^lv_f). ``lv_*`` are log-variances.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Self

from torch import Tensor


@dataclass(frozen=True)
class ParticlePosterior:
    """Per-particle posterior parameters, every field (..., L, ·) with the same leading dims ((M, L) per view,
    (B, N) per scene).

    kp: (..., 2) keypoint in normalised image coordinates [-1, 1] (x, y); mu_o, lv_o: (..., 2) offset from kp
    (normalised units); mu_s, lv_s: (..., 2) box half-size logits (sigmoid -> normalised units); mu_d, lv_d: (..., 1)
    depth logit (between ``d_min`` and ``d_max`` metres); mu_e, lv_e: (..., 1) depth-extent logit; beta_a, beta_b:
    (..., 1) > 0 Beta parameters of the transparency z_t; mu_f, lv_f: (..., d_obj) appearance features.
    """

    kp: Tensor
    mu_o: Tensor
    lv_o: Tensor
    mu_s: Tensor
    lv_s: Tensor
    mu_d: Tensor
    lv_d: Tensor
    mu_e: Tensor
    lv_e: Tensor
    beta_a: Tensor
    beta_b: Tensor
    mu_f: Tensor
    lv_f: Tensor

    def t_mean(self) -> Tensor:
        """E[z_t] = a / (a + b): (..., 1) in (0, 1)."""
        return self.beta_a / (self.beta_a + self.beta_b)

    def replace(self, **changes: Tensor) -> Self:
        """A copy with the named fields changed (the others shared, not copied)."""
        return dataclasses.replace(self, **changes)


@dataclass(frozen=True)
class Posterior(ParticlePosterior):
    """Posterior of B scenes with V context views and N = V*L particles: the particle fields of
    :class:`ParticlePosterior` as (B, N, ·), and

    mu_bg, lv_bg: (B, V, d_bg, h, w) background latent mean and log-variance per view; bg_mask: (B, V, 1, H, W)
    1 inside the boxes of active particles (hidden from the background encoder); view: (N,) int64 context view
    of each particle; bg_error: (B, V, 1, H, W) the background's own error per pixel (squared RGB + squared
    depth error in metres where depth is known): the static layer's per pixel, else the per-view background's
    per ``bg_block``² block; static_layer: (B, V, 5, H, W) the static layer alone rendered into the context views
    (colour over the background colour, depth in metres, alpha: :mod:`particlesplat.rendering.layers`), or None
    (no static layer); pose: (B, D) the scenes' poses the workspace layer follows (``bg_static_pose``), or None;
    bg_anchor: (B, V, 6, Hb, Wb) the anchored background's per-block anchors (``fg_evidence``:
    :func:`particlesplat.model.decoder.block_anchors`), or None; colour_anchor: (B, N, 2*S*S*3) the colours of
    the context views under each particle's cells (``patch.colour_anchor``: :meth:`ParticleSplat.with_colour_anchors`),
    or None.
    """

    mu_bg: Tensor
    lv_bg: Tensor
    bg_mask: Tensor
    view: Tensor
    bg_error: Tensor
    static_layer: Tensor | None = None
    pose: Tensor | None = None
    bg_anchor: Tensor | None = None
    colour_anchor: Tensor | None = None


__all__ = ["ParticlePosterior", "Posterior"]
