"""Amortised refinement (``refine_steps``): starts as the identity, sees the view beside the render of the current
means inside each particle's box, keeps its bounds, and trains end to end."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F
from test_model import TINY, scene_inputs, tiny_model

from particlesplat.model import ConfigError, ModelConfig
from particlesplat.model.refiner import BOX_MARGIN, _bounded_shift, box_glimpses
from particlesplat.rendering.api import render


def refined_pair(**kw):
    """A tiny model with refine_steps 1 and the same model without it, sharing every other weight."""
    plain = tiny_model(3, refine_steps=0, **kw)
    refined = tiny_model(4, refine_steps=1, refine_hidden=16, **kw)
    missing = refined.load_state_dict(plain.state_dict(), strict=False).missing_keys
    assert missing and all(k.startswith("refiner.") for k in missing)
    return plain, refined


def test_refinement_starts_as_the_identity_and_keeps_the_bounds():
    plain, refined = refined_pair()
    rgb, depth, cs = scene_inputs(2)
    a, b = plain.encode(rgb, depth, cs), refined.encode(rgb, depth, cs)
    for name in ("z_p", "z_s", "z_d", "z_e", "z_t", "z_f"):
        torch.testing.assert_close(getattr(b, name), getattr(a, name), rtol=0, atol=0)
    with torch.no_grad():
        refined.refiner.out.bias.fill_(5.0)  # a huge correction of every mean ...
        refined.refiner.out.bias[6] = 1.0  # ... but z_t's (its odds, in float32, stay measurable)
    c = refined.encode(rgb, depth, cs)
    cfg = refined.config
    centre = refined.encoder.scale_centre
    assert (c.z_s - a.z_s).abs().min() > 1e-3 and (c.z_f - a.z_f - 5.0).abs().max() < 1e-5
    assert bool(((c.z_s - centre).abs() <= cfg.scale_logit_bound + 1e-6).all())
    assert bool((c.z_t > a.z_t).all())  # Beta(a e, b / e): the mean's odds grow by e^2
    odds = lambda t: t / (1 - t)  # noqa: E731
    torch.testing.assert_close(odds(c.z_t.double()), odds(a.z_t.double()) * torch.e**2, rtol=1e-4, atol=0)
    assert (c.z_p - a.z_p).abs().max() <= 2 * cfg.offset_bound + 1e-6  # both within ±offset_bound of the keypoint


def test_bounded_shift_is_exact_at_zero_and_never_leaves_the_bound():
    value = torch.tensor([-0.99, -0.3, 0.0, 0.5, 1.0]) * 0.15
    torch.testing.assert_close(_bounded_shift(value, 0.0, 0.15, torch.zeros(5)), value, rtol=0, atol=0)
    for d in (-50.0, -1.0, 1.0, 50.0):
        moved = _bounded_shift(value, 0.0, 0.15, torch.full((5,), d))
        assert bool((moved.abs() <= 0.15 + 1e-7).all())
        assert bool(((moved - value) * d >= 0).all())  # it moves the way delta says


def test_box_glimpse_of_a_ramp_is_the_ramp_over_the_box():
    """An image whose value is its pixel x (channel 0) and y (channel 1) coordinate: the glimpse of a box shows
    the ramp between the box's edges (analytic, align_corners False)."""
    H = W = 32
    ys, xs = torch.meshgrid(torch.arange(H, dtype=torch.float64), torch.arange(W, dtype=torch.float64), indexing="ij")
    img = torch.stack([xs, ys])[None]
    centre = torch.tensor([[0.1, -0.2]], dtype=torch.float64)
    half = torch.tensor([[0.3, 0.5]], dtype=torch.float64)
    g = 8
    out = box_glimpses(img, centre, half, g)
    t = (2 * torch.arange(g, dtype=torch.float64) + 1) / g - 1  # glimpse sample positions in [-1, 1]
    want_x = ((centre[0, 0] + half[0, 0] * t + 1) * W - 1) / 2
    want_y = ((centre[0, 1] + half[0, 1] * t + 1) * H - 1) / 2
    torch.testing.assert_close(out[0, 0], want_x[None].expand(g, g))
    torch.testing.assert_close(out[0, 1], want_y[:, None].expand(g, g))


def pooled_behind(front, layer, f: int):
    """Brute force in float64: ``layer`` (a render of the static layer alone at full size) averaged over f x f
    pixel blocks (depth weighted by alpha) with the particles' render ``front`` (over black) composited over it
    -> (rgb (h, w, 3), depth (h, w), alpha (h, w))."""
    h, w = front.alpha.shape

    def blocks(t):  # (H, W, ...) -> mean over f x f blocks (h, w, ...)
        return t.double().reshape(h, f, w, f, *t.shape[2:]).mean(dim=(1, 3))

    a_b = blocks(layer.alpha)
    d_b = torch.where(a_b > 0, blocks(layer.alpha * layer.depth) / a_b, 0.0)
    a_f = front.alpha.double()
    rgb = front.rgb.double() + (1 - a_f)[..., None] * blocks(layer.rgb)
    alpha = a_f + (1 - a_f) * a_b
    depth = (a_f * front.depth.double() + (1 - a_f) * a_b * d_b) / alpha
    return rgb, depth, alpha


@pytest.mark.parametrize(
    ("scale", "keep", "static"),
    [(1.0, 0, "render"), (0.5, 0, "render"), (0.5, 3, "render"), (0.5, 0, "behind"), (0.25, 3, "behind")],
)
def test_refiner_sees_the_view_and_the_render_of_the_current_means(scale, keep, static):
    """The glimpses the refinement network reads equal an independent render of the plain model's decoded
    particles in their own view (colour, depth, alpha and the particle's own weight; at ``refine_scale`` of the
    view's size, through Camera.resized; each particle's ``refine_keep`` most opaque Gaussians) beside the
    observation, over each particle's box enlarged by BOX_MARGIN. With ``refine_static`` behind, the render is
    the particles alone over the static layer's full-size render averaged to that size."""
    plain, refined = refined_pair(refine_scale=scale, refine_keep=keep, refine_static=static)
    rgb, depth, cs = scene_inputs(2)
    seen = {}

    def spy(glimpses, latents):
        seen["g"] = glimpses
        return torch.zeros_like(latents)

    refined.refiner.forward = spy
    refined.encode(rgb, depth, cs)
    p = plain.encode(rgb, depth, cs)
    g = plain.decode(p, max_per_particle=keep or None)
    assert len(g.of_owner(0)) == (keep or plain.config.gaussians_per_particle)
    cfg = plain.config
    bg = plain.background_color()
    size = refined.config.glimpse_size
    N = p.num

    def glimpse(image, n):
        theta = torch.zeros(1, 2, 3)
        theta[0, 0, 0], theta[0, 1, 1] = (BOX_MARGIN * torch.sigmoid(p.z_s[n])).tolist()
        theta[0, :, 2] = p.z_p[n]
        grid = F.affine_grid(theta, [1, image.shape[0], size, size], align_corners=False)
        return F.grid_sample(image[None], grid, mode="bilinear", padding_mode="border", align_corners=False)[0]

    for n in range(N):
        v = int(p.view[n])
        small = cs[v].resized(int(cs[v].width * scale), int(cs[v].height * scale))
        assert small.width == cs[v].width * scale
        if static == "render":
            r = render(g, small, background=bg, owner_weights=True, num_owners=N)
            colour, dep, alpha = r.rgb, r.depth, r.alpha
        else:
            r = render(g.of_owner(list(range(N))), small, owner_weights=True, num_owners=N)
            layer = render(g.of_owner(-1), cs[v], background=bg)
            colour, dep, alpha = (t.float() for t in pooled_behind(r, layer, round(1 / scale)))
        observed = torch.cat([rgb[v], depth[v] / cfg.d_max, torch.ones_like(depth[v])])
        drawn = torch.cat([colour.permute(2, 0, 1), dep[None] / cfg.d_max, alpha[None], r.owner_weights[n][None]])
        want = torch.cat([glimpse(observed, n), glimpse(drawn, n)])
        assert seen["g"].shape[-1] == cfg.glimpse_size
        torch.testing.assert_close(seen["g"][n], want, rtol=1e-4, atol=1e-5)
    assert seen["g"][:, 10].amax() > 0.1  # particles see their own weight


def test_half_scale_refinement_render_lines_up_with_the_full_one():
    """A smooth scene rendered at half size, as the refinement does, and glimpsed over a box gives nearly the
    glimpse of the full-size render: the scaled intrinsics and the normalised boxes agree (a half-pixel slip
    of the smaller image triples the difference)."""
    from particlesplat.core.camera import Camera
    from particlesplat.core.gaussians import Gaussians
    from particlesplat.core.sh import rgb_to_sh_dc

    torch.manual_seed(0)
    n = 24
    g = Gaussians(
        torch.randn(n, 3) * 0.3,
        torch.tensor([[1.0, 0.0, 0.0, 0.0]]).repeat(n, 1),
        torch.full((n, 3), 0.12),
        torch.full((n,), 0.8),
        rgb_to_sh_dc(torch.rand(n, 3))[:, None],
        torch.zeros(n, dtype=torch.int64),
    )
    cam = Camera.look_at((0.0, -2.5, 1.5), (0.0, 0.0, 0.0), width=64, height=64)
    full = render(g, cam).rgb.permute(2, 0, 1)[None]
    half = render(g, cam.resized(32, 32)).rgb.permute(2, 0, 1)[None]
    centre, box = torch.tensor([[0.1, -0.15]]), torch.tensor([[0.4, 0.4]])
    a, b = box_glimpses(full, centre, box, 16), box_glimpses(half, centre, box, 16)
    assert (a - b).abs().mean() < 0.015 and (a - b).abs().max() < 0.06
    shifted = box_glimpses(half, centre + 1.0 / 32, box, 16)  # half a pixel of the small image
    assert (a - shifted).abs().mean() > 2.5 * (a - b).abs().mean()


def test_refinement_trains_end_to_end():
    """Through the corrected means, the loss reaches the refiner's output layer and the encoder under it."""
    from particlesplat.data.dataset import TrainingBatch
    from particlesplat.model import TrainConfig
    from particlesplat.training.trainer import training_loss

    _, refined = refined_pair()
    refined.train()
    rgb, depth, cs = scene_inputs(2)
    from particlesplat.model.geometry import stack_cameras

    K, c2w = stack_cameras(cs)
    batch = TrainingBatch(
        context_rgb=rgb[None],
        context_depth=depth[None],
        context_K=K[None],
        context_c2w=c2w[None],
        target_rgb=rgb[None, :1],
        target_depth=depth[None, :1],
        target_K=K[None, :1],
        target_c2w=c2w[None, :1],
        target_supervision=torch.ones_like(depth[None, :1]),
    )
    parts, _ = training_loss(refined, batch, TrainConfig(beta_fg=0.0), 32, refined.config)
    parts["loss"].backward()
    assert refined.refiner.out.weight.grad.abs().max() > 0
    assert refined.encoder.head.weight.grad.abs().max() > 0


def test_refinement_config_errors():
    with pytest.raises(ConfigError, match=r"model\.refine\.steps"):
        ModelConfig(**{**TINY, "refine_steps": -1}).validate()
    with pytest.raises(ConfigError, match=r"keypoints\.glimpse_size.*multiple of 8"):
        ModelConfig(**{**TINY, "glimpse_size": 12, "refine_steps": 1}).validate()
    for bad in (0.0, 1.5):
        with pytest.raises(ConfigError, match=r"refine\.scale: must be in \(0, 1\]"):
            ModelConfig(**{**TINY, "refine_scale": bad}).validate()
    with pytest.raises(ConfigError, match=r"refine\.scale: resolution x refine\.scale must be a whole number"):
        ModelConfig(**{**TINY, "refine_scale": 0.3}).validate()  # 32 x 0.3 = 9.6 pixels
    with pytest.raises(ConfigError, match=r"refine\.keep: must be >= 0"):
        ModelConfig(**{**TINY, "refine_keep": -1}).validate()
    with pytest.raises(ConfigError, match=r"refine\.static: must be render or behind"):
        ModelConfig(**{**TINY, "refine_static": "under"}).validate()
    for no_layer in ({"bg_static_grid": 0, "bg_per_view": True}, {"bg_per_view": True}):
        with pytest.raises(ConfigError, match=r"refine\.static: behind needs a static layer"):
            ModelConfig(**{**TINY, **no_layer, "refine_static": "behind"}).validate()
