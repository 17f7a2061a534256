"""Decoders: particles and background latents -> world-space 3D Gaussians (appendix steps 1-3)."""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from ..sh import SH_C0, num_sh_bases
from .config import ModelConfig
from .geometry import (camera_covariance_factor, covariance_to_quat_scale, plucker_at, ray_dirs,
                       rotate_sh_to_world)


def gaussian_channels(sh_degree: int) -> int:
    """Channels of a Gaussian head: SH colour 3K, offset 2, depth residual 1, quaternion 4, scales 3, opacity 1."""
    return 3 * num_sh_bases(sh_degree) + 11


def split_gaussian_params(raw: Tensor, sh_degree: int) -> dict[str, Tensor]:
    """raw: (..., C) head output -> named parts (sh (..., K, 3), delta (..., 2), dd (..., 1), quat (..., 4),
    scale (..., 3), opacity (..., 1))."""
    k = num_sh_bases(sh_degree)
    sh, delta, dd, quat, scale, opac = torch.split(raw, [3 * k, 2, 1, 4, 3, 1], dim=-1)
    return {"sh": sh.reshape(*sh.shape[:-1], k, 3), "delta": delta, "dd": dd, "quat": quat, "scale": scale,
            "opacity": opac}


def init_gaussian_head(conv: nn.Conv2d, sh_degree: int, opacity_logit: float, depth_logit: float = 0.0) -> None:
    """Small weights; biases: grey colour, identity rotation, mid scales, given opacity and depth logits."""
    k = num_sh_bases(sh_degree)
    nn.init.normal_(conv.weight, std=1e-3)
    b = torch.zeros(conv.out_channels)
    b[3 * k + 2] = depth_logit
    b[3 * k + 3] = 1.0  # quaternion w
    b[-1] = opacity_logit
    with torch.no_grad():
        conv.bias.copy_(b)


class ForegroundDecoder(nn.Module):
    """D_fg: z_f (…, D) -> canonical S×S patch of Gaussian parameters (…, S*S, C).

    z_f is decoded through a hidden layer (``patch_hidden`` units) to a ``patch_base``² feature grid
    (``patch_channels`` deep) that is doubled (nearest, then a residual 3×3 conv that starts at zero) until it
    is S×S, so a model trained with S = ``patch_base`` starts an S-times-finer
    patch from its own Gaussians, each split into children at the finer cell centres.

    ``patch_refine`` residual blocks (3×3 conv, SiLU, 3×3 conv whose output starts at zero) then work on the
    S×S grid, so a model trained without them starts from what it drew and gains depth where shapes need it.

    With ``patch_cell_mlp`` H > 0 a per-cell MLP (two hidden layers of H units) reads each cell's features, z_f
    and Fourier features of the cell's position, and adds its output to both heads' (it starts at zero, so a
    model trained without it starts from what it drew): the convolutions see a cell's position only through
    its neighbours, the MLP can draw an edge wherever z_f puts it.

    With ``patch_back`` a second head gives every cell a back Gaussian (rows S*S .. 2*S*S - 1), which
    :func:`foreground_gaussians` places behind the cell's front Gaussian on the same ray; it starts nearly
    transparent (opacity logit -2), so a model trained without it starts from what it drew before.

    With ``patch_copy_input`` the decoder also reads what the particle's context view shows at its cells
    (:func:`observed_cells`): the observation enters the feature grid through a convolution that starts at
    zero, and a per-cell gate (two channels, colour and depth, starting open at σ(2)) moves each front
    Gaussian's colour and depth residual towards the observed ones where the background alone explains the
    view badly: the pixel-aligned copy of feed-forward splatting, inside the particle's box.
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
            nn.init.zeros_(conv.bias)
            self.up.append(conv)
            size *= 2
        self.refine = nn.ModuleList()
        for _ in range(cfg.patch_refine):
            block = nn.Sequential(nn.SiLU(), nn.Conv2d(c, c, 3, padding=1), nn.SiLU(), nn.Conv2d(c, c, 3, padding=1))
            nn.init.zeros_(block[-1].weight)
            nn.init.zeros_(block[-1].bias)
            self.refine.append(block)
        self.conv = nn.Sequential(nn.SiLU(), nn.Conv2d(c, c, 3, padding=1), nn.SiLU())
        self.head = nn.Conv2d(c, gaussian_channels(cfg.sh_degree), 1)
        init_gaussian_head(self.head, cfg.sh_degree, opacity_logit=2.0)
        self.back_head = None
        if cfg.patch_back:
            self.back_head = nn.Conv2d(c, gaussian_channels(cfg.sh_degree), 1)
            init_gaussian_head(self.back_head, cfg.sh_degree, opacity_logit=-2.0)
        self.cell_mlp = None
        if cfg.patch_cell_mlp > 0:
            H = cfg.patch_cell_mlp
            heads = 2 if cfg.patch_back else 1
            self.register_buffer("cell_code", cell_fourier_features(self.S), persistent=False)
            self.cell_mlp = nn.Sequential(nn.Linear(c + cfg.d_obj + self.cell_code.shape[1], H), nn.SiLU(),
                                          nn.Linear(H, H), nn.SiLU(),
                                          nn.Linear(H, heads * gaussian_channels(cfg.sh_degree)))
            nn.init.zeros_(self.cell_mlp[-1].weight)
            nn.init.zeros_(self.cell_mlp[-1].bias)
        self.obs_in = self.copy_gate = None
        if cfg.patch_copy_input:
            self.obs_in = nn.Sequential(nn.Conv2d(PATCH_OBSERVED_CHANNELS, c, 3, padding=1), nn.SiLU(),
                                        nn.Conv2d(c, c, 3, padding=1))
            nn.init.zeros_(self.obs_in[-1].weight)  # a model trained without it starts from what it drew
            nn.init.zeros_(self.obs_in[-1].bias)
            self.copy_gate = nn.Conv2d(c, 2, 1)
            nn.init.zeros_(self.copy_gate.weight)
            nn.init.constant_(self.copy_gate.bias, 2.0)

    def forward(self, z_f: Tensor, obs: Tensor | None = None) -> Tensor:
        """z_f: (M, D); obs: (M, 7, S, S) from :func:`observed_cells` (needed with ``patch_copy_input``)
        -> (M, S*S, C) with cells in row-major (y, x) order; (M, 2*S*S, C) with ``patch_back``
        (front cells, then back cells)."""
        h = self.fc(z_f).reshape(-1, self.c, self.base, self.base)
        for conv in self.up:
            h = F.interpolate(h, scale_factor=2, mode="nearest")
            h = h + conv(F.silu(h))
        if self.obs_in is not None:
            if obs is None:
                raise ValueError("this model copies the observed cells (patch_copy_input): the particles "
                                 "carry no observation (encode them with this model)")
            h = h + self.obs_in(obs)
        for block in self.refine:
            h = h + block(h)
        h = self.conv(h)
        front = self.head(h)
        back = None if self.back_head is None else self.back_head(h)
        if self.cell_mlp is not None:
            M, S = h.shape[0], self.S
            cells = torch.cat([h.flatten(2).transpose(1, 2), z_f[:, None].expand(-1, S * S, -1),
                               self.cell_code[None].expand(M, -1, -1)], dim=-1)
            extra = self.cell_mlp(cells).transpose(1, 2).reshape(M, -1, S, S)
            C = front.shape[1]
            front = front + extra[:, :C]
            if back is not None:
                back = back + extra[:, C:]
        if self.copy_gate is not None:
            g = torch.sigmoid(self.copy_gate(h))
            colour, r, known, inside, fg = obs[:, :3], obs[:, 3:4], obs[:, 4:5], obs[:, 5:6], obs[:, 6:7]
            front = copy_into_head(front, colour, g[:, :1] * inside * fg, torch.atanh(r), g[:, 1:] * known * fg,
                                   self.sh_degree)
        out = [front] if back is None else [front, back]
        return torch.cat([o.flatten(2).transpose(1, 2) for o in out], dim=1)


# colour (3), depth residual in units of the extent (1), depth known (1), inside the image (1), foreground (1)
PATCH_OBSERVED_CHANNELS = 7


@torch.no_grad()
def observed_cells(rgb: Tensor, depth: Tensor | None, fg: Tensor, z_p: Tensor, z_s: Tensor, z_d: Tensor,
                   z_e: Tensor, cfg: ModelConfig) -> Tensor:
    """What each particle's context view shows at the centres of its S×S cells (nearest pixel; no gradient).

    rgb: (M, 3, H, W) the view each particle belongs to, in [0, 1]; depth: (M, 1, H, W) planar metres
    (0 = none) or None; fg: (M, 1, H, W) 1 where the background alone explains the view badly (only there
    is anything copied: the floor a box also frames stays the background's); z_p, z_s: (M, 2), z_d, z_e:
    (M, 1) as the decoder reads them. Returns (M, 7, S, S): the colour, r = (observed depth - d) / Δ clamped
    to ±0.999 (0 where the depth is unknown), whether the depth is known, whether the cell is inside the
    image, whether it is foreground. The depth is kept relative to the particle's own
    d and Δ, so the copied surface follows an edit of z_d (moved) or z_e (stretched), and its colour an
    edit of z_p or z_s, like everything else the particle decodes to.
    """
    S = cfg.patch_gaussians
    cells = 2.0 * cell_centres(S, rgb.device, rgb.dtype).reshape(S, S, 2) - 1.0  # canonical, in [-1, 1]
    grid = torch.sigmoid(z_s)[:, None, None, :] * cells + z_p[:, None, None, :]  # normalised image coords
    dep = torch.zeros_like(rgb[:, :1]) if depth is None else depth
    src = torch.cat([rgb, dep, torch.ones_like(dep), fg], dim=1)
    s = F.grid_sample(src, grid, mode="nearest", padding_mode="zeros", align_corners=False)
    known = (s[:, 3:4] > 0).to(rgb.dtype)
    d = cfg.depth_of(z_d)[:, :, None, None]
    half = 0.5 * (cfg.d_max - cfg.d_min) * torch.sigmoid(z_e)[:, :, None, None]
    r = ((s[:, 3:4] - d) / half).clamp(-0.999, 0.999) * known  # atanh(r) stays finite
    return torch.cat([s[:, :3], r, known, s[:, 4:6]], dim=1)


def copy_into_head(out: Tensor, colour: Tensor, gate_colour: Tensor, depth_channel: Tensor, gate_depth: Tensor,
                   sh_degree: int) -> Tensor:
    """Move a Gaussian head's SH DC colour and depth channel towards given values.

    out: (M, C, h, w) head output; colour: (M, 3, h, w) RGB in [0, 1]; depth_channel: (M, 1, h, w) the
    depth channel's target value; gate_colour, gate_depth: (M, 1, h, w) in [0, 1] (1 = take the target).
    """
    i = 3 * num_sh_bases(sh_degree) + 2  # the depth channel (after the SH and the 2-d offset)
    dc = (1.0 - gate_colour) * out[:, :3] + gate_colour * (colour - 0.5) / SH_C0
    dd = (1.0 - gate_depth) * out[:, i:i + 1] + gate_depth * depth_channel
    return torch.cat([dc, out[:, 3:i], dd, out[:, i + 1:]], dim=1)


class BackgroundDecoder(nn.Module):
    """D_bg: per-view background latent map + rays -> one Gaussian per k×k pixel block.

    The latent's first ``d_bg`` channels are the stochastic background latent; with ``bg_detail`` > 0 the
    next ``bg_detail`` channels, at block resolution, are the pixel-aligned detail features (absent or
    zero: the plain background, which the keypoint selection compares with the view). With
    ``bg_copy_input`` the last :data:`OBSERVED_CHANNELS` are the observed block colour, planar depth and
    their visibility (:func:`observed_blocks`): a visible block's Gaussian takes that colour and depth
    through a learned gate.
    """

    def __init__(self, cfg: ModelConfig):
        super().__init__()
        c = cfg.channels
        self.cfg = cfg
        self.ray_proj = nn.Conv2d(6, c, 1)
        self.inp = nn.Conv2d(cfg.d_bg, c, 3, padding=1)
        self.body = nn.Sequential(nn.SiLU(), nn.Conv2d(c, c, 3, padding=1), nn.SiLU(),
                                  nn.Conv2d(c, c, 3, padding=1), nn.SiLU())
        self.detail = nn.Conv2d(cfg.bg_detail, c, 1) if cfg.bg_detail > 0 else None
        self.copy_gate = nn.Parameter(torch.full((2,), 3.0)) if cfg.bg_copy_input else None  # colour, depth
        if self.detail is not None:  # zero: a model without detail is reproduced exactly at the start
            nn.init.zeros_(self.detail.weight)
            nn.init.zeros_(self.detail.bias)
        self.head = nn.Conv2d(c, gaussian_channels(cfg.sh_degree), 1)
        mid = (3.5 - cfg.d_min) / (cfg.d_max - cfg.d_min)
        init_gaussian_head(self.head, cfg.sh_degree, opacity_logit=3.0,
                           depth_logit=float(torch.logit(torch.tensor(min(max(mid, 0.05), 0.95)))))

    def forward(self, latent: Tensor, rays: Tensor) -> Tensor:
        """latent: (M, d_bg [+ bg_detail], h, w) (detail at (Hb, Wb)); rays: (M, 6, Hb, Wb) Plücker at block
        centres -> (M, Hb*Wb, C)."""
        hb, wb = rays.shape[-2:]
        d = self.cfg.d_bg
        z = F.interpolate(latent[:, :d], size=(hb, wb), mode="bilinear", align_corners=False)
        h = self.inp(z) + self.ray_proj(rays)
        obs = None
        if self.detail is not None and latent.shape[1] > d:
            detail = latent[:, d:]
            if self.copy_gate is not None:
                detail, obs = detail[:, :-OBSERVED_CHANNELS], detail[:, -OBSERVED_CHANNELS:]
            h = h + self.detail(detail)
        out = self.head(self.body(h))
        if obs is not None:
            out = self._copy_observed(out, obs)
        return out.flatten(2).transpose(1, 2)

    def _copy_observed(self, out: Tensor, obs: Tensor) -> Tensor:
        """out: (M, C, Hb, Wb) head output; obs: (M, 6, Hb, Wb) -> out with the SH DC colour and the depth
        channel of visible blocks moved towards the observed colour and depth by the learned gate."""
        cfg = self.cfg
        g = torch.sigmoid(self.copy_gate)
        frac = ((obs[:, 3:4] - cfg.d_min) / (cfg.d_max - cfg.d_min)).clamp(1e-3, 1.0 - 1e-3)
        return copy_into_head(out, obs[:, :3], g[0] * obs[:, 4:5], torch.logit(frac), g[1] * obs[:, 5:6],
                              cfg.sh_degree)


OBSERVED_CHANNELS = 6  # observed block colour (3), planar depth (1), colour and depth visibility (1 + 1)


def masked_block_mean(x: Tensor, weight: Tensor, k: int) -> tuple[Tensor, Tensor]:
    """x: (M, C, H, W); weight: (M, 1, H, W) in [0, 1] -> the weighted mean of every k×k block
    (M, C, H/k, W/k) and the block's mean weight (M, 1, H/k, W/k) (0 where nothing counts)."""
    w = F.avg_pool2d(weight, k)
    return F.avg_pool2d(x * weight, k) / w.clamp_min(1e-6), w


def observed_blocks(rgb: Tensor, depth: Tensor | None, hidden: Tensor, k: int) -> Tensor:
    """What a background block observes where nothing hides it.

    rgb: (M, 3, H, W); depth: (M, 1, H, W) metres (0 = none) or None; hidden: (M, 1, H, W) 1 = hidden;
    k: block size -> (M, 6, H/k, W/k): mean colour, mean planar depth, and 1 where every pixel of the block is
    visible (colour) / visible with depth (depth), else 0.
    """
    keep = 1.0 - hidden
    colour, w = masked_block_mean(rgb, keep, k)
    if depth is None:
        dep, wd = torch.zeros_like(w), torch.zeros_like(w)
    else:
        dep, wd = masked_block_mean(depth, keep * (depth > 0).to(rgb.dtype), k)
    return torch.cat([colour, dep, (w > 0.999).to(rgb.dtype), (wd > 0.999).to(rgb.dtype)], dim=1)


def _finish(p: dict[str, Tensor], pix: Tensor, zeta: Tensor, jac_px: Tensor, K: Tensor, c2w: Tensor,
            opacity: Tensor, cfg: ModelConfig, depth_cell: Tensor | None = None) -> dict[str, Tensor]:
    """Lift image-plane Gaussians to the world.

    pix: (..., 2) pixel centres; zeta: (...) planar depth; jac_px: (..., 2) pixels per canonical unit;
    K: (..., 3, 3), c2w: (..., 4, 4) broadcast per Gaussian; opacity: (...) final α; depth_cell: (...)
    metres per canonical unit along the camera axis, at least a pixel's width (default: a pixel's width).
    """
    dirs = ray_dirs(pix[..., None, :], K, c2w)[..., 0, :]
    means = c2w[..., :3, 3] + zeta[..., None] * dirs
    fx = K[..., 0, 0]
    fy = K[..., 1, 1]
    jac_z = zeta / fx if depth_cell is None else torch.maximum(zeta / fx, depth_cell)
    jac = torch.stack([jac_px[..., 0] * zeta / fx, jac_px[..., 1] * zeta / fy, jac_z], dim=-1)
    s = cfg.s_min + (cfg.s_max - cfg.s_min) * torch.sigmoid(p["scale"])
    M = camera_covariance_factor(p["quat"], s, jac)
    M_world = c2w[..., :3, :3] @ M
    quats, scales = covariance_to_quat_scale(M_world)
    sh = rotate_sh_to_world(p["sh"], c2w[..., :3, :3])  # c2w already broadcasts over the Gaussians
    return {"means": means, "quats": quats, "scales": scales, "opacities": opacity, "sh": sh}


def cell_fourier_features(S: int, octaves: int = 4) -> Tensor:
    """(S*S, 4 * octaves) sin and cos of 2^k π x and 2^k π y (k < octaves) at an S×S patch's cell centres
    (x, y in [-1, 1]), row-major (y, x) order."""
    xy = cell_centres(S, None, torch.float32) * 2.0 - 1.0
    angles = xy[:, :, None] * (math.pi * 2.0 ** torch.arange(octaves, dtype=torch.float32))
    return torch.cat([angles.sin(), angles.cos()], dim=-1).reshape(S * S, 4 * octaves)


def cell_centres(S: int, device, dtype) -> Tensor:
    """(S*S, 2) centres (x, y) of an S×S patch's cells in [0, 1], row-major (y, x) order."""
    ar = (torch.arange(S, device=device, dtype=dtype) + 0.5) / S
    gy, gx = torch.meshgrid(ar, ar, indexing="ij")
    return torch.stack([gx, gy], dim=-1).reshape(S * S, 2)


def foreground_gaussians(raw: Tensor, z_p: Tensor, z_s: Tensor, z_d: Tensor, z_e: Tensor, z_t: Tensor, K: Tensor,
                         c2w: Tensor, cfg: ModelConfig) -> dict[str, Tensor]:
    """Steps 2-3 for M particles.

    raw: (M, N, C) canonical patch parameters (N = S*S, row-major cells; 2*S*S with ``patch_back``);
    z_p: (M, 2) in [-1, 1]; z_s: (M, 2), z_d: (M, 1), z_e: (M, 1) pre-sigmoid; z_t: (M, 1) in [0, 1];
    K: (M, 3, 3) and c2w: (M, 4, 4) of each particle's view. Returns Gaussian fields with leading dims (M, N).

    A back Gaussian sits on its front Gaussian's ray, σ(its depth channel) x the particle box's width
    (metres, at the front depth) further away: the far side of the object along the context view's ray,
    which the view cannot see. Its offset channels are unused; the rest are its own.
    """
    S = cfg.patch_gaussians
    H = W = cfg.resolution
    p = split_gaussian_params(raw[:, :S * S], cfg.sh_degree)
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
    out = _lift_cells(p, pix, zeta, jac_px, z_t * torch.sigmoid(p["opacity"][..., 0]), K, c2w, cfg)
    if not cfg.patch_back:
        return out
    pb = split_gaussian_params(raw[:, S * S:], cfg.sh_degree)
    box = jac_px.mean(-1) * S * zeta / K[:, 0, 0, None]  # (M, N) the particle box's width in metres
    zeta_back = zeta + torch.sigmoid(pb["dd"][..., 0]) * box
    back = _lift_cells(pb, pix, zeta_back, jac_px, z_t * torch.sigmoid(pb["opacity"][..., 0]), K, c2w, cfg)
    return {k: torch.cat([out[k], back[k]], dim=1) for k in out}


def _lift_cells(p: dict[str, Tensor], pix: Tensor, zeta: Tensor, jac_px: Tensor, opacity: Tensor, K: Tensor,
                c2w: Tensor, cfg: ModelConfig) -> dict[str, Tensor]:
    """Lift N cells of M particles: p split head output, pix (M, N, 2) pixels, zeta (M, N) planar metres,
    jac_px (M, 1, 2) pixels per canonical cell, opacity (M, N); K (M, 3, 3), c2w (M, 4, 4)."""
    N = pix.shape[1]
    Kn = K[:, None].expand(-1, N, -1, -1)
    cn = c2w[:, None].expand(-1, N, -1, -1)
    # "cell": canonical cells are cubes (as deep as they are wide), so a particle's Gaussians have volume and
    # do not turn into slivers seen from the side
    depth_cell = None
    if cfg.particle_depth_scale == "cell":
        fx = K[:, 0, 0, None]
        depth_cell = jac_px.mean(-1) * zeta / fx
    return _finish(p, pix, zeta, jac_px.expand(-1, N, -1), Kn, cn, opacity, cfg, depth_cell)


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


def background_gaussians(raw: Tensor, K: Tensor, c2w: Tensor, cfg: ModelConfig) -> dict[str, Tensor]:
    """raw: (M, Hb*Wb, C) per-block parameters; K: (M, 3, 3); c2w: (M, 4, 4) -> fields with dims (M, Hb*Wb).

    Pixel-aligned: a block centre plus a bounded sub-block offset; depth ζ = d_min + σ(·)(d_max − d_min)
    from the depth-residual channel; opacity σ(o) (no transparency gate).
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
    return _finish(p, pix, zeta, jac_px, Kn, cn, opacity, cfg)
