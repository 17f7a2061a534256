"""DLP-style view-aware encoder: keypoint proposals, STN glimpses, attribute heads, ray-FiLM transformer,
and a per-view background encoder whose input has the boxes of active particles masked out."""

from __future__ import annotations

from dataclasses import fields

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from particlesplat.model.config import ModelConfig
from particlesplat.model.decoder import conv_bias
from particlesplat.model.geometry import plucker_at, plucker_map
from particlesplat.model.posterior import ParticlePosterior


def conv3x3(cin: int, cout: int, stride: int = 1) -> nn.Module:
    return nn.Sequential(nn.Conv2d(cin, cout, 3, stride=stride, padding=1), nn.SiLU())


def depth_input(depth: Tensor | None, like: Tensor, cfg: ModelConfig) -> Tensor:
    """depth: (M, 1, H, W) metres (0 = missing) or None -> (M, 2, H, W) [depth / d_max, valid]."""
    if depth is None:
        return torch.zeros(like.shape[0], 2, *like.shape[-2:], device=like.device, dtype=like.dtype)
    valid = (depth > 0).to(like.dtype)
    return torch.cat([depth / cfg.d_max, valid], dim=1)


class RayConditioning(nn.Module):
    """h' = h + W φ(c̃) + b: Plücker map resampled to the feature size, unit directions, 1×1 conv."""

    def __init__(self, channels: int):
        super().__init__()
        self.proj = nn.Conv2d(6, channels, 1)

    def forward(self, h: Tensor, rays: Tensor) -> Tensor:
        """h: (M, C, h, w); rays: (M, 6, H, W) -> (M, C, h, w)."""
        r = F.interpolate(rays, size=h.shape[-2:], mode="bilinear", align_corners=False)
        r = torch.cat([F.normalize(r[:, :3], dim=1), r[:, 3:]], dim=1)
        return h + self.proj(torch.tanh(r))


class FusedBackbone(nn.Module):
    """Parallel RGB and depth CNNs (strides 1, 2, 4) with depth fused into RGB and rays added at every level."""

    def __init__(self, cfg: ModelConfig, extra_in: int = 0):
        super().__init__()
        c = cfg.channels
        widths = [c // 2, c, c]
        self.rgb = nn.ModuleList(
            [conv3x3(3 + extra_in, widths[0]), conv3x3(widths[0], widths[1], 2), conv3x3(widths[1], widths[2], 2)]
        )
        self.dep = nn.ModuleList(
            [conv3x3(2, widths[0]), conv3x3(widths[0], widths[1], 2), conv3x3(widths[1], widths[2], 2)]
        )
        self.fuse = nn.ModuleList([nn.Conv2d(w, w, 1) for w in widths])
        self.rays = nn.ModuleList([RayConditioning(w) for w in widths])
        self.out_channels = widths[-1]

    def forward(self, rgb: Tensor, dep: Tensor, rays: Tensor) -> Tensor:
        """rgb: (M, 3+extra, H, W); dep: (M, 2, H, W); rays: (M, 6, H, W) -> (M, C, H/4, W/4)."""
        h, g = rgb, dep
        for conv_r, conv_d, fuse, ray in zip(self.rgb, self.dep, self.fuse, self.rays, strict=False):
            h, g = conv_r(h), conv_d(g)
            h = ray(h + fuse(g), rays)
        return h


class ParticleEncoder(nn.Module):
    """q(z_fg | context views): proposals -> top-L -> glimpse heads -> ray-FiLM transformer refinement."""

    def __init__(self, cfg: ModelConfig):
        super().__init__()
        self.cfg = cfg
        c = cfg.channels
        P = cfg.kp_patch
        self.backbone = FusedBackbone(cfg)
        self.heat = nn.Conv2d(self.backbone.out_channels, P * P + 1, 1)  # patch logits + presence logit
        g = cfg.glimpse_size
        self.glimpse_cnn = nn.Sequential(
            conv3x3(5, c // 2, 2), conv3x3(c // 2, c, 2), conv3x3(c, c, 2 if g >= 16 else 1)
        )
        gs = g // 8 if g >= 16 else g // 4
        hid = 4 * c
        self.glimpse_fc = nn.Sequential(nn.Linear(c * gs * gs + self.backbone.out_channels, hid), nn.SiLU())
        D = cfg.d_obj
        # heads: offset (2+2), scale (2+2), depth (1+1), extent (1+1), Beta (2), features (D+D)
        self.head = nn.Linear(hid, 14 + 2 * D)
        nn.init.normal_(self.head.weight, std=1e-3)
        b = torch.zeros(14 + 2 * D)
        b[2:4] = -4.0  # offset logvar
        self.scale_centre = float(torch.logit(torch.tensor(cfg.glimpse_ratio)))
        b[4:6] = self.scale_centre
        b[6:8] = -4.0
        b[9] = -4.0
        b[10] = cfg.logit_prior_extent
        b[11] = -4.0
        b[12:14] = 1.0  # Beta a, b ≈ softplus(1) + … ≈ 1.3 each: z_t ≈ 0.5 at the start
        b[14 + D :] = -4.0
        with torch.no_grad():
            self.head.bias.copy_(b)
        T = cfg.token_dim
        self.token = nn.Linear(hid + 7, T)
        self.film = nn.Linear(6, 2 * T)
        nn.init.zeros_(self.film.weight)
        nn.init.zeros_(self.film.bias)
        self.bg_token = nn.Linear(c, T)
        layer = nn.TransformerEncoderLayer(
            T, cfg.transformer_heads, 2 * T, dropout=0.0, batch_first=True, norm_first=True
        )
        self.transformer = (
            nn.TransformerEncoder(layer, cfg.transformer_layers, enable_nested_tensor=False)
            if cfg.transformer_layers > 0
            else None
        )
        self.refine = nn.Linear(T, 1 + D)
        nn.init.zeros_(self.refine.weight)
        nn.init.zeros_(self.refine.bias)

    def proposals(self, feats: Tensor) -> tuple[Tensor, Tensor]:
        """feats: (M, C, h, w) -> keypoints (M, Q, 2) in [-1, 1] (spatial-softmax means) and a presence logit
        (M, Q) per patch (Q = (resolution / kp_patch)^2)."""
        cfg = self.cfg
        P = cfg.kp_patch
        n = cfg.resolution // P
        out = self.heat(F.interpolate(feats, size=(n, n), mode="bilinear", align_corners=False))
        presence = out[:, -1].flatten(1)
        prob = out[:, :-1].flatten(2).transpose(1, 2).reshape(feats.shape[0], n * n, P * P).softmax(-1)
        ar = torch.arange(P, device=feats.device, dtype=feats.dtype) + 0.5
        gy, gx = torch.meshgrid(ar, ar, indexing="ij")
        local = torch.stack([gx, gy], dim=-1).reshape(P * P, 2)  # pixels within a patch
        mean = prob @ local
        cy, cx = torch.meshgrid(
            torch.arange(n, device=feats.device, dtype=feats.dtype) * P,
            torch.arange(n, device=feats.device, dtype=feats.dtype) * P,
            indexing="ij",
        )
        origin = torch.stack([cx, cy], dim=-1).reshape(1, n * n, 2)
        pix = origin + mean
        return pix / cfg.resolution * 2.0 - 1.0, presence

    def attributes(self, rgb: Tensor, dep: Tensor, rays: Tensor, residual: Tensor) -> tuple[ParticlePosterior, Tensor]:
        """Per-view particle posteriors before interaction.

        rgb: (M, 3, H, W); dep: (M, 2, H, W); rays: (M, 6, H, W); residual: (M, Q) per-patch error of the
        background alone (the keypoint selection's score)
        -> the posteriors (M, L, ·) and the glimpse embeddings h (M, L, C).
        """
        cfg = self.cfg
        L, D = cfg.particles_per_view, cfg.d_obj
        M = rgb.shape[0]
        feats = self.backbone(rgb, dep, rays)
        kp, presence = self.proposals(feats)
        # filter to L, with non-maximum suppression: where the background alone explains the view worst
        idx = select_keypoints(kp.detach(), -residual.detach(), L, cfg.kp_min_separation)
        kp = torch.gather(kp, 1, idx[..., None].expand(-1, -1, 2))  # (M, L, 2)
        presence = torch.gather(presence, 1, idx)[..., None]  # (M, L, 1)
        # glimpses of the RGB-D input around each keypoint (STN, bilinear)
        g = cfg.glimpse_ratio
        theta = torch.zeros(M * L, 2, 3, device=rgb.device, dtype=rgb.dtype)
        theta[:, 0, 0] = g
        theta[:, 1, 1] = g
        theta[:, :, 2] = kp.reshape(M * L, 2)
        src = torch.cat([rgb, dep], dim=1)
        grid = F.affine_grid(theta, [M * L, 5, cfg.glimpse_size, cfg.glimpse_size], align_corners=False)
        src_rep = src[:, None].expand(-1, L, -1, -1, -1).reshape(M * L, *src.shape[1:])
        glimpses = F.grid_sample(src_rep, grid, mode="bilinear", padding_mode="border", align_corners=False)
        at_kp = F.grid_sample(feats, kp[:, :, None, :], mode="bilinear", align_corners=False)[..., 0]
        h = torch.cat([self.glimpse_cnn(glimpses).flatten(1), at_kp.transpose(1, 2).reshape(M * L, -1)], dim=1)
        h = self.glimpse_fc(h)
        out = self.head(h).reshape(M, L, -1)
        # depth: a residual on the observed depth at the keypoint, when there is one
        obs = F.grid_sample(dep, kp[:, :, None, :], mode="nearest", align_corners=False)[..., 0].transpose(1, 2)
        d_obs = (obs[..., :1] * cfg.d_max - cfg.d_min) / (cfg.d_max - cfg.d_min)
        d_logit = torch.logit(d_obs.clamp(0.02, 0.98)) * obs[..., 1:2]
        shift = 0.5 * presence  # the proposal's presence logit seeds the transparency (learned through z_t)
        beta_ab = F.softplus(out[..., 12:14] + torch.cat([shift, -shift], dim=-1)) + 0.05
        post = ParticlePosterior(
            kp=kp,
            mu_o=cfg.offset_bound * torch.tanh(out[..., 0:2]),
            lv_o=out[..., 2:4],
            mu_s=self.scale_centre
            + cfg.scale_logit_bound * torch.tanh((out[..., 4:6] - self.scale_centre) / cfg.scale_logit_bound),
            lv_s=out[..., 6:8],
            mu_d=out[..., 8:9] + d_logit.detach(),
            lv_d=out[..., 9:10],
            mu_e=out[..., 10:11],
            lv_e=out[..., 11:12],
            beta_a=beta_ab[..., :1],
            beta_b=beta_ab[..., 1:],
            mu_f=out[..., 14 : 14 + D],
            lv_f=out[..., 14 + D :],
        )
        return post, h.reshape(M, L, -1)

    def interact(
        self, att: ParticlePosterior, h: Tensor, K: Tensor, c2w: Tensor, bg_feats: Tensor, n_views: int
    ) -> ParticlePosterior:
        """Ray-FiLM + particle-interaction transformer over all context views' particles and background tokens.

        att, h: output of :meth:`attributes` for M = B*V views; K: (M, 3, 3); c2w: (M, 4, 4);
        bg_feats: (M, C) pooled background features. Returns the posteriors with leading dims (B, V*L)
        (depth and feature means refined).
        """
        cfg = self.cfg
        L = cfg.particles_per_view
        M = K.shape[0]
        B = M // n_views
        pix = (att.kp + att.mu_o + 1.0) * 0.5 * cfg.resolution
        ray = plucker_at(pix.detach(), K, c2w)  # (M, L, 6)
        desc = torch.cat([h, att.mu_o, att.mu_s, att.mu_d, att.mu_e, att.t_mean()], dim=-1)
        tok = self.token(desc)
        T = tok.shape[-1]
        gamma_beta = self.film(ray)
        tok = (1.0 + gamma_beta[..., :T]) * tok + gamma_beta[..., T:]
        tok = tok.reshape(B, n_views * L, T)
        bg_tok = self.bg_token(bg_feats).reshape(B, n_views, T)
        if self.transformer is not None:
            tok = self.transformer(torch.cat([tok, bg_tok], dim=1))[:, : n_views * L]
        delta = self.refine(tok)
        out = ParticlePosterior(
            **{f.name: getattr(att, f.name).reshape(B, n_views * L, -1) for f in fields(ParticlePosterior)}
        )
        return out.replace(mu_d=out.mu_d + delta[..., :1], mu_f=out.mu_f + delta[..., 1:])


def select_keypoints(kp: Tensor, score: Tensor, count: int, min_separation: float) -> Tensor:
    """Filter proposals to ``count`` per view: lowest ``score`` first, skipping proposals closer than
    ``min_separation`` (normalised units, Chebyshev) to one already kept (greedy NMS); when too few are far
    enough apart the rest are the next lowest-score proposals.

    kp: (M, Q, 2) in [-1, 1]; score: (M, Q) -> (M, count) int64 proposal indices.
    """
    score = score.clone()
    chosen = []
    big = torch.finfo(score.dtype).max
    for _ in range(count):
        i = score.argmin(1)
        chosen.append(i)
        p = torch.gather(kp, 1, i[:, None, None].expand(-1, 1, 2))
        near = (kp - p).abs().amax(-1) < min_separation
        score = torch.where(near, score + 1e6, score)
        score.scatter_(1, i[:, None], big)
    return torch.stack(chosen, 1)


def box_mask(z_p: Tensor, scale: Tensor, active: Tensor, size: int) -> Tensor:
    """Union of particle boxes. z_p: (M, L, 2) in [-1, 1]; scale: (M, L, 2) half-extents in normalised
    units; active: (M, L) bool -> (M, 1, size, size) float mask (1 inside an active box)."""
    ar = (torch.arange(size, device=z_p.device, dtype=z_p.dtype) + 0.5) / size * 2.0 - 1.0
    inside_x = (ar[None, None, :] - z_p[..., 0:1]).abs() <= scale[..., 0:1]  # (M, L, W)
    inside_y = (ar[None, None, :] - z_p[..., 1:2]).abs() <= scale[..., 1:2]  # (M, L, H)
    box = inside_y[..., :, None] & inside_x[..., None, :] & active[..., None, None]
    return box.any(1, keepdim=True).to(z_p.dtype)


def covered_blocks(z_p: Tensor, z_s: Tensor, active: Tensor, view: Tensor, V: int, cfg: ModelConfig) -> Tensor:
    """The share of each per-view background block inside its view's active particles' boxes (the boxes
    :func:`box_mask` hides from the background encoder).

    z_p: (N, 2) in [-1, 1]; z_s: (N, 2) pre-sigmoid half-extents; active: (N,) bool; view: (N,) each particle's
    view in [0, V). Returns (V, Hb*Wb) in [0, 1]."""
    on = view[None, :] == torch.arange(V, device=view.device)[:, None]  # (V, N)
    boxes = box_mask(
        z_p[None].expand(V, -1, -1), torch.sigmoid(z_s)[None].expand(V, -1, -1), on & active[None], cfg.resolution
    )
    return F.avg_pool2d(boxes, cfg.bg_block).flatten(1)


class BackgroundEncoder(nn.Module):
    """q(z_bg | view): masked RGB-D + rays -> latent map (d_bg, H/stride, W/stride) (mean, logvar)."""

    def __init__(self, cfg: ModelConfig):
        super().__init__()
        self.cfg = cfg
        self.backbone = FusedBackbone(cfg, extra_in=1)
        c = self.backbone.out_channels
        self.head = nn.Conv2d(c, 2 * cfg.d_bg, 3, padding=1)
        with torch.no_grad():
            conv_bias(self.head)[cfg.d_bg :] = -4.0

    def forward(self, rgb: Tensor, dep: Tensor, rays: Tensor, mask: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """rgb: (M, 3, H, W); dep: (M, 2, H, W); rays: (M, 6, H, W); mask: (M, 1, H, W) 1 = hidden.

        Returns mean, logvar (M, d_bg, H/s, W/s) and pooled features (M, C) for the background tokens.
        """
        keep = 1.0 - mask
        feats = self.backbone(torch.cat([rgb * keep, mask], dim=1), dep * keep, rays)
        out = self.head(feats)
        s = self.cfg.bg_latent_stride
        n = self.cfg.resolution // s
        if out.shape[-1] != n:
            out = (
                F.interpolate(out, size=(n, n), mode="bilinear", align_corners=False)
                if n > out.shape[-1]
                else F.adaptive_avg_pool2d(out, n)
            )
        d = self.cfg.d_bg
        return out[:, :d], out[:, d:], feats.mean((2, 3))


__all__ = ["ParticleEncoder", "BackgroundEncoder", "box_mask", "depth_input", "plucker_map"]
