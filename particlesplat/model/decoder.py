"""Decoders: particles and background latents -> world-space 3D Gaussians (appendix steps 1-3)."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from particlesplat.core.sh import SH_C0, num_sh_bases
from particlesplat.core.world import ON_SUPPORT, SUPPORT_Z
from particlesplat.model.config import ModelConfig
from particlesplat.model.geometry import (
    camera_covariance_factor,
    covariance_to_quat_scale,
    plucker_at,
    ray_dirs,
    rotate_sh_to_world,
)


def gaussian_channels(sh_degree: int) -> int:
    """Channels of a Gaussian head: SH colour 3K, offset 2, depth residual 1, quaternion 4, scales 3, opacity 1."""
    return 3 * num_sh_bases(sh_degree) + 11


def split_gaussian_params(raw: Tensor, sh_degree: int) -> dict[str, Tensor]:
    """raw: (..., C) head output -> named parts (sh (..., K, 3), delta (..., 2), dd (..., 1), quat (..., 4),
    scale (..., 3), opacity (..., 1))."""
    k = num_sh_bases(sh_degree)
    sh, delta, dd, quat, scale, opac = torch.split(raw, [3 * k, 2, 1, 4, 3, 1], dim=-1)
    return {
        "sh": sh.reshape(*sh.shape[:-1], k, 3),
        "delta": delta,
        "dd": dd,
        "quat": quat,
        "scale": scale,
        "opacity": opac,
    }


def conv_bias(conv: nn.Conv2d) -> Tensor:
    """The bias of ``conv``, a convolution made with one (``bias=True``, the default)."""
    if conv.bias is None:
        raise ValueError(f"expected a convolution with a bias, got {conv}")
    return conv.bias


def init_gaussian_head(conv: nn.Conv2d, sh_degree: int, opacity_logit: float, depth_logit: float = 0.0) -> None:
    """Small weights; biases: grey colour, identity rotation, mid scales, given opacity and depth logits."""
    k = num_sh_bases(sh_degree)
    nn.init.normal_(conv.weight, std=1e-3)
    b = torch.zeros(conv.out_channels)
    b[3 * k + 2] = depth_logit
    b[3 * k + 3] = 1.0  # quaternion w
    b[-1] = opacity_logit
    with torch.no_grad():
        conv_bias(conv).copy_(b)


class ForegroundDecoder(nn.Module):
    """D_fg: z_f (…, D) -> canonical S×S patch of Gaussian parameters (…, S*S, C).

    z_f is decoded through a hidden layer (``patch_hidden`` units) to a ``patch_base``² feature grid
    (``patch_channels`` deep) that is doubled (nearest, then a residual 3×3 conv that starts at zero) until it
    is S×S, so a model trained with S = ``patch_base`` starts an S-times-finer
    patch from its own Gaussians, each split into children at the finer cell centres.

    A second head gives every cell a back Gaussian (rows S*S .. 2*S*S - 1), which :func:`foreground_gaussians`
    places behind the cell's front Gaussian on the same ray; it starts nearly transparent (opacity logit -2).
    """

    def __init__(self, cfg: ModelConfig):
        super().__init__()
        self.S = cfg.patch_gaussians
        self.base = cfg.patch_base or cfg.patch_gaussians
        self.sh_degree = cfg.sh_degree
        c = cfg.particle_decoder_channels
        self.c = c
        hidden = cfg.particle_decoder_hidden
        self.fc = nn.Sequential(nn.Linear(cfg.d_obj, hidden), nn.SiLU(), nn.Linear(hidden, c * self.base * self.base))
        self.up = nn.ModuleList()
        size = self.base
        while size < self.S:
            conv = nn.Conv2d(c, c, 3, padding=1)
            nn.init.zeros_(conv.weight)
            nn.init.zeros_(conv_bias(conv))
            self.up.append(conv)
            size *= 2
        self.conv = nn.Sequential(nn.SiLU(), nn.Conv2d(c, c, 3, padding=1), nn.SiLU())
        self.head = nn.Conv2d(c, gaussian_channels(cfg.sh_degree), 1)
        init_gaussian_head(self.head, cfg.sh_degree, opacity_logit=2.0)
        self.back_head = nn.Conv2d(c, gaussian_channels(cfg.sh_degree), 1)
        init_gaussian_head(self.back_head, cfg.sh_degree, opacity_logit=-2.0)

    def forward(self, z_f: Tensor) -> Tensor:
        """z_f: (M, D) -> (M, 2*S*S, C): the front cells in row-major (y, x) order, then the back cells."""
        h = self.fc(z_f).reshape(-1, self.c, self.base, self.base)
        for conv in self.up:
            h = F.interpolate(h, scale_factor=2, mode="nearest")
            h = h + conv(F.silu(h))
        h = self.conv(h)
        return torch.cat([o(h).flatten(2).transpose(1, 2) for o in (self.head, self.back_head)], dim=1)


class BackgroundDecoder(nn.Module):
    """D_bg: per-view background latent map (``d_bg`` channels) + rays -> one Gaussian per k×k pixel block
    (``bg_per_view``)."""

    def __init__(self, cfg: ModelConfig):
        super().__init__()
        c = cfg.channels
        self.cfg = cfg
        self.ray_proj = nn.Conv2d(6, c, 1)
        self.inp = nn.Conv2d(cfg.d_bg, c, 3, padding=1)
        self.body = nn.Sequential(
            nn.SiLU(), nn.Conv2d(c, c, 3, padding=1), nn.SiLU(), nn.Conv2d(c, c, 3, padding=1), nn.SiLU()
        )
        self.head = nn.Conv2d(c, gaussian_channels(cfg.sh_degree), 1)
        mid = (3.5 - cfg.d_min) / (cfg.d_max - cfg.d_min)
        init_gaussian_head(
            self.head,
            cfg.sh_degree,
            opacity_logit=3.0,
            # anchored (fg_evidence): the depth channel is a residual about the view's own depth, 0 at the start
            depth_logit=0.0 if cfg.fg_evidence else float(torch.logit(torch.tensor(min(max(mid, 0.05), 0.95)))),
        )

    def forward(self, latent: Tensor, rays: Tensor) -> Tensor:
        """latent: (M, d_bg, h, w); rays: (M, 6, Hb, Wb) Plücker at block centres -> (M, Hb*Wb, C)."""
        hb, wb = rays.shape[-2:]
        z = F.interpolate(latent, size=(hb, wb), mode="bilinear", align_corners=False)
        h = self.inp(z) + self.ray_proj(rays)
        return self.head(self.body(h)).flatten(2).transpose(1, 2)


def masked_block_mean(x: Tensor, weight: Tensor, k: int) -> tuple[Tensor, Tensor]:
    """x: (M, C, H, W); weight: (M, 1, H, W) in [0, 1] -> the weighted mean of every k×k block
    (M, C, H/k, W/k) and the block's mean weight (M, 1, H/k, W/k) (0 where nothing counts)."""
    w = F.avg_pool2d(weight, k)
    return F.avg_pool2d(x * weight, k) / w.clamp_min(1e-6), w


def _place(
    pix: Tensor,
    zeta: Tensor,
    K: Tensor,
    c2w: Tensor,
    opacity: Tensor,
    support: bool = False,
    cut: float = -1.0,
    height: Tensor | None = None,
) -> tuple[Tensor, Tensor, Tensor]:
    """Where image-plane Gaussians lie in the world, and whether they draw.

    pix: (..., 2) pixel centres; zeta: (...) planar depth; K: (..., 3, 3), c2w: (..., 4, 4) broadcast per
    Gaussian; opacity: (...) α. support: no mean below the support surface (:func:`clamp_to_support`); cut: a
    Gaussian whose mean lies more than ``cut`` metres below it does not draw (opacity 0; < 0 = off). height:
    the support surface's world z under each Gaussian (broadcast with zeta; None: SUPPORT_Z, the shared one).
    Returns the planar depth (clamped with ``support``), means (..., 3) and opacity.
    """
    dirs = ray_dirs(pix[..., None, :], K, c2w)[..., 0, :]
    surface: Tensor | float = SUPPORT_Z if height is None else height
    if support:
        zeta = clamp_to_support(zeta, c2w[..., 2, 3], dirs[..., 2], surface)
    means = c2w[..., :3, 3] + zeta[..., None] * dirs
    if cut >= 0.0:
        opacity = torch.where(means[..., 2] < surface - cut, torch.zeros_like(opacity), opacity)
    return zeta, means, opacity


def _finish(
    p: dict[str, Tensor],
    zeta: Tensor,
    means: Tensor,
    opacity: Tensor,
    jac_px: Tensor,
    K: Tensor,
    c2w: Tensor,
    cfg: ModelConfig,
    depth_cell: Tensor | None = None,
    shapes: bool = True,
) -> dict[str, Tensor]:
    """The fields of Gaussians placed by :func:`_place` (its zeta, means and opacity), with their world rotation,
    scales and SH. jac_px: (..., 2) pixels per canonical unit; depth_cell: (...) metres per canonical unit along
    the camera axis, at least a pixel's width (default: a pixel's width). ``shapes`` False leaves out "quats" and
    "scales" (a caller that shapes the Gaussians itself: a float64 eigendecomposition a Gaussian not paid for)."""
    sh = rotate_sh_to_world(p["sh"], c2w[..., :3, :3])  # c2w already broadcasts over the Gaussians
    if not shapes:
        return {"means": means, "opacities": opacity, "sh": sh}
    fx = K[..., 0, 0]
    fy = K[..., 1, 1]
    jac_z = zeta / fx if depth_cell is None else torch.maximum(zeta / fx, depth_cell)
    jac = torch.stack([jac_px[..., 0] * zeta / fx, jac_px[..., 1] * zeta / fy, jac_z], dim=-1)
    s = cfg.s_min + (cfg.s_max - cfg.s_min) * torch.sigmoid(p["scale"])
    M = camera_covariance_factor(p["quat"], s, jac)
    M_world = c2w[..., :3, :3] @ M
    quats, scales = covariance_to_quat_scale(M_world)
    return {"means": means, "quats": quats, "scales": scales, "opacities": opacity, "sh": sh}


def clamp_to_support(zeta: Tensor, origin_z: Tensor, dir_z: Tensor, surface: Tensor | float = SUPPORT_Z) -> Tensor:
    """Planar depths (...) of points on camera rays moved, where they would lie below the support surface
    z = ``surface`` (default the shared one, :data:`~particlesplat.core.world.SUPPORT_Z`: the floor or table top
    objects rest on, world metres, +z up; a tensor broadcast with zeta: each point's own), to where the ray meets it.

    origin_z: (...) camera height; dir_z: (...) world z of the ray direction per unit planar depth. Rays from
    below the surface or not going down are left alone. Differentiable (a minimum).
    """
    height = origin_z - surface
    down = (dir_z < 0) & (height > 0)
    hit = torch.where(down, height / (-dir_z).clamp_min(1e-12), torch.full_like(zeta, float("inf")))
    return torch.minimum(zeta, hit)


def cell_centres(S: int, device, dtype) -> Tensor:
    """(S*S, 2) centres (x, y) of an S×S patch's cells in [0, 1], row-major (y, x) order."""
    ar = (torch.arange(S, device=device, dtype=dtype) + 0.5) / S
    gy, gx = torch.meshgrid(ar, ar, indexing="ij")
    return torch.stack([gx, gy], dim=-1).reshape(S * S, 2)


def foreground_gaussians(
    raw: Tensor,
    z_p: Tensor,
    z_s: Tensor,
    z_d: Tensor,
    z_e: Tensor,
    z_t: Tensor,
    K: Tensor,
    c2w: Tensor,
    cfg: ModelConfig,
    keep: int = 0,
    colour_anchor: Tensor | None = None,
    support: Tensor | None = None,
) -> dict[str, Tensor]:
    """Steps 2-3 for M particles.

    raw: (M, 2*S*S, C) canonical patch parameters (the S*S front cells row-major, then the back cells);
    z_p: (M, 2) in [-1, 1]; z_s: (M, 2), z_d: (M, 1), z_e: (M, 1) pre-sigmoid; z_t: (M, 1) in [0, 1];
    K: (M, 3, 3) and c2w: (M, 4, 4) of each particle's view. Returns Gaussian fields with leading dims (M, N),
    N = 2*S*S; with ``keep`` = k in (0, N), (M, k): each particle's k most opaque Gaussians, in their order among
    its N, chosen before they are lifted to the world (the opacity needs no lifting; the lift is most of the
    cost).

    A back Gaussian sits on its front Gaussian's ray, σ(its depth channel) x the particle box's width
    (metres, at the front depth) further away: the far side of the object along the context view's ray,
    which the view cannot see. Its offset channels are unused; the rest are its own.

    ``colour_anchor`` (M, N, 3) in [0, 1] (``patch.colour_anchor``): each cell's colour is a residual about it (the
    context view's colour under the cell, :meth:`ParticleSplat.with_colour_anchors`). ``support`` (M,): the world
    height of the surface under each particle (:attr:`Particles.support`; None: the shared SUPPORT_Z), where
    ``support.clamp`` and ``support.cut`` put it.
    """
    S = cfg.patch_gaussians
    H = W = cfg.resolution
    p = split_gaussian_params(raw[:, : S * S], cfg.sh_degree)
    u = cell_centres(S, raw.device, raw.dtype)[None]
    du = (torch.sigmoid(p["delta"]) - 0.5) / S
    u_patch = 2.0 * (u + du) - 1.0
    scale = torch.sigmoid(z_s)[:, None, :]
    u_img = 0.5 * (scale * u_patch + z_p[:, None, :] + 1.0)
    size = torch.tensor([W, H], device=raw.device, dtype=raw.dtype)
    pix = u_img * size
    d = cfg.depth_of(z_d)
    half = 0.5 * (cfg.d_max - cfg.d_min) * torch.sigmoid(z_e)
    zeta = d + half * torch.tanh(p["dd"][..., 0])
    jac_px = scale * size / S  # s_x / (S_w / W): pixels per canonical cell
    opacity = z_t * torch.sigmoid(p["opacity"][..., 0])
    pb = split_gaussian_params(raw[:, S * S :], cfg.sh_degree)
    box = jac_px.mean(-1) * S * zeta / K[:, 0, 0, None]  # (M, S*S) the particle box's width in metres
    p = {k: torch.cat([p[k], pb[k]], dim=1) for k in p}
    pix = torch.cat([pix, pix], dim=1)
    zeta = torch.cat([zeta, zeta + torch.sigmoid(pb["dd"][..., 0]) * box], dim=1)
    opacity = torch.cat([opacity, z_t * torch.sigmoid(pb["opacity"][..., 0])], dim=1)
    if colour_anchor is not None:
        dc = p["sh"][..., 0, :] + (colour_anchor - 0.5) / SH_C0
        p = {**p, "sh": torch.cat([dc[..., None, :], p["sh"][..., 1:, :]], dim=-2)}
    return _lift_cells(p, pix, zeta, jac_px, opacity, K, c2w, cfg, keep, support)


def cell_pixels(z_p: Tensor, z_s: Tensor, S: int, size: tuple[int, int]) -> Tensor:
    """Pixel centres (M, S*S, 2) of M particles' S×S cells without their learned offsets: z_p (M, 2) in [-1, 1],
    z_s (M, 2) pre-sigmoid; size (W, H) of the view."""
    u = cell_centres(S, z_p.device, z_p.dtype)[None]
    u_img = 0.5 * (torch.sigmoid(z_s)[:, None, :] * (2.0 * u - 1.0) + z_p[:, None, :] + 1.0)
    return u_img * torch.tensor(size, device=z_p.device, dtype=z_p.dtype)


def _lift_cells(
    p: dict[str, Tensor],
    pix: Tensor,
    zeta: Tensor,
    jac_px: Tensor,
    opacity: Tensor,
    K: Tensor,
    c2w: Tensor,
    cfg: ModelConfig,
    keep: int = 0,
    support: Tensor | None = None,
) -> dict[str, Tensor]:
    """Lift N cells of M particles: p split head output, pix (M, N, 2) pixels, zeta (M, N) planar metres,
    jac_px (M, 1, 2) pixels per canonical cell, opacity (M, N); K (M, 3, 3), c2w (M, 4, 4). ``keep`` = k in
    (0, N): only each particle's k most opaque cells (as they draw, after ``support_cut``), in their order.
    ``support`` (M,): the height of the surface under each particle (None: SUPPORT_Z)."""
    N = pix.shape[1]
    # canonical cells are cubes (as deep as they are wide), so a particle's Gaussians have volume and do not
    # turn into slivers seen from the side
    depth_cell = jac_px.mean(-1) * zeta / K[:, 0, 0, None]
    height = None if support is None else support.to(zeta)[:, None]  # (M, 1) with zeta (M, N)
    zeta, means, opacity = _place(
        pix, zeta, K[:, None], c2w[:, None], opacity, cfg.support_clamp, cfg.support_cut, height
    )
    if 0 < keep < N:
        rows = opacity.topk(keep, dim=1).indices.sort(dim=1).values  # (M, k)

        def take(t: Tensor) -> Tensor:
            return t.gather(1, rows.reshape(*rows.shape, *[1] * (t.ndim - 2)).expand(-1, -1, *t.shape[2:]))

        p = {k: take(v) for k, v in p.items()}
        zeta, means, opacity, depth_cell = take(zeta), take(means), take(opacity), take(depth_cell)
        N = keep
    Kn, cn = K[:, None].expand(-1, N, -1, -1), c2w[:, None].expand(-1, N, -1, -1)
    return _finish(p, zeta, means, opacity, jac_px.expand(-1, N, -1), Kn, cn, cfg, depth_cell)


def block_centres(cfg: ModelConfig, device, dtype) -> Tensor:
    """(Hb*Wb, 2) pixel centres of the k×k background blocks, row-major."""
    k = cfg.bg_block
    n = cfg.resolution // k
    ar = (torch.arange(n, device=device, dtype=dtype) + 0.5) * k
    gy, gx = torch.meshgrid(ar, ar, indexing="ij")
    return torch.stack([gx, gy], dim=-1).reshape(-1, 2)


def background_rays(K: Tensor, c2w: Tensor, cfg: ModelConfig) -> Tensor:
    """K: (M, 3, 3), c2w: (M, 4, 4) -> (M, 6, Hb, Wb) Plücker rays at block centres."""
    n = cfg.resolution // cfg.bg_block
    pix = block_centres(cfg, K.device, K.dtype)[None].expand(K.shape[0], -1, -1)
    return plucker_at(pix, K, c2w).transpose(1, 2).reshape(K.shape[0], 6, n, n)


ANCHOR_CHANNELS = 6
"""Per-block anchors of an anchored background (``fg_evidence``): colour (3, [0, 1]), planar depth (1, metres),
the share of the block's pixels they were taken from (1, in [0, 1]; 0 = none: the block shows an object or has
no depth) and the share of its pixels under an object (1, in [0, 1]: within :data:`UNDER_OBJECT_PIXELS` of an
object's evidence and inside an active particle's box). Anchors of five channels (particles encoded before the last
one) read as no block under an object."""
ANCHOR_DEPTH_RANGE = 0.05
"""How far an anchored background Gaussian may move off its anchor depth: ± this fraction of it."""
UNDER_OBJECT_PIXELS = 4
"""Pixels by which an object's evidence is grown to find the blocks under it (``background.opaque_under_objects``):
its foot and the rim a particle's edge leaves."""
UNDER_OBJECT_OPACITY = 0.99
"""The opacity of a block under an object (``background.opaque_under_objects``)."""
UNDER_OBJECT_WIDTH = 0.7
"""The least in-surface width of a block under an object, as a fraction of the step to the next block: wide enough
that the table it draws where an object stood has no gaps."""


def block_anchors(rgb: Tensor, depth: Tensor | None, hidden: Tensor, k: int, under: Tensor | None = None) -> Tensor:
    """The anchors of an anchored background: each k×k block's mean colour and depth over its pixels that are
    neither hidden nor without depth, and the share of its pixels under an object.

    rgb: (M, 3, H, W); depth: (M, 1, H, W) planar metres (0 = missing) or None; hidden: (M, 1, H, W) in [0, 1]
    (1 = an object's pixel); under: (M, 1, H, W) in [0, 1] (1 = under an object, :data:`ANCHOR_CHANNELS`) or None
    (none). Returns (M, :data:`ANCHOR_CHANNELS`, H/k, W/k).
    """
    keep = 1.0 - hidden
    if depth is not None:
        keep = keep * (depth > 0).to(rgb.dtype)
    colour, w = masked_block_mean(rgb, keep, k)
    d = masked_block_mean(depth, keep, k)[0] if depth is not None else torch.zeros_like(w)
    share = F.avg_pool2d(under, k) if under is not None else torch.zeros_like(w)
    return torch.cat([colour, d, w, share], dim=1)


def _anchored_depth(
    zeta_free: Tensor, dd: Tensor, anchor: Tensor, pix: Tensor, K: Tensor, c2w: Tensor
) -> tuple[Tensor, Tensor, Tensor]:
    """Planar depths of anchored background Gaussians (M, N): within ± :data:`ANCHOR_DEPTH_RANGE` of the block's
    own depth where more than half its pixels gave one; else of where the block's ray meets the support surface
    (the table behind an object); else ``zeta_free`` (the latent's own depth). anchor: (M, N, 5 or 6); dd: (M, N).
    Also returns (M, N) bool: the blocks placed on the support surface (not seen, their ray meets it), and (M, N)
    the planar depth where each block's ray meets the support surface (inf where it does not)."""
    dirs = ray_dirs(pix[..., None, :], K, c2w)[..., 0, :]
    plane = clamp_to_support(torch.full_like(zeta_free, float("inf")), c2w[..., 2, 3], dirs[..., 2])
    seen = anchor[..., 4] > 0.5
    base = torch.where(seen, anchor[..., 3], plane)
    on_support = ~seen & torch.isfinite(plane)
    usable = seen | on_support
    base = torch.where(usable, base, torch.ones_like(base))
    return torch.where(usable, base * (1.0 + ANCHOR_DEPTH_RANGE * torch.tanh(dd)), zeta_free), on_support, plane


MIN_SUPPORT_BLOCKS = 20
"""The least number of a view's blocks on the support surface for their colour to stand for it."""


def support_colours(anchor: Tensor, K: Tensor, c2w: Tensor, cfg: ModelConfig) -> tuple[Tensor, Tensor]:
    """The colour of the support surface each view shows: the median anchor colour of its blocks whose anchor
    point lies within :data:`~particlesplat.core.world.ON_SUPPORT` of z = 0 (blocks more than half seen,
    :func:`block_anchors`).

    anchor: (M, N, 5); K: (M, 3, 3); c2w: (M, 4, 4) -> colours (M, 3) in [0, 1], and (M,) bool: the view has at
    least :data:`MIN_SUPPORT_BLOCKS` such blocks (else its colour is 0.5 grey and unused)."""
    M = anchor.shape[0]
    pix = block_centres(cfg, anchor.device, anchor.dtype)[None].expand(M, -1, -1)
    height = c2w[:, None, 2, 3] + anchor[..., 3] * ray_dirs(pix, K, c2w)[..., 2]  # (M, N) world z, metres
    on = (anchor[..., 4] > 0.5) & ((height - SUPPORT_Z).abs() < ON_SUPPORT)
    colours = torch.full((M, 3), 0.5, dtype=anchor.dtype, device=anchor.device)
    found = on.sum(dim=1) >= MIN_SUPPORT_BLOCKS
    for m in torch.nonzero(found).flatten().tolist():
        colours[m] = anchor[m, on[m], :3].median(dim=0).values
    return colours.detach(), found


def background_gaussians(
    raw: Tensor,
    K: Tensor,
    c2w: Tensor,
    cfg: ModelConfig,
    anchor: Tensor | None = None,
    covered: Tensor | None = None,
    fill_colour: Tensor | None = None,
) -> dict[str, Tensor]:
    """raw: (M, Hb*Wb, C) per-block parameters; K: (M, 3, 3); c2w: (M, 4, 4) -> fields with dims (M, Hb*Wb).

    Pixel-aligned: a block centre plus a bounded sub-block offset; depth ζ = d_min + σ(·)(d_max − d_min)
    from the depth-residual channel; opacity σ(o) (no transparency gate). With ``anchor`` (M, Hb*Wb, 5)
    (:func:`block_anchors`, ``fg_evidence``) the depth is a residual about the block's own depth
    (:func:`_anchored_depth`) and the colour one about its own colour, weighted by the share it was taken from;
    with ``bg_hidden_from_views`` a block an object hides (one placed where its ray meets the support surface)
    takes the colour of the support surface its view shows (:func:`support_colours`); with
    ``bg_opaque_under_objects`` and ``covered`` (M, Hb*Wb), the share of each block inside its view's active
    particles' boxes (:func:`~particlesplat.model.encoder.covered_blocks`), such a block under an object (anchor
    channel 5) that no box covers any longer (an edit moved or removed the object) lies on the support surface,
    opaque and wide enough to leave no gaps, in ``fill_colour`` (M, Hb*Wb, 3) where given (the scene's support map
    there), else the support surface's colour: the table where the object stood.
    """
    k = cfg.bg_block
    p = split_gaussian_params(raw, cfg.sh_degree)
    n = raw.shape[1]
    pix = block_centres(cfg, raw.device, raw.dtype)[None] + (torch.sigmoid(p["delta"]) - 0.5) * k
    zeta = cfg.depth_of(p["dd"][..., 0])
    jac_px = torch.full_like(pix, float(k))
    opacity = torch.sigmoid(p["opacity"][..., 0])
    Kn = K[:, None].expand(-1, n, -1, -1)
    cn = c2w[:, None].expand(-1, n, -1, -1)
    if anchor is None:
        zeta, means, opacity = _place(pix, zeta, Kn, cn, opacity)
        return _finish(p, zeta, means, opacity, jac_px, Kn, cn, cfg)
    zeta, behind, plane = _anchored_depth(zeta, p["dd"][..., 0], anchor, pix, Kn, cn)
    dc = p["sh"][..., 0, :] + anchor[..., 4:5] * (anchor[..., :3] - 0.5) / SH_C0
    under = None  # the blocks drawn as the table where an object stood (bg_opaque_under_objects)
    if cfg.bg_hidden_from_views:
        surface, found = support_colours(anchor, K, c2w, cfg)  # (M, 3), (M,)
        hidden = behind & found[:, None]  # (M, N): placed on the table behind an object
        dc = torch.where(hidden[..., None], ((surface - 0.5) / SH_C0)[:, None, :].expand_as(dc), dc)
        if cfg.bg_opaque_under_objects and anchor.shape[-1] > 5 and covered is not None:
            # the table under an object that a particle's box no longer covers (an edit moved it): on it, opaque
            under = hidden & (anchor[..., 5] > 0.5) & (covered <= 0.5)
            zeta = torch.where(under, plane, zeta)
            opacity = torch.where(under, torch.full_like(opacity, UNDER_OBJECT_OPACITY), opacity)
            if fill_colour is not None:
                dc = torch.where(under[..., None], (fill_colour.to(dc) - 0.5) / SH_C0, dc)
    p = {**p, "sh": torch.cat([dc[..., None, :], p["sh"][..., 1:, :]], dim=-2)}
    zeta, means, opacity = _place(pix, zeta, Kn, cn, opacity)
    fields = _finish(p, zeta, means, opacity, jac_px, Kn, cn, cfg, shapes=False)
    quats, scales = _surface_shapes(p["scale"], anchor, zeta, K, c2w, cfg, under)
    return {**fields, "quats": quats, "scales": scales}


SURFACE_THICKNESS = 0.1
"""An anchored background Gaussian's thickness along its surface's normal, as a fraction of its block's width."""
SURFACE_STEP_LIMIT = 3.0
"""A step to the next block's anchor longer than this many block widths crosses a depth edge: the block's own
camera-facing width is used instead."""


def _surface_shapes(
    scale_raw: Tensor,
    anchor: Tensor,
    zeta: Tensor,
    K: Tensor,
    c2w: Tensor,
    cfg: ModelConfig,
    under: Tensor | None = None,
) -> tuple[Tensor, Tensor]:
    """Shapes of anchored background Gaussians that lie flat on the surface their blocks see, spanning the steps
    to the neighbouring blocks' anchors, so a view from another side sees the surface without gaps.

    scale_raw: (M, N, 3) the head's scale channels (in-surface x, y and thickness factors in [s_min, s_max]);
    anchor: (M, N, 5 or 6) (:func:`block_anchors`); zeta: (M, N) the Gaussians' planar depths, metres; K (M, 3, 3),
    c2w (M, 4, 4); under: (M, N) bool, the blocks under an object (``background.opaque_under_objects``), which
    lie flat on the support surface, span the steps to their neighbours there and have in-surface factors of at
    least :data:`UNDER_OBJECT_WIDTH`; or None. With ``background.min_width`` the in-surface factors span
    [min_width, s_max] instead of [s_min, s_max]. Returns quats (M, N, 4), scales (M, N, 3).
    The two in-surface axes are the half-steps to the next block's anchor point along x and y (the shorter of the
    steps forward and back, so that a depth edge is not bridged; a step over :data:`SURFACE_STEP_LIMIT` block
    widths, or from a block without an anchor, falls back to the camera-facing block width).
    """
    k = cfg.bg_block
    n = cfg.resolution // k
    M = anchor.shape[0]
    pix = block_centres(cfg, anchor.device, anchor.dtype)[None].expand(M, -1, -1)
    dirs = ray_dirs(pix, K, c2w)  # (M, N, 3), camera z = 1
    depth = torch.where(anchor[..., 4] > 0.5, anchor[..., 3], torch.full_like(anchor[..., 3], float("nan")))
    if under is not None:  # a block under an object spans the steps to its neighbours on the support surface
        plane = clamp_to_support(torch.full_like(depth, float("inf")), c2w[:, None, 2, 3], dirs[..., 2])
        depth = torch.where(under, plane, depth)
    pts = (c2w[:, None, :3, 3] + depth[..., None] * dirs).reshape(M, n, n, 3)
    width = (zeta.detach() * k / K[:, None, 0, 0]).reshape(M, n, n, 1)  # metres a block spans, facing the camera

    def step(axis: int, fallback: Tensor) -> Tensor:
        fwd = torch.diff(pts, dim=axis, append=pts.narrow(axis, n - 1, 1))
        back = torch.diff(pts, dim=axis, prepend=pts.narrow(axis, 0, 1))
        fwd_n, back_n = fwd.norm(dim=-1, keepdim=True), back.norm(dim=-1, keepdim=True)
        fwd_n, back_n = torch.nan_to_num(fwd_n, nan=float("inf")), torch.nan_to_num(back_n, nan=float("inf"))
        fwd_n = torch.where(fwd_n == 0, torch.full_like(fwd_n, float("inf")), fwd_n)
        back_n = torch.where(back_n == 0, torch.full_like(back_n, float("inf")), back_n)
        best = torch.where(fwd_n <= back_n, fwd, back)
        ok = torch.minimum(fwd_n, back_n) <= SURFACE_STEP_LIMIT * width
        return torch.where(ok & (width > 0), best, fallback)

    cam = c2w[:, None, None, :3, :3]  # (M, 1, 1, 3, 3)
    fallback_w = width.clamp_min(1e-4)
    u = step(2, cam[..., 0] * fallback_w)
    v = step(1, cam[..., 1] * fallback_w)
    normal = torch.linalg.cross(u, v)
    normal = normal / normal.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    thick = SURFACE_THICKNESS * torch.maximum(u.norm(dim=-1, keepdim=True), v.norm(dim=-1, keepdim=True))
    lo = torch.tensor([max(cfg.bg_min_width, cfg.s_min)] * 2 + [cfg.s_min], dtype=scale_raw.dtype)
    lo = lo.to(scale_raw.device)
    s = lo + (cfg.s_max - lo) * torch.sigmoid(scale_raw)  # (M, N, 3)
    if under is not None:
        s = torch.where(under[..., None] & (torch.arange(3, device=s.device) < 2), s.clamp_min(UNDER_OBJECT_WIDTH), s)
    cols = torch.stack(
        [
            u.reshape(M, -1, 3) * s[..., 0:1],
            v.reshape(M, -1, 3) * s[..., 1:2],
            (normal * thick).reshape(M, -1, 3) * s[..., 2:3],
        ],
        dim=-1,
    )  # (M, N, 3, 3): columns are the axes
    return covariance_to_quat_scale(cols)
