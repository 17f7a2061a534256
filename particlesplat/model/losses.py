"""The multi-view ELBO: reconstruction over context and target views, scene-level masked KL, z_t regulariser."""

from __future__ import annotations

import math

import torch
from torch import Tensor

from particlesplat.model.config import ModelConfig, TrainConfig
from particlesplat.model.posterior import Posterior


def kl_normal(mu: Tensor, logvar: Tensor, prior_mu: float, prior_std: float) -> Tensor:
    """KL(N(mu, exp(logvar)) || N(prior_mu, prior_std²)) elementwise. mu, logvar: (...) -> (...)."""
    var_ratio = torch.exp(logvar) / prior_std**2
    return 0.5 * (var_ratio + (mu - prior_mu) ** 2 / prior_std**2 - 1.0 - torch.log(var_ratio))


def kl_beta(a: Tensor, b: Tensor, a0: float, b0: float) -> Tensor:
    """KL(Beta(a, b) || Beta(a0, b0)) elementwise, closed form. a, b: (...) -> (...)."""
    lbeta = lambda x, y: torch.lgamma(x) + torch.lgamma(y) - torch.lgamma(x + y)  # noqa: E731
    lb0 = math.lgamma(a0) + math.lgamma(b0) - math.lgamma(a0 + b0)
    return (
        lb0
        - lbeta(a, b)
        + (a - a0) * torch.digamma(a)
        + (b - b0) * torch.digamma(b)
        + (a0 - a + b0 - b) * torch.digamma(a + b)
    )


def scene_kl(post: Posterior, z_t: Tensor, cfg: ModelConfig, beta_f: float) -> Tensor:
    """Scene-level masked KL of the appendix, one value per scene (B,), not normalised by views.

    post: posterior parameters (B, N, ·) and background (B, V, d_bg, h, w); z_t: (B, N, 1) the transparency
    that masks the geometric and appearance KL terms (the Beta KL of z_t itself is unmasked). The background
    latents' KL counts only for a model that decodes them (``bg_per_view``).
    """
    geo = (
        kl_normal(post.mu_o, post.lv_o, 0.0, cfg.prior_offset_std).sum(-1)
        + kl_normal(post.mu_s, post.lv_s, cfg.logit_prior_scale, cfg.prior_scale_std).sum(-1)
        + kl_normal(post.mu_d, post.lv_d, cfg.prior_depth_mean, cfg.prior_depth_std).sum(-1)
        + kl_normal(post.mu_e, post.lv_e, cfg.logit_prior_extent, cfg.prior_extent_std).sum(-1)
    )
    feat = kl_normal(post.mu_f, post.lv_f, 0.0, 1.0).sum(-1)
    t = kl_beta(post.beta_a, post.beta_b, cfg.prior_t_a, cfg.prior_t_b).sum(-1)
    mask = z_t[..., 0]
    fg = ((geo + beta_f * feat) * mask + t).sum(-1)
    if not cfg.bg_per_view:  # no background latent is decoded: it carries no information and costs nothing
        return fg
    bg = beta_f * kl_normal(post.mu_bg, post.lv_bg, 0.0, 1.0).flatten(1).sum(-1)
    return fg + bg


def view_error(
    rgb_hat: Tensor, rgb: Tensor, depth_hat: Tensor, depth: Tensor | None, mask: Tensor | None, lambda_depth: float
) -> Tensor:
    """𝓔(x, x̂) per view: Σ (I − Î)² + λ_D Σ_valid (D − D̂)², summed over pixels (and channels).

    rgb*: (B, 3, H, W); depth*: (B, 1, H, W) metres (0 = no ground truth); mask: (B, 1, H, W) or None.
    Returns (B,).
    """
    m = torch.ones_like(rgb[:, :1]) if mask is None else mask
    err = ((rgb_hat - rgb) ** 2 * m).flatten(1).sum(-1)
    if depth is not None and lambda_depth > 0:
        valid = (depth > 0).to(rgb.dtype) * m
        err = err + lambda_depth * (((depth_hat - depth) ** 2) * valid).flatten(1).sum(-1)
    return err


def elbo(rec_ctx: Tensor, rec_tgt: Tensor | None, kl: Tensor, z_t: Tensor, tc: TrainConfig) -> dict[str, Tensor]:
    """Negative ELBO with the z_t regulariser, averaged over the B scenes of the batch.

    rec_ctx: (B, Vc) per-view errors of the context views; rec_tgt: (B, Vt) or None; kl: (B,);
    z_t: (B, N, 1). Returns loss and its parts (scalars).
    """
    n = rec_ctx.shape[1] + (0 if rec_tgt is None else rec_tgt.shape[1])
    rec = tc.beta_rec_ctx * rec_ctx.sum(1)
    if rec_tgt is not None:
        rec = rec + tc.beta_rec_tgt * rec_tgt.sum(1)
    rec = rec / n
    reg = (z_t[..., 0] ** 2).sum(-1)
    loss = rec + tc.beta_kl * kl + tc.beta_reg * reg
    return {"loss": loss.mean(), "rec": rec.mean(), "kl": kl.mean(), "reg": reg.mean()}
