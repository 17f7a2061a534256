"""The ParticleSplat model: encoder, decoders, and the scene-level API used by the viewer."""

from __future__ import annotations

from dataclasses import fields, replace

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from particlesplat.core.camera import Camera
from particlesplat.core.gaussians import BACKGROUND_OWNER, Gaussians
from particlesplat.core.panda_arm import ARM_STATE_KEY
from particlesplat.core.sh import SH_C0
from particlesplat.model.backdrop import views_backdrop
from particlesplat.model.config import ModelConfig, config_to_dict
from particlesplat.model.decoder import (
    UNDER_OBJECT_PIXELS,
    BackgroundDecoder,
    ForegroundDecoder,
    background_gaussians,
    background_rays,
    block_anchors,
    cell_pixels,
    foreground_gaussians,
    masked_block_mean,
    split_gaussian_params,
)
from particlesplat.model.encoder import BackgroundEncoder, ParticleEncoder, box_mask, covered_blocks, depth_input
from particlesplat.model.evidence import canonical_turn, dilate, foreground_evidence
from particlesplat.model.geometry import plucker_map, stack_cameras
from particlesplat.model.particles import Particles
from particlesplat.model.posterior import ParticlePosterior, Posterior
from particlesplat.model.refiner import BOX_MARGIN, Refiner, box_glimpses, latent_vector
from particlesplat.model.static_background import StaticBackground, WorkspaceBackground
from particlesplat.model.support_map import CELLS as SUPPORT_CELLS
from particlesplat.model.support_map import support_at, support_map_image, views_support_map
from particlesplat.rendering.api import render_batch
from particlesplat.rendering.layers import composite_over, pool_layer, render_layer


def _gaussians(fields: dict[str, Tensor], owner: Tensor) -> Gaussians:
    n = owner.shape[0]
    return Gaussians(
        fields["means"].reshape(n, 3),
        fields["quats"].reshape(n, 4),
        fields["scales"].reshape(n, 3),
        fields["opacities"].reshape(n),
        fields["sh"].reshape(n, -1, 3),
        owner,
    )


def layer_error(layer: Tensor, x: Tensor, depth: Tensor | None, block: int) -> Tensor:
    """Per-block error of a rendered layer (M, 5, H, W) against the views x (M, 3, H, W) and depth (M, 1, H, W)
    metres (0 = none) or None: per pixel squared RGB error + squared depth error in metres where depth is known
    (a pixel the layer leaves empty renders depth 0), averaged over ``block``² blocks -> (M, 1, Hb, Wb)."""
    err = ((layer[:, :3] - x) ** 2).sum(1, keepdim=True)
    if depth is not None:
        err = err + (layer[:, 3:4] - depth) ** 2 * (depth > 0).to(x.dtype)
    return F.avg_pool2d(err, block)


EVIDENCE_DILATION = 2
"""Pixels by which the foreground evidence grows before the background encoder's mask hides it: an object's rim
just above the table, below the evidence's height threshold, must not show the background its colour."""


class ParticleSplat(nn.Module):
    """Encoder q(Z | context views) and Gaussian-splatting decoder p(x | Z)."""

    def __init__(self, config: ModelConfig):
        super().__init__()
        config.validate()
        self.config = config
        # per robot input (a scene.json pose key): {"min": [...], "max": [...]} over the training scenes
        # (particlesplat.data.pose_ranges); saved with the checkpoint, None when not recorded
        self.input_ranges: dict[str, dict[str, list[float]]] | None = None
        self.encoder = ParticleEncoder(config)
        self.bg_encoder = BackgroundEncoder(config)
        self.fg_decoder = ForegroundDecoder(config)
        # the per-view background decoder exists only where it draws (a module without gradients breaks DDP)
        self.bg_decoder = BackgroundDecoder(config) if config.bg_per_view else None
        self.static_bg: StaticBackground | WorkspaceBackground | None = None
        if config.bg_static_grid > 0:
            self.static_bg = StaticBackground(config)
        elif config.bg_static_points > 0:
            self.static_bg = WorkspaceBackground(config)
        self.refiner = Refiner(config) if config.refine_steps > 0 else None
        # training switches the refinement on at ``train.refine_start``; off, encode returns the first look
        self.refine_enabled = True
        # one colour behind all Gaussians, learned (sigmoid of 3 logits; near black at the start)
        self.background_logit = nn.Parameter(torch.full((3,), -3.0))

    def background_color(self) -> Tensor:
        """(3,) RGB in [0, 1] rendered behind the Gaussians: the learned background colour."""
        return torch.sigmoid(self.background_logit)

    def backdrop(self, particles: Particles | None = None) -> Tensor:
        """(3,) RGB in [0, 1] behind a scene's Gaussians: the colour its particles read from their context views
        (``background.colour_from_views``), else the learned background colour."""
        if particles is not None and particles.backdrop is not None:
            return particles.backdrop.to(self.background_logit.device)
        return self.background_color()

    def backdrop_image(self, particles: Particles | None, camera: Camera) -> Tensor:
        """What ``camera`` sees behind a scene's Gaussians: (H, W, 3) RGB in [0, 1] where its particles carry a
        support map (``background.support_map``: :func:`~particlesplat.model.support_map.support_map_image` over
        :meth:`backdrop`), else :meth:`backdrop`'s (3,) colour. On the model's device."""
        colour = self.backdrop(particles)
        if particles is None or particles.support_map is None:
            return colour
        return support_map_image(particles.support_map.to(colour.device), colour, camera)

    def _table_fill(self, particles: Particles) -> tuple[Tensor, Tensor | None]:
        """Where ``background.opaque_under_objects`` draws no table, and in what colour it draws it: (V, Hb*Wb) in
        [0, 1] per background block, the share inside its view's active particles' boxes
        (:func:`~particlesplat.model.encoder.covered_blocks`), or 1 where the block's ray meets the support plane
        off the support (the floor past the table's edge, by the scene's support map); and (V, Hb*Wb, 3) the
        support map's colour where its ray meets the plane, or None without a map (the table's median colour)."""
        p, cfg = particles, self.config
        covered = self._covered_blocks(p)
        if p.support_map is None:
            return covered, None
        maps = p.support_map.to(covered)
        rgb, on = zip(*(support_at(maps, cam) for cam in p.cameras), strict=True)  # (H, W, 3), (H, W) a view
        off = F.avg_pool2d((torch.stack(on) <= 0.5).to(covered)[:, None], cfg.bg_block).flatten(1)
        colour = F.avg_pool2d(torch.stack(rgb).permute(0, 3, 1, 2), cfg.bg_block).flatten(2).transpose(1, 2)
        return torch.maximum(covered, off), colour

    def table_fill_key(self, particles: Particles) -> Tensor | None:
        """What of the particles the background's decode depends on (``background.opaque_under_objects``): (V,
        Hb*Wb) bool, the blocks under an object (anchor channel 5) that no active particle's box covers any longer,
        which :meth:`_table_fill` draws as the table; None for a model without the key (its background does not
        depend on the particles). Two decodes with equal keys give the same background, however far the boxes moved
        (an editor decodes it again only when the key changes)."""
        cfg = self.config
        if not cfg.bg_opaque_under_objects or int(particles.background.shape[1]) < cfg.d_bg + 6:
            return None
        covered = self._covered_blocks(particles)
        under = particles.background[:, cfg.d_bg + 5].flatten(1).to(covered) > 0.5
        return (under & (covered <= 0.5)).detach().cpu()

    def _covered_blocks(self, p: Particles) -> Tensor:
        """(V, Hb*Wb) the share of each background block inside its view's active particles' boxes
        (:func:`~particlesplat.model.encoder.covered_blocks`)."""
        cfg = self.config
        return covered_blocks(p.z_p, p.z_s, p.z_t[:, 0] > cfg.bg_mask_threshold, p.view, len(p.cameras), cfg)

    def views_support_map(
        self,
        rgb: Tensor,
        depth: Tensor | None,
        K: Tensor,
        c2w: Tensor,
        pose: Tensor | None = None,
        evidence: Tensor | None = None,
    ) -> Tensor | None:
        """What :attr:`Particles.support_map` holds for one scene's context views (shapes as in
        :meth:`views_backdrop`; pose (D,) the scene's robot state or None): with ``background.support_map``,
        :func:`~particlesplat.model.support_map.views_support_map`, which with ``background.opaque_under_objects``
        leaves out the pixels within :data:`EVIDENCE_DILATION` of an object's evidence (its foot would
        colour the table an edit uncovers); else None. ``evidence``: the views' object evidence (V, 1, H, W) where
        the encoder has computed it already (:meth:`views_evidence`), else computed here."""
        cfg = self.config
        if not cfg.bg_support_map:
            return None
        hidden = None
        if cfg.bg_opaque_under_objects and depth is not None:
            if evidence is None:
                arm = None if pose is None else pose[None].expand(depth.shape[0], -1)
                evidence = foreground_evidence(depth.to(K.dtype), K, c2w, arm)
            hidden = dilate(evidence.to(K.dtype), EVIDENCE_DILATION)
        return views_support_map(rgb, depth, K, c2w, hidden)

    def views_evidence(self, post: Posterior, b: int) -> Tensor | None:
        """Scene ``b``'s context views' object evidence (V, 1, H, W) as :meth:`posterior` computed it (its
        ``bg_error`` with ``fg_evidence``), to carry into :meth:`views_support_map`; None without it."""
        return post.bg_error[b] if self.config.fg_evidence else None

    def views_backdrop(self, rgb: Tensor, depth: Tensor | None, K: Tensor, c2w: Tensor) -> Tensor | None:
        """What :attr:`Particles.backdrop` holds for one scene's context views (rgb (V, 3, H, W), depth
        (V, 1, H, W) or None, K (V, 3, 3), c2w (V, 4, 4)): :func:`~particlesplat.model.backdrop.views_backdrop`
        with ``background.colour_from_views``, else None."""
        if not self.config.bg_colour_from_views:
            return None
        return views_backdrop(rgb, depth, K, c2w)

    def _bg_decoder(self) -> BackgroundDecoder:
        """The per-view background decoder: only a model with ``bg_per_view`` has one."""
        if self.bg_decoder is None:
            raise ValueError("this model has no per-view background decoder (background.per_view is false)")
        return self.bg_decoder

    # ------------------------------------------------------------------ batched internals
    def posterior(
        self, rgb: Tensor, depth: Tensor | None, K: Tensor, c2w: Tensor, pose: Tensor | None = None
    ) -> Posterior:
        """Posterior parameters for B scenes with V context views.

        rgb: (B, V, 3, H, W) in [0, 1]; depth: (B, V, 1, H, W) metres (0 = missing) or None;
        K: (B, V, 3, 3); c2w: (B, V, 4, 4) OpenCV; pose: (B, D) the scenes' poses the workspace layer follows
        (``bg_static_pose``; None: its mean pose). Returns the :class:`Posterior`: particle posteriors
        (B, V*L, ·), the view index (V*L,), background mean/logvar (B, V, d_bg, h, w), the background mask
        (B, V, 1, H, W) and the background's own error per pixel, ``bg_error`` (B, V, 1, H, W): the static layer's
        (``bg_static_grid``) per pixel, else the per-view background's per ``bg_block``² block.
        """
        cfg = self.config
        B, V = rgb.shape[:2]
        H, W = rgb.shape[-2:]
        if H != cfg.resolution or W != cfg.resolution:
            raise ValueError(f"images are {W}x{H}, the model was built for {cfg.resolution}x{cfg.resolution}")
        x = rgb.reshape(B * V, 3, H, W)
        d = None if depth is None else depth.reshape(B * V, 1, H, W)
        dep = depth_input(d, x, cfg)
        Kf, cf = K.reshape(B * V, 3, 3), c2w.reshape(B * V, 4, 4)
        # the network reads rays in a frame turned to face the context cameras (canonical_frame): a turn of the
        # world about z leaves its inputs as they were; the Gaussians are placed with the real cameras
        cn = (canonical_turn(c2w)[:, None] @ c2w).reshape(B * V, 4, 4) if cfg.canonical_frame else cf
        rays = plucker_map(Kf, cn, H, W)
        # what the background alone explains badly (or, with fg_evidence, what stands on the table and is not
        # the arm): the keypoints go there
        static = None
        evidence = None
        if cfg.fg_evidence:
            if d is None:
                raise ValueError("this model reads objects from depth (fg_evidence): the scene needs depth maps")
            evidence = foreground_evidence(d, Kf, cf, None if pose is None else pose.repeat_interleave(V, 0))
            pixel_err = evidence
            block_err = F.avg_pool2d(evidence, cfg.bg_block)
        elif self.static_bg is not None:
            static = self.static_layer(Kf, cf, W, H, None if pose is None else pose.repeat_interleave(V, 0))
            pixel_err = layer_error(static, x, d, block=1)
            block_err = F.avg_pool2d(pixel_err, cfg.bg_block)
        else:
            with torch.no_grad():
                block_err = self.coarse_background_error(x, d, dep, rays, Kf, cf)
            pixel_err = F.interpolate(block_err, scale_factor=cfg.bg_block, mode="nearest")
        residual = F.adaptive_avg_pool2d(block_err, cfg.resolution // cfg.kp_patch).flatten(1)
        att, h = self.encoder.attributes(x, dep, rays, residual)
        with torch.no_grad():
            t_mean = att.t_mean()
            boxes = box_mask(
                att.kp + att.mu_o,
                torch.sigmoid(att.mu_s),
                t_mean[..., 0] > cfg.bg_mask_threshold,
                cfg.resolution,
            )
            mask = boxes
            if evidence is not None:  # the background never sees an object, whether a particle took it or not
                mask = torch.maximum(mask, dilate(evidence, EVIDENCE_DILATION))
        mu_bg, lv_bg, bg_feats = self.bg_encoder(x, dep, rays, mask)
        part = self.encoder.interact(att, h, Kf, cn, bg_feats, V)
        anchor = None
        if evidence is not None:  # under an object: near its evidence, in a particle's box
            anchor = block_anchors(x, d, mask, cfg.bg_block, dilate(evidence, UNDER_OBJECT_PIXELS) * boxes)
        return Posterior(
            **{f.name: getattr(part, f.name) for f in fields(ParticlePosterior)},
            mu_bg=mu_bg.reshape(B, V, *mu_bg.shape[1:]),
            lv_bg=lv_bg.reshape(B, V, *lv_bg.shape[1:]),
            bg_mask=mask.reshape(B, V, 1, H, W),
            view=torch.arange(V, device=rgb.device).repeat_interleave(cfg.particles_per_view),
            bg_error=pixel_err.reshape(B, V, 1, H, W),
            static_layer=None if static is None else static.reshape(B, V, 5, H, W),
            pose=pose,
            bg_anchor=None if anchor is None else anchor.reshape(B, V, *anchor.shape[1:]),
        )

    def coarse_background_error(
        self, x: Tensor, depth: Tensor | None, dep: Tensor, rays: Tensor, K: Tensor, c2w: Tensor
    ) -> Tensor:
        """Per-block error of the plain background (unmasked input, no detail features).

        x: (M, 3, H, W); depth: (M, 1, H, W) metres or None; dep, rays: encoder inputs; K: (M, 3, 3);
        c2w: (M, 4, 4). Compares each background Gaussian's colour and planar depth with its pixel block
        (squared RGB error + squared depth error in metres where depth is known). Returns (M, 1, Hb, Wb).
        """
        cfg = self.config
        M = x.shape[0]
        mu, _, _ = self.bg_encoder(x, dep, rays, torch.zeros_like(x[:, :1]))
        p = split_gaussian_params(self._bg_decoder()(mu, background_rays(K, c2w, cfg)), cfg.sh_degree)
        nb = cfg.resolution // cfg.bg_block
        colour = (SH_C0 * p["sh"][..., 0, :] + 0.5).clamp(0, 1).transpose(1, 2).reshape(M, 3, nb, nb)
        err = ((colour - F.avg_pool2d(x, cfg.bg_block)) ** 2).sum(1, keepdim=True)
        if depth is not None:
            d_blk, w = masked_block_mean(depth, (depth > 0).to(x.dtype), cfg.bg_block)
            zeta = cfg.depth_of(p["dd"][..., 0])
            err = err + (zeta.reshape(M, 1, nb, nb) - d_blk) ** 2 * (w > 0.5).to(x.dtype)
        return err

    @torch.no_grad()
    def static_background_error(
        self,
        x: Tensor,
        depth: Tensor | None,
        K: Tensor,
        c2w: Tensor,
        block: int | None = None,
        pose: Tensor | None = None,
    ) -> Tensor:
        """Per-block error (:func:`layer_error`, ``block`` default ``bg_block``) of the static background layer
        alone rendered into M views (no gradient): x (M, 3, H, W); depth (M, 1, H, W) metres (0 = none) or None;
        K (M, 3, 3); c2w (M, 4, 4); pose (M, D) or None (:meth:`static_layer`) -> (M, 1, Hb, Wb). An object in
        front of the floor and the floor where the layer is transparent both count."""
        H, W = x.shape[-2:]
        return layer_error(self.static_layer(K, c2w, W, H, pose), x, depth, block or self.config.bg_block)

    @torch.no_grad()
    def static_layer(self, K: Tensor, c2w: Tensor, width: int, height: int, pose: Tensor | None = None) -> Tensor:
        """The static background layer alone rendered into M views over the background colour (no gradient):
        K (M, 3, 3), c2w (M, 4, 4), pose (M, D) the pose of each view's scene (``bg_static_pose``; None: the
        layer's mean pose) -> layers (M, 5, height, width) (:mod:`particlesplat.rendering.layers`)."""
        if self.static_bg is None:
            raise ValueError(
                "this model has no static background layer (background.static_grid and background.static_points are 0)"
            )
        owner = torch.full((self.static_bg.num,), BACKGROUND_OWNER, device=K.device)
        M = K.shape[0]
        if self.follows_pose and pose is not None:
            moved = self.static_fields(M, pose)
            sets = [_gaussians({k: v[i] for k, v in moved.items()}, owner) for i in range(M)]
        else:
            sets = [_gaussians(self.static_bg(), owner)] * M
        res = render_batch(
            [(sets[i], Camera(K[i], c2w[i], width, height)) for i in range(M)], background=self.background_color()
        )
        return torch.stack([render_layer(r.rgb, r.depth, r.alpha) for r in res])

    def refine(self, post: Posterior, rgb: Tensor, depth: Tensor | None, K: Tensor, c2w: Tensor) -> Posterior:
        """``refine_steps`` amortised corrections of the particle posterior means (:mod:`.refiner`).

        Each step decodes the current means and renders the context views (no gradient; at ``refine_scale`` of
        their resolution, each particle's ``refine_keep`` most opaque Gaussians; with ``refine_static`` behind,
        the particles alone over the posterior's render of the static layer, pooled), then every particle compares
        render and observation inside its box (enlarged by :data:`BOX_MARGIN`, ``glimpse_size`` pixels across)
        in its own view. post: from :meth:`posterior`; rgb: (B, V, 3, H, W); depth: (B, V, 1, H, W) metres or
        None; K: (B, V, 3, 3); c2w: (B, V, 4, 4). Returns the posterior with refined means (the same fields and
        shapes).
        """
        if self.refiner is None or not self.refine_enabled:
            return post
        cfg = self.config
        B, V = rgb.shape[:2]
        H, W = rgb.shape[-2:]
        h, w = round(H * cfg.refine_scale), round(W * cfg.refine_scale)
        view = post.view
        N = view.shape[0]
        observed = torch.cat(
            [
                rgb,
                depth_input(None if depth is None else depth.flatten(0, 1), rgb.flatten(0, 1), cfg).reshape(
                    B, V, 2, H, W
                ),
            ],
            dim=2,
        )[:, view]  # (B, N, 5, H, W)
        # a view's render weighs only its own particles (owner: rank among them, -1 elsewhere), so the rasterizer
        # carries one weight column per particle of the busiest view instead of one per particle
        rank = (view[:, None] == view[None, :]).tril(-1).sum(1)  # (N,) each particle's rank in its own view
        P = int(rank.max()) + 1 if N else 1
        slot = [torch.where(view == v, rank, -1) for v in range(V)]  # per view: particle -> owner slot
        behind = None
        if cfg.refine_static == "behind":
            if post.static_layer is None:
                raise ValueError("refine.static behind: the posterior holds no render of the static layer")
            behind = pool_layer(post.static_layer.flatten(0, 1), (h, w))
        for _ in range(cfg.refine_steps):
            with torch.no_grad():
                z = self.latents(self.with_colour_anchors(post, rgb), sample=False)
                gaussians = self.decode_batch(
                    z, view, K, c2w, background=behind is None, max_per_particle=cfg.refine_keep, pose=post.pose
                )
                res = render_batch(
                    [
                        (
                            replace(g, owner=torch.where(g.owner >= 0, slot[v][g.owner.clamp_min(0)], g.owner)),
                            Camera(K[b, v], c2w[b, v], W, H).resized(w, h),
                        )
                        for b, g in enumerate(gaussians)
                        for v in range(V)
                    ],
                    background=self.background_color() if behind is None else (0.0, 0.0, 0.0),
                    owner_weights=True,
                    num_owners=P,
                )
                layers = torch.stack([render_layer(r.rgb, r.depth, r.alpha) for r in res])  # (B * V, 5, h, w)
                if behind is not None:
                    layers = composite_over(layers, behind)
                layers[:, 3] /= cfg.d_max
                rendered = layers.reshape(B, V, 5, h, w)[:, view]
                weights = torch.stack([r.require_owner_weights() for r in res]).reshape(B, V, P, h, w)
                own = weights[:, view, rank][:, :, None]  # (B, N, 1, h, w)
                centre = z["z_p"].reshape(B * N, 2)
                half = BOX_MARGIN * torch.sigmoid(z["z_s"]).reshape(B * N, 2)
            # box coordinates are normalised ([-1, 1] over the image), so both sizes sample the same box
            seen = box_glimpses(observed.reshape(B * N, -1, H, W), centre, half, cfg.glimpse_size)
            drawn = box_glimpses(
                torch.cat([rendered, own], dim=2).reshape(B * N, -1, h, w), centre, half, cfg.glimpse_size
            )
            glimpses = torch.cat([seen, drawn], dim=1)  # (B * N, 11, glimpse_size, glimpse_size)
            delta = self.refiner(glimpses, latent_vector(post).reshape(B * N, -1)).reshape(B, N, -1)
            post = self.refiner.corrected(post, delta, self.encoder.scale_centre)
        return post

    def encode_posterior(
        self, rgb: Tensor, depth: Tensor | None, K: Tensor, c2w: Tensor, pose: Tensor | None = None
    ) -> Posterior:
        """The posterior of B scenes as encode and training use it (shapes as in :meth:`posterior`): refined
        (:meth:`refine`), with the colours under the particles' cells (:meth:`with_colour_anchors`)."""
        post = self.refine(self.posterior(rgb, depth, K, c2w, pose), rgb, depth, K, c2w)
        return self.with_colour_anchors(post, rgb)

    def with_colour_anchors(self, post: Posterior, rgb: Tensor) -> Posterior:
        """``post`` with ``colour_anchor`` (``patch.colour_anchor``; else ``post`` as it is): each particle's cells'
        colours in its context view, (B, N, 2*S*S*3) (front cells, then the back cells with the same colours),
        sampled bilinearly at the cells' centres under the posterior means of ``z_p`` and ``z_s``. The colours are
        kept with the particle (in ``z_f``, after its ``d_obj`` features), so an edit moves them with it.
        rgb: (B, V, 3, H, W) the context views."""
        cfg = self.config
        if not cfg.patch_colour_anchor:
            return post
        B, N = post.kp.shape[:2]
        H, W = rgb.shape[-2:]
        S = cfg.patch_gaussians
        z_p = (post.kp + post.mu_o).reshape(B * N, 2)
        pix = cell_pixels(z_p, post.mu_s.reshape(B * N, 2), S, (W, H))  # (B*N, S*S, 2)
        grid = (pix / torch.tensor([W, H], device=pix.device, dtype=pix.dtype) * 2.0 - 1.0)[:, :, None, :]
        images = rgb[:, post.view].reshape(B * N, 3, H, W)
        colours = F.grid_sample(images, grid.detach(), mode="bilinear", padding_mode="border", align_corners=False)
        colours = colours[..., 0].transpose(1, 2)  # (B*N, S*S, 3)
        return replace(post, colour_anchor=torch.cat([colours, colours], dim=1).reshape(B, N, -1).detach())

    @staticmethod
    def latents(post: Posterior, sample: bool) -> dict[str, Tensor]:
        """Posterior samples (reparameterised) or means: z_p, z_s, z_d, z_e, z_t, z_f (B, N, ·), bg (B, V, ·)."""

        def g(mu: Tensor, lv: Tensor) -> Tensor:
            return mu + torch.randn_like(mu) * torch.exp(0.5 * lv) if sample else mu

        a, b = post.beta_a, post.beta_b
        z_t = torch.distributions.Beta(a, b).rsample() if sample else a / (a + b)
        bg = g(post.mu_bg, post.lv_bg)
        if post.bg_anchor is not None:  # an anchored background's latent carries its anchors (fg_evidence)
            bg = torch.cat([bg, post.bg_anchor], dim=2)
        return {
            "z_p": post.kp + g(post.mu_o, post.lv_o),
            "z_s": g(post.mu_s, post.lv_s),
            "z_d": g(post.mu_d, post.lv_d),
            "z_e": g(post.mu_e, post.lv_e),
            "z_t": z_t,
            # the colours under the cells, when the model keeps them (patch.colour_anchor), follow the features
            "z_f": g(post.mu_f, post.lv_f)
            if post.colour_anchor is None
            else torch.cat([g(post.mu_f, post.lv_f), post.colour_anchor], dim=-1),
            "bg": bg,
        }

    def foreground(
        self,
        z_p: Tensor,
        z_s: Tensor,
        z_d: Tensor,
        z_e: Tensor,
        z_t: Tensor,
        z_f: Tensor,
        K: Tensor,
        c2w: Tensor,
        keep: int = 0,
        support: Tensor | None = None,
    ) -> dict[str, Tensor]:
        """M particles -> Gaussian fields (M, 2*S*S, ·): the front Gaussians, then the back layer. Latents (M, ·);
        K (M, 3, 3), c2w (M, 4, 4) of their views. ``keep`` = k > 0: each particle's k most opaque (M, k, ·).
        ``support`` (M,): the height of the surface under each particle (None: the shared SUPPORT_Z)."""
        d = self.config.d_obj
        anchor = z_f[:, d:].reshape(z_f.shape[0], -1, 3) if z_f.shape[-1] > d else None
        raw = self.fg_decoder(z_f[:, :d])
        return foreground_gaussians(raw, z_p, z_s, z_d, z_e, z_t, K, c2w, self.config, keep, anchor, support)

    def background(
        self,
        bg: Tensor,
        K: Tensor,
        c2w: Tensor,
        c2w_net: Tensor | None = None,
        covered: Tensor | None = None,
        fill_colour: Tensor | None = None,
    ) -> dict[str, Tensor]:
        """bg: (M, d_bg, h, w) latents of M views (with ``fg_evidence``, (M, d_bg + 6, h, w): the latents, then the
        blocks' anchors); K (M, 3, 3), c2w (M, 4, 4); c2w_net (M, 4, 4): the cameras as the network reads them
        (``canonical_frame``; default c2w); covered (M, Hb*Wb): the share of each block inside its view's active
        particles' boxes (:func:`~particlesplat.model.encoder.covered_blocks`, ``background.opaque_under_objects``)
        or None; fill_colour (M, Hb*Wb, 3) the table's colour under each block or None -> fields (M, Hb*Wb, ·)."""
        cfg = self.config
        anchor = None
        if cfg.fg_evidence:
            bg, anchor = bg[:, : cfg.d_bg], bg[:, cfg.d_bg :].flatten(2).transpose(1, 2)
        raw = self._bg_decoder()(bg, background_rays(K, c2w if c2w_net is None else c2w_net, cfg))
        return background_gaussians(raw, K, c2w, cfg, anchor, covered, fill_colour)

    def batch_pose(self, poses: list[Tensor | None], device: torch.device) -> Tensor | None:
        """The scenes' poses (each (D,) or None: the layer's mean pose) as the batch (B, D) the layer reads, on
        ``device``; None for a model whose layer follows no pose. ValueError for a pose of another length."""
        layer = self.static_bg
        if self.config.fg_evidence and self.config.bg_static_pose == ARM_STATE_KEY:
            # the robot state the evidence reads to leave the arm out; without it for every scene, nothing is
            if any(pose is None for pose in poses):
                return None
            return torch.stack([pose.to(device=device, dtype=torch.float32) for pose in poses])  # type: ignore[union-attr]
        if not (isinstance(layer, WorkspaceBackground) and layer.pose_dims > 0):
            return None
        for pose in poses:
            if pose is not None and tuple(pose.shape) != (layer.pose_dims,):
                raise ValueError(
                    f"pose: {self.config.bg_static_pose} must hold {layer.pose_dims} numbers, got {tuple(pose.shape)}"
                )
        rows = [layer.pose_mean if pose is None else pose.to(layer.pose_mean) for pose in poses]
        return torch.stack(rows).to(device)

    @property
    def follows_pose(self) -> bool:
        """The workspace layer follows a per-scene pose (``bg_static_pose``)."""
        return isinstance(self.static_bg, WorkspaceBackground) and self.static_bg.pose_dims > 0

    def static_fields(self, B: int, pose: Tensor | None = None) -> dict[str, Tensor]:
        """The static layer's Gaussian fields for B scenes (B, N, ·); pose (B, D) or None (the mean pose) moves
        a workspace layer that follows one (:attr:`follows_pose`)."""
        if self.static_bg is None:
            raise ValueError(
                "this model has no static background layer (background.static_grid and background.static_points are 0)"
            )
        if isinstance(self.static_bg, WorkspaceBackground) and self.follows_pose and pose is not None:
            return self.static_bg(pose)
        return {k: v[None].expand(B, *v.shape) for k, v in self.static_bg().items()}

    def background_fields(
        self,
        bg: Tensor,
        K: Tensor,
        c2w: Tensor,
        pose: Tensor | None = None,
        fill: tuple[Tensor, Tensor | None] | None = None,
    ) -> dict[str, Tensor]:
        """Background Gaussians of B scenes: the per-view background (``bg_per_view``) then the static layer
        (``bg_static_grid``, ``bg_static_points``). bg: (B, V, C, h, w) latents; K: (B, V, 3, 3); c2w: (B, V, 4, 4);
        pose: (B, D) or None (:meth:`static_fields`); fill: where and in what colour the table under a moved
        object is drawn (``background.opaque_under_objects``: (B, V, Hb*Wb) and (B, V, Hb*Wb, 3) or None,
        :meth:`_table_fill`), or None -> fields (B, N_bg, ·)."""
        B, V = K.shape[:2]
        parts = []
        if self.config.bg_per_view:
            net = (canonical_turn(c2w)[:, None] @ c2w).reshape(B * V, 4, 4) if self.config.canonical_frame else None
            f = self.background(
                bg.reshape(B * V, *bg.shape[2:]),
                K.reshape(B * V, 3, 3),
                c2w.reshape(B * V, 4, 4),
                net,
                None if fill is None else fill[0].reshape(B * V, -1),
                None if fill is None or fill[1] is None else fill[1].reshape(B * V, -1, 3),
            )
            parts.append({k: v.reshape(B, -1, *v.shape[2:]) for k, v in f.items()})
        if self.static_bg is not None:
            parts.append(self.static_fields(B, pose))
        return {k: torch.cat([p[k] for p in parts], dim=1) for k in parts[0]}

    def decode_batch(
        self,
        z: dict[str, Tensor],
        view: Tensor,
        K: Tensor,
        c2w: Tensor,
        background: bool = True,
        max_per_particle: int = 0,
        pose: Tensor | None = None,
    ) -> list[Gaussians]:
        """Decode B scenes. z: from :meth:`latents`; view: (N,) particle views;
        K: (B, V, 3, 3); c2w: (B, V, 4, 4) of the context views; pose: (B, D) or None (:meth:`static_fields`).
        Returns B Gaussian sets (owner = particle).
        ``max_per_particle`` k > 0: each particle keeps its k most opaque Gaussians (as :meth:`decode`)."""
        B, N = z["z_p"].shape[:2]
        flat = {k: z[k].reshape(B * N, -1) for k in ("z_p", "z_s", "z_d", "z_e", "z_t", "z_f")}
        Kp = K[:, view].reshape(B * N, 3, 3)
        cp = c2w[:, view].reshape(B * N, 4, 4)
        fg = self.foreground(
            flat["z_p"], flat["z_s"], flat["z_d"], flat["z_e"], flat["z_t"], flat["z_f"], Kp, cp, max_per_particle
        )
        per = fg["opacities"].shape[1]
        fg = {k: v.reshape(B, -1, *v.shape[2:]) for k, v in fg.items()}
        owner_fg = torch.arange(N, device=K.device).repeat_interleave(per)
        if background:
            bgf = self.background_fields(z["bg"], K, c2w, pose)
            owner = torch.cat([owner_fg, torch.full((bgf["means"].shape[1],), BACKGROUND_OWNER, device=K.device)])
            fields = {k: torch.cat([fg[k], bgf[k]], dim=1) for k in fg}
        else:
            owner, fields = owner_fg, fg
        return [_gaussians({k: v[b] for k, v in fields.items()}, owner) for b in range(B)]

    def forward(
        self,
        rgb: Tensor,
        depth: Tensor | None,
        K: Tensor,
        c2w: Tensor,
        sample: bool = True,
        background: bool = True,
        pose: Tensor | None = None,
    ) -> tuple[Posterior, dict[str, Tensor], list[Gaussians]]:
        """Training pass for B scenes (shapes as in :meth:`posterior`): posterior, latents (with the background
        colour to render behind the Gaussians, ``bg_color`` (3,), computed here so that under DDP every weight
        is used inside the forward pass, with ``background.colour_from_views`` each scene's own, ``backdrop``
        (B, 3), and with ``background.support_map`` each scene's map, ``support_map`` (B, 4, N, N), support share 0
        for a scene without one), Gaussians per scene."""
        post = self.encode_posterior(rgb, depth, K, c2w, pose)
        z = self.latents(post, sample)
        z["bg_color"] = self.background_color()
        if self.config.bg_colour_from_views:  # (B, 3): each scene's colour from its views, else the learned one
            read = [
                self.views_backdrop(rgb[b], None if depth is None else depth[b], K[b], c2w[b]) for b in range(len(rgb))
            ]
            z["backdrop"] = torch.stack([z["bg_color"] if c is None else c.to(z["bg_color"]) for c in read])
        if self.config.bg_support_map:
            depths = [None if depth is None else depth[b] for b in range(len(rgb))]
            poses = [None if post.pose is None else post.pose[b] for b in range(len(rgb))]
            maps = [
                self.views_support_map(rgb[b], depths[b], K[b], c2w[b], poses[b], self.views_evidence(post, b))
                for b in range(len(rgb))
            ]
            empty = z["bg_color"].new_zeros(4, SUPPORT_CELLS, SUPPORT_CELLS)
            z["support_map"] = torch.stack([empty if m is None else m.to(empty) for m in maps])
        return post, z, self.decode_batch(z, post.view, K, c2w, background, pose=post.pose)

    # ------------------------------------------------------------------ scene-level API
    @torch.no_grad()
    def encode(self, rgb: Tensor, depth: Tensor | None, cameras: list[Camera], pose: Tensor | None = None) -> Particles:
        """Posterior means of one scene.

        rgb: (V, 3, H, W) in [0, 1], H = W = config.resolution; depth: (V, 1, H, W) planar metres
        (0 = missing) or None; cameras: V OpenCV cameras of those images; pose: (D,) the scene's pose
        (``bg_static_pose``: :func:`particlesplat.data.scene_meta.read_pose`), None for the layer's mean pose.
        """
        V = rgb.shape[0]
        if rgb.ndim != 4 or rgb.shape[1] != 3:
            raise ValueError(f"encode: rgb must be (V, 3, H, W), got {tuple(rgb.shape)}")
        if len(cameras) != V:
            raise ValueError(f"encode: {V} images but {len(cameras)} cameras")
        if depth is not None and tuple(depth.shape) != (V, 1, *rgb.shape[-2:]):
            raise ValueError(f"encode: depth must be {(V, 1, *rgb.shape[-2:])}, got {tuple(depth.shape)}")
        for c in cameras:
            if (c.width, c.height) != tuple(rgb.shape[-2:][::-1]):
                raise ValueError(
                    f"encode: camera is {c.width}x{c.height} but images are {rgb.shape[-1]}x{rgb.shape[-2]}"
                )
        dev = next(self.parameters()).device
        K, c2w = stack_cameras(cameras, device=dev)
        rgb_b, depth_b = rgb[None].to(dev), None if depth is None else depth[None].to(dev)
        pose_b = self.batch_pose([pose], dev)
        post = self.encode_posterior(rgb_b, depth_b, K[None], c2w[None], pose_b)
        z = self.latents(post, sample=False)
        return Particles(
            z_p=z["z_p"][0],
            z_s=z["z_s"][0],
            z_d=z["z_d"][0],
            z_e=z["z_e"][0],
            z_t=z["z_t"][0],
            z_f=z["z_f"][0],
            view=post.view,
            background=z["bg"][0],
            cameras=[c.to(dev) for c in cameras],
            pose=None if pose_b is None else pose_b[0],
            backdrop=self.views_backdrop(rgb_b[0], None if depth_b is None else depth_b[0], K, c2w),
            support_map=self.views_support_map(
                rgb_b[0],
                None if depth_b is None else depth_b[0],
                K,
                c2w,
                None if pose_b is None else pose_b[0],
                self.views_evidence(post, 0),
            ),
        )

    @torch.no_grad()
    def decode(
        self,
        particles: Particles,
        indices: Tensor | None = None,
        *,
        background: bool = True,
        z_t_threshold: float | None = None,
        opacity_threshold: float = 0.0,
        max_per_particle: int | None = None,
    ) -> Gaussians:
        """Gaussians of one scene.

        indices: (M,) particle indices to decode (default all); their Gaussians get owner = index.
        background: include the per-view background Gaussians (owner -1). Particles with z_t below
        ``z_t_threshold`` and Gaussians with opacity below ``opacity_threshold`` are dropped; with
        ``max_per_particle`` = k, each particle keeps its k most opaque Gaussians (of
        ``config.gaussians_per_particle``; the background is untouched).
        ``z_t_threshold`` None = ``config.bg_mask_threshold``: only active particles draw (an inactive one
        drew a faint copy that no object grouping took along; dropping them costs nothing on the test
        scenes, docs/object-edits.md); 0 draws every particle.
        Decoding a subset gives the same Gaussians as the full decode restricted to it (to float32 rounding: a
        batch of another size may round the last bits differently).
        """
        dev = next(self.parameters()).device
        p = particles.to(dev)
        idx = torch.arange(p.num, device=dev) if indices is None else torch.as_tensor(indices, device=dev).long()
        if idx.numel() and (int(idx.min()) < 0 or int(idx.max()) >= p.num):
            raise IndexError(f"decode: particle indices must be in [0, {p.num}), got {idx.tolist()}")
        if max_per_particle is not None and max_per_particle < 1:
            raise ValueError(f"decode: max_per_particle must be >= 1, got {max_per_particle}")
        if z_t_threshold is None:
            z_t_threshold = self.config.bg_mask_threshold
        if z_t_threshold > 0.0:
            idx = idx[p.z_t[idx, 0] >= z_t_threshold]
        K, c2w = stack_cameras(p.cameras, device=dev)
        if K.shape[0] != int(p.background.shape[0]):
            raise ValueError(f"decode: {K.shape[0]} cameras but {p.background.shape[0]} background latents")
        parts = []
        if idx.numel():
            v = p.view[idx]
            fg = self.foreground(
                p.z_p[idx],
                p.z_s[idx],
                p.z_d[idx],
                p.z_e[idx],
                p.z_t[idx],
                p.z_f[idx],
                K[v],
                c2w[v],
                max_per_particle or 0,
                None if p.support is None else p.support[idx, 0],
            )
            parts.append(_gaussians(fg, idx.repeat_interleave(fg["opacities"].shape[1])))
        if background:
            pose = self.batch_pose([p.pose], dev)
            fill = None
            if self.config.bg_opaque_under_objects:  # the table shows where no particle's box is any longer
                covered, colour = self._table_fill(p)
                fill = (covered[None], None if colour is None else colour[None])
            fields = self.background_fields(p.background[None], K[None], c2w[None], pose, fill)
            bgf = {k: v[0] for k, v in fields.items()}
            parts.append(_gaussians(bgf, torch.full((bgf["means"].shape[0],), BACKGROUND_OWNER, device=dev)))
        if not parts:
            return Gaussians.empty(self.config.sh_degree, device=dev)
        g = Gaussians.cat(parts)
        if opacity_threshold > 0.0:
            g = g.subset(g.opacities >= opacity_threshold)
        return g

    def config_dict(self) -> dict:
        """The config as a checkpoint stores it: nested (:func:`~particlesplat.model.config.config_to_dict`)."""
        return config_to_dict(self.config)
