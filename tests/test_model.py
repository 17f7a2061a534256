"""Model tests: decoder geometry against analytic truth, subset decoding, the scene API, KL terms, checkpoints."""

from __future__ import annotations

import math
from dataclasses import fields, replace

import pytest
import torch
from model_data import TINY_MODEL

from particlesplat.core.camera import Camera
from particlesplat.core.gaussians import Gaussians
from particlesplat.core.sh import eval_sh_colors
from particlesplat.model import ConfigError, ModelConfig, ParticleSplat, load_config, load_model, save_checkpoint
from particlesplat.model.decoder import foreground_gaussians, gaussian_channels
from particlesplat.model.geometry import covariance_to_quat_scale, ray_dirs, rotate_sh_to_world, stack_cameras
from particlesplat.model.losses import kl_beta, kl_normal, scene_kl, view_error
from particlesplat.model.posterior import ParticlePosterior, Posterior

TINY = TINY_MODEL  # the recipe's model, shrunk
PER_VIEW = dict(bg_per_view=True, bg_static_grid=0)  # the per-view background alone (no shared floor)


def tiny_model(seed: int = 0, **kw) -> ParticleSplat:
    torch.manual_seed(seed)
    return ParticleSplat(ModelConfig(**{**TINY, **kw})).eval()


def cams(n: int = 2, size: int = 32) -> list[Camera]:
    return [Camera.orbit((0.0, 0.0, 0.15), az, 30.0, 3.3, width=size, height=size) for az in (-30, 25, 0, 50)[:n]]


def random_rotation(gen: torch.Generator) -> torch.Tensor:
    q, _ = torch.linalg.qr(torch.randn(3, 3, generator=gen, dtype=torch.float64))
    return q * torch.sign(torch.linalg.det(q))


# ------------------------------------------------------------------ geometry
def test_covariance_factorisation_round_trip():
    gen = torch.Generator().manual_seed(1)
    M = torch.randn(200, 3, 3, generator=gen, dtype=torch.float64)
    M[:5] = torch.diag(torch.tensor([0.2, 0.2, 0.05], dtype=torch.float64))  # repeated eigenvalues
    q, s = covariance_to_quat_scale(M)
    g = Gaussians(
        torch.zeros(200, 3, dtype=torch.float64),
        q,
        s,
        torch.ones(200, dtype=torch.float64),
        torch.zeros(200, 1, 3, dtype=torch.float64),
        torch.zeros(200, dtype=torch.int64),
    )
    torch.testing.assert_close(g.covariances(), M @ M.transpose(-1, -2), rtol=1e-9, atol=1e-10)


def test_covariance_factorisation_gradient_is_the_identity_map():
    """Σ -> (q, s) -> R diag(s²) Rᵀ is the identity, so its vector-Jacobian product is the incoming gradient."""
    gen = torch.Generator().manual_seed(2)
    M = torch.randn(20, 3, 3, generator=gen, dtype=torch.float64, requires_grad=True)
    W = torch.randn(20, 3, 3, generator=gen, dtype=torch.float64)
    q, s = covariance_to_quat_scale(M)
    g = Gaussians(
        torch.zeros(20, 3, dtype=torch.float64),
        q,
        s,
        torch.ones(20, dtype=torch.float64),
        torch.zeros(20, 1, 3, dtype=torch.float64),
        torch.zeros(20, dtype=torch.int64),
    )
    (g.covariances() * W).sum().backward()
    Md = M.detach().requires_grad_(True)
    ((Md @ Md.transpose(-1, -2)) * W).sum().backward()
    torch.testing.assert_close(M.grad, Md.grad, rtol=1e-6, atol=1e-8)


def test_keep_lifts_each_particles_most_opaque_gaussians_as_they_draw():
    """``keep`` = k: the k most opaque of each particle's Gaussians, chosen before the lift, equal the full lift
    with each particle's k largest opacities picked afterwards (brute force), also where ``support_cut`` has
    zeroed Gaussians that lie below the support surface."""
    cfg = replace(ModelConfig(**TINY), support_cut=0.0)
    S = cfg.patch_gaussians
    K, c2w = stack_cameras(cams(1))
    M = 3
    gen = torch.Generator().manual_seed(4)
    raw = torch.randn(M, 2 * S * S, gaussian_channels(0), generator=gen)
    z = dict(
        z_p=torch.rand(M, 2, generator=gen) - 0.5,
        z_s=torch.randn(M, 2, generator=gen),
        z_d=torch.full((M, 1), -1.0),  # with a wide depth range, a third fall below the floor
        z_e=torch.full((M, 1), 3.0),
        z_t=torch.rand(M, 1, generator=gen),
    )
    Km, cm = K.expand(M, 3, 3), c2w.expand(M, 4, 4)
    full = foreground_gaussians(raw, **z, K=Km, c2w=cm, cfg=cfg)
    below = full["means"][..., 2] < 0
    assert bool(below.any()) and bool((full["opacities"][below] == 0).all())
    k = S * S // 2
    assert bool(((full["opacities"] > 0).sum(1) > k).all())  # no ties at zero among the k chosen
    kept = foreground_gaussians(raw, **z, K=Km, c2w=cm, cfg=cfg, keep=k)
    picked_before_cut = []
    for i in range(M):
        rows = sorted(torch.argsort(full["opacities"][i], descending=True, stable=True)[:k].tolist())
        for name in ("means", "quats", "scales", "opacities", "sh"):
            torch.testing.assert_close(kept[name][i], full[name][i, rows])
        pre_cut = z["z_t"][i] * torch.sigmoid(raw[i, :, -1])
        picked_before_cut.append(sorted(pre_cut.topk(k).indices.tolist()) == rows)
    assert not all(picked_before_cut)  # the cut changed which Gaussians count as most opaque


def test_sh_rotation_degree_one_matches_rotated_directions():
    gen = torch.Generator().manual_seed(3)
    sh = torch.randn(50, 4, 3, generator=gen, dtype=torch.float64)
    R = random_rotation(gen)
    d = torch.nn.functional.normalize(torch.randn(50, 3, generator=gen, dtype=torch.float64), dim=-1)
    # keep colours above the clamp at 0 so the comparison is of the linear SH value
    sh[:, 0] = 10.0
    torch.testing.assert_close(eval_sh_colors(rotate_sh_to_world(sh, R), d @ R.T), eval_sh_colors(sh, d))


def test_foreground_lifting_matches_projection_and_jacobian():
    """Step 2-3 by hand: with zero head outputs the Gaussians sit at the cell centres of the particle's box,
    at planar depth d, and their covariance is (ζ/f)² J diag(s̄²) J in camera axes, where J's depth entry is
    the mean width of a canonical cell (cubic cells). The front layer (the first S*S Gaussians) is checked."""
    cfg = ModelConfig(**TINY)
    S = cfg.patch_gaussians
    cam = cams(1)[0]
    K, c2w = stack_cameras([cam])
    raw = torch.zeros(1, 2 * S * S, gaussian_channels(0))
    raw[..., 7] = 1.0  # quaternion w -> identity
    z_p = torch.tensor([[0.3, -0.2]])
    z_s = torch.logit(torch.tensor([[0.25, 0.4]]))
    z_d = torch.tensor([[0.1]])
    z_e = torch.tensor([[-1.0]])
    z_t = torch.tensor([[0.7]])
    f = {k: v[:, : S * S] for k, v in foreground_gaussians(raw, z_p, z_s, z_d, z_e, z_t, K, c2w, cfg).items()}
    W = cfg.resolution
    d = cfg.d_min + torch.sigmoid(z_d) * (cfg.d_max - cfg.d_min)
    cells = (torch.arange(S) + 0.5) / S * 2 - 1  # patch-normalised centres
    gy, gx = torch.meshgrid(cells, cells, indexing="ij")
    px = ((0.25 * gx + 0.3) + 1) / 2 * W
    py = ((0.4 * gy - 0.2) + 1) / 2 * W
    uv, z = cam.project(f["means"][0])
    torch.testing.assert_close(uv, torch.stack([px, py], -1).reshape(-1, 2), rtol=1e-4, atol=1e-4)
    torch.testing.assert_close(z, d.reshape(1).expand(S * S), rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(f["opacities"][0], torch.full((S * S,), 0.7 * 0.5))
    s_bar = cfg.s_min + 0.5 * (cfg.s_max - cfg.s_min)
    fx = float(cam.K[0, 0])
    depth_px = (0.25 + 0.4) / 2 * W / S
    jac = torch.tensor([0.25 * W / S, 0.4 * W / S, depth_px]) * float(d) / fx
    expect = torch.diag((jac * s_bar) ** 2)
    g = Gaussians(
        f["means"][0],
        f["quats"][0],
        f["scales"][0],
        f["opacities"][0],
        f["sh"][0],
        torch.zeros(S * S, dtype=torch.int64),
    )
    R = cam.R
    cov_cam = R.T @ g.covariances() @ R
    torch.testing.assert_close(cov_cam, expect.expand(S * S, 3, 3), rtol=1e-4, atol=1e-6)


def test_back_layer_sits_behind_the_front_on_the_same_ray():
    """The back layer: with zero head outputs (σ = 0.5) each back Gaussian projects onto its front Gaussian's
    pixel, half the particle box's width (σ(z_s) W / f · ζ, metres, along x and y averaged) deeper; its
    opacity is z_t σ(its own opacity logit), and the front layer does not depend on the back cells' parameters."""
    cfg = ModelConfig(**TINY)
    S = cfg.patch_gaussians
    cam = cams(1)[0]
    K, c2w = stack_cameras([cam])
    gen = torch.Generator().manual_seed(3)
    raw = torch.randn(1, 2 * S * S, gaussian_channels(0), generator=gen) * 0.3
    raw[:, S * S :, 5] = 0.0  # back depth channel -> σ = 0.5
    z = dict(
        z_p=torch.tensor([[0.1, 0.2]]),
        z_s=torch.logit(torch.tensor([[0.3, 0.2]])),
        z_d=torch.tensor([[0.2]]),
        z_e=torch.tensor([[-1.0]]),
        z_t=torch.tensor([[0.8]]),
    )
    f = foreground_gaussians(raw, **z, K=K, c2w=c2w, cfg=cfg)
    other = raw.clone()
    other[:, S * S :] = torch.randn(1, S * S, gaussian_channels(0), generator=gen)
    moved = foreground_gaussians(other, **z, K=K, c2w=c2w, cfg=cfg)
    assert f["means"].shape == (1, 2 * S * S, 3)
    for k in f:
        torch.testing.assert_close(moved[k][:, : S * S], f[k][:, : S * S], rtol=0, atol=0)
        assert not torch.equal(moved[k][:, S * S :], f[k][:, S * S :]), k
    uv_f, z_f = cam.project(f["means"][0, : S * S])
    uv_b, z_b = cam.project(f["means"][0, S * S :])
    torch.testing.assert_close(uv_b, uv_f, rtol=1e-4, atol=1e-4)
    box = (0.3 + 0.2) / 2 * cfg.resolution / float(cam.K[0, 0]) * z_f
    torch.testing.assert_close(z_b - z_f, 0.5 * box, rtol=1e-4, atol=1e-5)
    torch.testing.assert_close(f["opacities"][0, S * S :], 0.8 * torch.sigmoid(raw[0, S * S :, -1]))
    m = ParticleSplat(cfg)
    assert m.fg_decoder(torch.zeros(3, cfg.d_obj)).shape == (3, 2 * S * S, gaussian_channels(0))
    assert cfg.gaussians_per_particle == 2 * S * S


def test_ray_dirs_match_camera_rays():
    cam = cams(1)[0]
    K, c2w = stack_cameras([cam])
    uv = torch.rand(1, 10, 2) * 32
    _, d = cam.rays(uv[0])
    torch.testing.assert_close(ray_dirs(uv, K, c2w)[0], d, rtol=1e-5, atol=1e-6)


# ------------------------------------------------------------------ the scene API
def scene_inputs(n_views: int = 2, size: int = 32):
    gen = torch.Generator().manual_seed(5)
    rgb = torch.rand(n_views, 3, size, size, generator=gen)
    depth = 2.5 + torch.rand(n_views, 1, size, size, generator=gen)
    return rgb, depth, cams(n_views, size)


@pytest.mark.parametrize("n_views,with_depth", [(2, True), (1, True), (2, False), (1, False)])
def test_encode_shapes(n_views, with_depth):
    m = tiny_model()
    rgb, depth, cs = scene_inputs(n_views)
    p = m.encode(rgb, depth if with_depth else None, cs)
    L = n_views * m.config.particles_per_view
    assert p.z_p.shape == (L, 2) and p.z_s.shape == (L, 2) and p.z_d.shape == (L, 1)
    assert p.z_e.shape == (L, 1) and p.z_t.shape == (L, 1) and p.z_f.shape == (L, m.config.d_obj)
    assert p.view.tolist() == sorted(p.view.tolist()) and int(p.view.max()) == n_views - 1
    assert p.background.shape == (n_views, m.config.d_bg, 4, 4)
    assert bool(((p.z_t >= 0) & (p.z_t <= 1)).all())
    g = m.decode(p, z_t_threshold=0.0)
    S2 = m.config.gaussians_per_particle
    assert S2 == 2 * 4 * 4  # a front and a back Gaussian per cell of the 4x4 patch
    assert len(g) == L * S2 + 16 * 16  # the particles and the static floor layer
    assert torch.isfinite(g.means).all() and torch.isfinite(g.scales).all()


def test_encode_rejects_wrong_size():
    m = tiny_model()
    rgb, depth, cs = scene_inputs(2, 16)
    with pytest.raises(ValueError, match="32x32"):
        m.encode(rgb, depth, cs)


@pytest.mark.parametrize("kw", [{}, PER_VIEW], ids=["recipe", "per-view bg"])
def test_subset_decode_equals_full_decode_restricted(kw):
    m = tiny_model(**kw)
    rgb, depth, cs = scene_inputs(2)
    p = m.encode(rgb, depth, cs)
    full = m.decode(p, z_t_threshold=0.0)
    idx = torch.tensor([4, 1])
    sub = m.decode(p, idx, background=False, z_t_threshold=0.0)
    assert sorted(set(sub.owner.tolist())) == [1, 4]
    assert len(sub) == 2 * m.config.gaussians_per_particle
    for i in (1, 4):
        a, b = full.of_owner(i), sub.of_owner(i)
        for name in ("means", "opacities", "sh"):
            torch.testing.assert_close(getattr(b, name), getattr(a, name))
        # cubic cells give covariances with repeated eigenvalues, whose rotation the batched eigh may pick
        # differently: compare the covariances themselves
        torch.testing.assert_close(b.covariances(), a.covariances(), rtol=1e-5, atol=1e-8)
    n_bg = 2 * (32 // m.config.bg_block) ** 2 if m.config.bg_per_view else 16 * 16
    assert (full.owner == -1).sum() == n_bg
    assert not bool((sub.owner == -1).any())


def test_decode_thresholds_prune():
    m = tiny_model()
    rgb, depth, cs = scene_inputs(2)
    p = m.encode(rgb, depth, cs)
    p = p.with_attribute(0, "z_t", [0.05]).with_attribute(2, "z_t", [0.9])
    g = m.decode(p, z_t_threshold=0.1)
    assert 0 not in g.owner.tolist() and 2 in g.owner.tolist()
    full = m.decode(p)
    thr = float(full.opacities.median())
    g2 = m.decode(p, opacity_threshold=thr)
    assert len(g2) == int((full.opacities >= thr).sum()) and bool((g2.opacities >= thr).all())


def test_decode_keeps_each_particles_most_opaque_gaussians():
    m = tiny_model()
    rgb, depth, cs = scene_inputs(2)
    p = m.encode(rgb, depth, cs)
    full = m.decode(p, z_t_threshold=0.0)
    G, k = m.config.gaussians_per_particle, 5
    kept = m.decode(p, z_t_threshold=0.0, max_per_particle=k)
    bg = full.owner < 0
    assert torch.equal(kept.of_owner(-1).means, full.subset(bg).means)  # the background is untouched
    for i in range(p.num):
        own = full.opacities[full.owner == i].tolist()
        assert len(own) == G
        got = sorted(kept.opacities[kept.owner == i].tolist(), reverse=True)
        assert got == sorted(own, reverse=True)[:k]  # brute force: the k largest, each particle separately
    assert m.decode(p, z_t_threshold=0.0, max_per_particle=G + 1).means.shape == full.means.shape
    with pytest.raises(ValueError, match="max_per_particle"):
        m.decode(p, max_per_particle=0)

    # the batched decode the refinement renders prunes the same way, scene by scene
    z = {k: getattr(p, k)[None] for k in ("z_p", "z_s", "z_d", "z_e", "z_t", "z_f")}
    z["bg"] = p.background[None]
    K, c2w = stack_cameras(p.cameras)
    (batched,) = m.decode_batch(z, p.view, K[None], c2w[None], max_per_particle=k)
    for name in ("means", "quats", "scales", "opacities", "sh", "owner"):
        torch.testing.assert_close(getattr(batched, name), getattr(kept, name))


def test_edit_moves_only_that_particle():
    m = tiny_model()
    rgb, depth, cs = scene_inputs(2)
    p = m.encode(rgb, depth, cs)
    before = m.decode(p)
    moved = m.decode(p.with_attribute(3, "z_p", p.z_p[3] + torch.tensor([0.2, 0.0])))
    assert not torch.allclose(moved.of_owner(3).means, before.of_owner(3).means)
    torch.testing.assert_close(moved.of_owner([0, 1, 2, 4, 5, -1]).means, before.of_owner([0, 1, 2, 4, 5, -1]).means)


# ------------------------------------------------------------------ loss terms
def test_kl_terms_match_torch_distributions():
    mu, lv = torch.tensor([0.3, -1.0]), torch.tensor([-0.5, 0.2])
    ref = torch.distributions.kl_divergence(
        torch.distributions.Normal(mu, torch.exp(0.5 * lv)), torch.distributions.Normal(0.1, 0.4)
    )
    torch.testing.assert_close(kl_normal(mu, lv, 0.1, 0.4), ref)
    a, b = torch.tensor([0.7, 3.0], dtype=torch.float64), torch.tensor([2.0, 0.4], dtype=torch.float64)
    ref = torch.distributions.kl_divergence(
        torch.distributions.Beta(a, b),
        torch.distributions.Beta(torch.tensor(0.01, dtype=torch.float64), torch.tensor(0.01, dtype=torch.float64)),
    )
    torch.testing.assert_close(kl_beta(a, b, 0.01, 0.01), ref)


def test_scene_kl_masks_geometry_but_not_transparency():
    m = tiny_model()
    rgb, depth, cs = scene_inputs(2)
    K, c2w = stack_cameras(cs)
    post = m.posterior(rgb[None], depth[None], K[None], c2w[None])
    cfg = m.config
    zero = scene_kl(post, torch.zeros(1, 6, 1), cfg, beta_f=1.0)
    t_only = kl_beta(post.beta_a, post.beta_b, cfg.prior_t_a, cfg.prior_t_b).sum()
    # the background latents count only where they are decoded (bg_per_view)
    bg = kl_normal(post.mu_bg, post.lv_bg, 0.0, 1.0).sum() if cfg.bg_per_view else torch.zeros(())
    torch.testing.assert_close(zero, (t_only + bg)[None])
    one = scene_kl(post, torch.ones(1, 6, 1), cfg, beta_f=0.5)
    geo = (
        kl_normal(post.mu_o, post.lv_o, 0.0, cfg.prior_offset_std).sum()
        + kl_normal(post.mu_s, post.lv_s, cfg.logit_prior_scale, cfg.prior_scale_std).sum()
        + kl_normal(post.mu_d, post.lv_d, 0.0, 1.0).sum()
        + kl_normal(post.mu_e, post.lv_e, cfg.logit_prior_extent, cfg.prior_extent_std).sum()
    )
    feat = kl_normal(post.mu_f, post.lv_f, 0.0, 1.0).sum()
    torch.testing.assert_close(one, (geo + 0.5 * feat + t_only + 0.5 * bg)[None], rtol=1e-5, atol=1e-3)
    per_view = replace(cfg, bg_per_view=True)
    torch.testing.assert_close(
        scene_kl(post, torch.zeros(1, 6, 1), per_view, beta_f=1.0),
        (t_only + kl_normal(post.mu_bg, post.lv_bg, 0.0, 1.0).sum())[None],
    )


def test_view_error_ignores_unsupervised_and_depthless_pixels():
    rgb = torch.zeros(1, 3, 4, 4)
    hat = torch.zeros(1, 3, 4, 4)
    hat[..., 0, 0] = 1.0  # wrong pixel, unsupervised
    mask = torch.ones(1, 1, 4, 4)
    mask[..., 0, 0] = 0
    depth = torch.full((1, 1, 4, 4), 2.0)
    depth[..., 1, 1] = 0.0  # no ground truth here
    dhat = torch.full((1, 1, 4, 4), 2.0)
    dhat[..., 1, 1] = 9.0
    dhat[..., 2, 2] = 3.0
    err = view_error(hat, rgb, dhat, depth, mask, lambda_depth=0.5)
    torch.testing.assert_close(err, torch.tensor([0.5]))


# ------------------------------------------------------------------ config and checkpoints
def test_config_errors_name_file_and_key(tmp_path):
    p = tmp_path / "c.yaml"
    p.write_text("model:\n  resolution: 64\n  particles: 3\n")
    with pytest.raises(ConfigError, match=r"c\.yaml: model: unknown key\(s\) particles"):
        load_config(p)
    p.write_text("model:\n  resolution: 60\n")
    with pytest.raises(ConfigError, match="model.resolution"):
        load_config(p)
    p.write_text("train:\n  lr: fast\n")
    with pytest.raises(ConfigError, match="train.lr"):
        load_config(p)


def test_checkpoint_round_trip_and_errors(tmp_path):
    m = tiny_model(seed=3)
    path = tmp_path / "m.pt"
    save_checkpoint(path, m, step=7)
    m2 = load_model(path)
    assert m2.config == m.config
    rgb, depth, cs = scene_inputs(2)
    a, b = m.decode(m.encode(rgb, depth, cs)), m2.decode(m2.encode(rgb, depth, cs))
    torch.testing.assert_close(a.means, b.means)
    with pytest.raises(FileNotFoundError, match="nope.pt"):
        load_model(tmp_path / "nope.pt")
    torch.save({"config": {}, "step": 1}, tmp_path / "bad.pt")
    with pytest.raises(ValueError, match="bad.pt: checkpoint has no 'state_dict'"):
        load_model(tmp_path / "bad.pt")


def test_shipped_model_loads_and_matches_its_yaml():
    """The shipped checkpoint's config (written flat, with keys of removed branches) is the nested recipe's."""
    from particlesplat.core.bundled import bundled_assets

    m = load_model()
    shipped = load_config(bundled_assets() / "recipe.yaml")[0]
    # the one setting that differs: the shipped checkpoint hides what hangs more than 1 cm under the floor at
    # decode (its recipe trains without the cut; the weights do not depend on it)
    assert m.config.support_cut == 0.01 and shipped.support_cut == -1.0
    assert replace(m.config, support_cut=-1.0) == shipped
    size = m.config.resolution
    rgb, depth, _ = scene_inputs(2, size)
    p = m.encode(rgb, depth, cams(2, size))
    assert math.isfinite(float(m.decode(p).means.sum()))


def test_keypoint_filter_prefers_low_score_and_spreads_out():
    from particlesplat.model.encoder import select_keypoints

    kp = torch.tensor([[[0.0, 0.0], [0.1, 0.0], [0.5, 0.5], [-0.6, 0.2], [0.52, 0.5]]])
    var = torch.tensor([[1.0, 0.5, 2.0, 3.0, 1.5]])
    # lowest variance first (index 1); index 0 is within 0.25 of it, so 4, then 3 come next; 0 and 2 last
    assert select_keypoints(kp, var, 3, 0.25).tolist() == [[1, 4, 3]]
    assert select_keypoints(kp, var, 5, 0.25).tolist() == [[1, 4, 3, 0, 2]]
    assert select_keypoints(kp, var, 3, 0.0).tolist() == [[1, 0, 4]]


def test_presence_logit_seeds_the_transparency_of_the_kept_proposals():
    """The kept proposals are the patches with the largest background residual (spread by NMS), and their
    transparency grows with the proposal's presence logit."""
    m = tiny_model()
    enc = m.encoder
    rgb, depth, cs = scene_inputs(1)
    K, c2w = stack_cameras(cs)
    from particlesplat.model.encoder import depth_input, plucker_map

    dep = depth_input(depth, rgb, m.config)
    rays = plucker_map(K, c2w, 32, 32)
    kp0, _ = enc.proposals(enc.backbone(rgb, dep, rays))
    presence = torch.zeros(1, 64)
    presence[0, [5, 40, 63]] = torch.tensor([3.0, 6.0, 9.0])
    residual = torch.zeros(1, 64)
    residual[0, [5, 40, 63]] = torch.tensor([1.0, 2.0, 3.0])
    enc.proposals = lambda feats: (kp0, presence)
    with torch.no_grad():
        att, _ = enc.attributes(rgb, dep, rays, residual)
    assert torch.equal(att.kp[0], kp0[0, [63, 40, 5]])
    t = (att.beta_a / (att.beta_a + att.beta_b))[0, :, 0]
    shift = att.beta_a - att.beta_b
    assert bool((shift[0, 0] > shift[0, 2]).all()) and float(t[0]) > float(t[2])


def test_residual_selection_puts_particles_where_the_background_fails():
    """A constant grey background explains a grey image except two coloured squares: the residual is
    largest on their patches and the kept keypoints land in them first."""
    m = tiny_model(**PER_VIEW, particles_per_view=2)
    with torch.no_grad():
        m.bg_decoder.head.weight.zero_()  # colour = SH DC bias -> 0.5 grey everywhere
    rgb = torch.full((1, 3, 32, 32), 0.5)
    rgb[0, :, 4:8, 20:24] = torch.tensor([0.9, 0.1, 0.1])[:, None, None]
    rgb[0, :, 24:28, 8:12] = torch.tensor([0.1, 0.1, 0.9])[:, None, None]
    cs = cams(1)
    K, c2w = stack_cameras(cs)
    from particlesplat.model.encoder import depth_input, plucker_map

    dep = depth_input(None, rgb, m.config)
    rays = plucker_map(K, c2w, 32, 32)
    err = m.coarse_background_error(rgb, None, dep, rays, K, c2w)  # the plain background's error per block
    res = torch.nn.functional.adaptive_avg_pool2d(err, 8).flatten(1)  # per 4x4 keypoint patch
    assert res.shape == (1, 64)
    top = set(res[0].topk(2).indices.tolist())
    assert top == {1 * 8 + 5, 6 * 8 + 2}
    post = m.posterior(rgb[None], None, K[None], c2w[None])
    pix = (post.kp[0] + 1) / 2 * 32
    cells = {(int(p[1]) // 4) * 8 + int(p[0]) // 4 for p in pix}
    assert cells == top


def _floor_depth(cam: Camera) -> torch.Tensor:
    """(1, H, W) planar depth of the floor z = 0 at every pixel centre (analytic ray-plane hit)."""
    v, u = torch.meshgrid(torch.arange(cam.height) + 0.5, torch.arange(cam.width) + 0.5, indexing="ij")
    K, c2w = cam.K.double(), cam.c2w.double()
    d_cam = torch.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], torch.ones_like(u)], -1).double()
    d_world = d_cam @ c2w[:3, :3].T
    return (-c2w[2, 3] / d_world[..., 2]).float()[None]


# ------------------------------------------------------------------ the static background layer
STATIC = dict(bg_static_grid=24, bg_static_extent=2.25, bg_per_view=False)


def test_static_layer_is_flat_discs_covering_the_floor_square():
    m = tiny_model(**STATIC)
    f = m.static_bg()
    n = 24 * 24
    assert f["means"].shape == (n, 3) and f["sh"].shape == (n, 1, 3)
    assert bool((f["means"][:, 2] == 0).all())
    cell = 2 * 2.25 / 24
    assert float(f["means"][:, :2].abs().max()) == pytest.approx(2.25 - cell / 2)
    assert bool((f["scales"][:, 2] < 0.1 * f["scales"][:, 0]).all())  # flat, lying in the plane
    # with SH degree 1 the higher bases are zero: the colour does not depend on the view
    f1 = tiny_model(**STATIC, sh_degree=1).static_bg()
    assert f1["sh"].shape == (n, 4, 3) and bool((f1["sh"][:, 1:] == 0).all())


def test_static_layer_renders_the_floor_plane_with_its_colour_and_depth():
    """An opaque layer of one colour: the central pixels take that colour (overlapping discs leave < 0.6 %
    transmittance) and about the planar depth of the analytic floor z = 0. A render's depth is that of the
    disc centres, the nearer discs weighing most, so it lies in front of the floor by less than the discs'
    reach along the plane (3 sigma; depth changes by at most 1 m per metre along it)."""
    from particlesplat.core.sh import rgb_to_sh_dc
    from particlesplat.rendering.api import render

    m = tiny_model(**{**STATIC, "bg_static_grid": 48})
    with torch.no_grad():
        m.static_bg.sh_dc.copy_(rgb_to_sh_dc(torch.tensor([0.2, 0.7, 0.4])).expand_as(m.static_bg.sh_dc))
        m.static_bg.opacity_logit.fill_(8.0)
    cam = cams(1)[0]
    g = m.decode(
        m.encode(*[t[:1] if t is not None else None for t in scene_inputs(1)[:2]], [cam]),
        torch.tensor([], dtype=torch.long),
    )
    assert len(g) == 48 * 48
    r = render(g, cam)
    centre = (slice(12, 20), slice(12, 20))
    torch.testing.assert_close(r.rgb[centre], torch.tensor([0.2, 0.7, 0.4]).expand(8, 8, 3), atol=6e-3, rtol=0)
    err = _floor_depth(cam)[0][centre] - r.depth[centre]
    assert bool((err > 0).all()) and float(err.max()) < 3 * float(m.static_bg.scales[0, 0])


def test_static_layer_error_is_zero_on_its_own_render_and_finds_an_object():
    """The layer's own render has no error; a block whose observed depth is 0.3 m nearer (an object) has
    exactly the squared depth difference on top of its colour error, and the residual selection puts a
    particle on it."""
    from particlesplat.rendering.api import render

    m = tiny_model(**STATIC, particles_per_view=1)
    cam = cams(1)[0]
    K, c2w = stack_cameras([cam])
    g = m.decode(m.encode(*[t[:1] for t in scene_inputs(1)[:2]], [cam]), torch.tensor([], dtype=torch.long))
    r = render(g, cam, background=m.background_color())
    rgb, depth = r.rgb.detach().permute(2, 0, 1)[None], r.depth.detach()[None, None]
    err = m.static_background_error(rgb, depth, K, c2w)
    assert err.shape == (1, 1, 8, 8) and float(err.abs().max()) < 1e-8
    obj_rgb, obj_depth = rgb.clone(), depth.clone()
    obj_depth[..., 20:24, 8:12] -= 0.3
    obj_rgb[..., 20:24, 8:12] = torch.tensor([0.9, 0.1, 0.1])[:, None, None]
    err = m.static_background_error(obj_rgb, obj_depth, K, c2w)
    colour = ((obj_rgb - rgb) ** 2).sum(1)[0, 20:24, 8:12].mean()
    assert float(err[0, 0, 5, 2]) == pytest.approx(float(colour) + 0.09, rel=1e-4)
    assert float(err[0, 0].flatten().topk(2).values[1]) < 1e-8  # nothing else
    post = m.posterior(obj_rgb[None], obj_depth[None], K[None], c2w[None])
    u, v = ((post.kp[0, 0] + 1) / 2 * 32).tolist()
    assert 8 <= u < 12 and 20 <= v < 24


def test_static_layer_config_and_decode():
    m = tiny_model(**STATIC)
    p = m.encode(*scene_inputs(2)[:2], cams(2))
    g = m.decode(p)
    assert int((g.owner == -1).sum()) == 24 * 24  # no per-view background
    both = tiny_model(bg_static_grid=24, bg_per_view=True)  # per-view background and the layer
    g2 = both.decode(both.encode(*scene_inputs(2)[:2], cams(2)))
    assert int((g2.owner == -1).sum()) == 24 * 24 + 2 * (32 // both.config.bg_block) ** 2
    assert tiny_model(**PER_VIEW).static_bg is None
    with pytest.raises(ConfigError, match=r"model\.background\.per_view: false needs a static background layer"):
        ModelConfig(**{**TINY, "bg_per_view": False, "bg_static_grid": 0}).validate()


def test_finer_patch_starts_from_the_base_patch_split_into_children():
    """S = 8 grown from patch_base 4 loads the weights of an S = 4 decoder; with a pointwise conv, every
    fine cell starts with exactly the parameters of the base cell it lies in (the doubling conv is zero)."""
    from particlesplat.model.decoder import ForegroundDecoder

    torch.manual_seed(0)
    coarse = ForegroundDecoder(ModelConfig(**{**TINY, "patch_gaussians": 4, "patch_base": 0}))
    with torch.no_grad():
        w = coarse.conv[1].weight
        w.zero_()
        w[:, :, 1, 1] = torch.randn(w.shape[:2])  # a 3x3 conv with only its centre tap: pointwise
        coarse.head.weight.normal_()
        coarse.back_head.weight.normal_()
    fine = ForegroundDecoder(ModelConfig(**{**TINY, "patch_gaussians": 8, "patch_base": 4}))
    missing = fine.load_state_dict(coarse.state_dict(), strict=False).missing_keys
    assert missing == ["up.0.weight", "up.0.bias"]
    z_f = torch.randn(3, TINY["d_obj"])
    base = coarse(z_f).reshape(3, 2, 4, 4, -1)  # front and back layers, each 4x4 cells
    want = base.repeat_interleave(2, dim=2).repeat_interleave(2, dim=3).reshape(3, 2 * 64, -1)
    torch.testing.assert_close(fine(z_f), want)
    with pytest.raises(ConfigError, match=r"model\.patch\.base"):
        ModelConfig(**{**TINY, "patch_gaussians": 8, "patch_base": 3}).validate()
    with pytest.raises(ConfigError, match=r"model\.patch\.channels"):
        ModelConfig(**{**TINY, "patch_channels": 2}).validate()


@pytest.mark.parametrize("recipe", ["recipe.yaml", "robot/recipe.yaml"])
def test_shipped_yaml_documents_every_config_key(recipe):
    """Each recipe lists every ModelConfig key by its nested path (``background.block``) and every TrainConfig
    key, each with a comment (the file documents them)."""
    import re

    from particlesplat.core.bundled import bundled_assets
    from particlesplat.model.config import TrainConfig, model_key

    listed: dict[str, str] = {}  # "model.background.block" -> its line
    section = group = ""
    for ln in (bundled_assets() / recipe).read_text().splitlines():
        m = re.match(r"^( *)(\w+):(.*)$", ln)
        if not m:
            continue
        depth, name, rest = len(m.group(1)) // 2, m.group(2), m.group(3)
        if depth == 0:
            section, group = name, ""
        elif depth == 1 and rest.split("#")[0].strip() == "":
            group = name  # a group's header: its keys follow, indented
        else:
            listed[".".join(p for p in (section, group if depth == 2 else "", name) if p)] = ln
    want = [f"model.{model_key(f.name)}" for f in fields(ModelConfig)]
    want += [f"train.{f.name}" for f in fields(TrainConfig)]
    assert sorted(listed) == sorted(want)
    for key, line in listed.items():
        assert "#" in line, f"{recipe}: {key} has no comment"


def test_posterior_fields_have_the_documented_shapes():
    m = tiny_model()
    rgb, depth, cs = scene_inputs(2)
    K, c2w = stack_cameras(cs)
    post = m.posterior(rgb[None], depth[None], K[None], c2w[None])
    cfg = m.config
    L = cfg.particles_per_view
    widths = {"kp": 2, "mu_o": 2, "lv_o": 2, "mu_s": 2, "lv_s": 2, "mu_d": 1, "lv_d": 1, "mu_e": 1, "lv_e": 1}
    widths.update(beta_a=1, beta_b=1, mu_f=cfg.d_obj, lv_f=cfg.d_obj)
    assert isinstance(post, Posterior)
    assert [f.name for f in fields(ParticlePosterior)] == list(widths)
    for name, w in widths.items():
        assert tuple(getattr(post, name).shape) == (1, 2 * L, w), name
    h = cfg.resolution // cfg.bg_latent_stride
    assert tuple(post.mu_bg.shape) == tuple(post.lv_bg.shape) == (1, 2, cfg.d_bg, h, h)
    assert tuple(post.bg_mask.shape) == tuple(post.bg_error.shape) == (1, 2, 1, 32, 32)
    assert post.view.tolist() == [0] * L + [1] * L
    assert bool((post.beta_a > 0).all() and (post.beta_b > 0).all())
    torch.testing.assert_close(post.t_mean(), post.beta_a / (post.beta_a + post.beta_b))
    # replace: a new posterior of the same type with only the named fields changed; the original is untouched
    before = post.mu_d.clone()
    moved = post.replace(mu_d=post.mu_d + 1.0)
    assert type(moved) is Posterior and moved.mu_f is post.mu_f and moved.view is post.view
    assert torch.equal(moved.mu_d, before + 1.0) and torch.equal(post.mu_d, before)
