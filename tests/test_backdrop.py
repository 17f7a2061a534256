"""The colour behind a scene read from its context views (``background.colour_from_views``): the median colour of
the pixels whose depth puts them below the support surface, carried with the scene's particles and drawn by every
render of the scene."""

from __future__ import annotations

from dataclasses import replace

import pytest
import torch
from test_model import tiny_model

from particlesplat.core.camera import Camera
from particlesplat.core.world import BELOW_SUPPORT
from particlesplat.model.backdrop import views_backdrop
from particlesplat.model.geometry import stack_cameras
from particlesplat.rendering.api import render

FLOOR, TABLE = torch.tensor([0.2, 0.4, 0.6]), torch.tensor([0.9, 0.1, 0.3])


def _views(size: int = 32, depth_m: float = 3.3):
    """Two orbit cameras looking down at 30 degrees from 3.3 m, every pixel at the same planar depth; each pixel
    coloured by where its point lies (float64 unprojection by the camera): FLOOR below the support surface by more
    than BELOW_SUPPORT, TABLE above it. Returns rgb (2, 3, H, W), depth (2, 1, H, W), cameras."""
    cams = [Camera.orbit((0.0, 0.0, 0.0), az, 30.0, 3.3, width=size, height=size) for az in (-30, 40)]
    depth = torch.full((2, 1, size, size), depth_m)
    rgb = torch.empty(2, 3, size, size)
    for v, cam in enumerate(cams):
        c = cam.to(dtype=torch.float64)
        points = c.unproject(c.pixel_centers().reshape(-1, 2), torch.full((size * size,), depth_m, dtype=torch.float64))
        below = (points[:, 2] < -BELOW_SUPPORT).reshape(size, size)
        rgb[v] = torch.where(below[None], FLOOR[:, None, None], TABLE[:, None, None])
        assert 0 < int(below.sum()) < size * size  # both kinds of pixel in every view
    return rgb, depth, cams


def test_the_backdrop_is_the_colour_below_the_support_surface():
    rgb, depth, cams = _views()
    K, c2w = stack_cameras(cams)
    torch.testing.assert_close(views_backdrop(rgb, depth, K, c2w), FLOOR)
    assert views_backdrop(rgb, None, K, c2w) is None  # no depth: nothing to read
    # nothing below the surface (every pixel 1 m away, over it): none
    assert views_backdrop(rgb, torch.full_like(depth, 1.0), K, c2w) is None
    # missing depth (0) is not below anything
    assert views_backdrop(rgb, torch.zeros_like(depth), K, c2w) is None


def test_a_model_with_the_key_carries_its_scene_s_backdrop_and_renders_over_it():
    rgb, depth, cams = _views()
    plain = tiny_model()
    assert plain.encode(rgb, depth, cams).backdrop is None
    model = tiny_model(bg_colour_from_views=True)
    particles = model.encode(rgb, depth, cams)
    assert particles.backdrop is not None
    torch.testing.assert_close(particles.backdrop, FLOOR)
    torch.testing.assert_close(model.backdrop(particles), FLOOR)
    torch.testing.assert_close(model.backdrop(None), model.background_color())
    # the scene's rows change under edits; its backdrop stays
    for edited in (particles.take([0, 1]), particles.cat(particles), particles.clone(), particles.detach()):
        assert edited.backdrop is not None and torch.equal(edited.backdrop, particles.backdrop)
    # a render of the scene shows it where nothing is drawn: empty Gaussians over the backdrop
    empty = model.decode(particles, background=False, z_t_threshold=1.1)
    image = render(empty, cams[0], background=model.backdrop(particles)).rgb
    torch.testing.assert_close(image, FLOOR.expand_as(image))
    assert model.encode(rgb, None, cams).backdrop is None  # without depth: the learned colour


def test_the_key_is_an_inference_key(tmp_path):
    from particlesplat.cli.main import main
    from particlesplat.model import load_model, save_checkpoint

    path, out = tmp_path / "m.pt", tmp_path / "views.pt"
    save_checkpoint(path, tiny_model(), 0)
    assert main(["model", "set", str(path), "background.colour_from_views=true", "--out", str(out)]) == 0
    assert load_model(out).config.bg_colour_from_views and not load_model(path).config.bg_colour_from_views


@pytest.mark.parametrize("depth_m", [2.9, 3.6])
def test_the_rule_reads_depth_not_colour(depth_m):
    """At another depth other pixels lie below the surface: the colour follows the geometry."""
    rgb, depth, cams = _views(depth_m=depth_m)
    K, c2w = stack_cameras(cams)
    torch.testing.assert_close(views_backdrop(rgb, depth, K, c2w), FLOOR)


def test_training_renders_each_scene_over_its_own_backdrop(rasterizer):
    """The training render with one colour per scene equals rendering each scene over its colour, on both
    rasterizers; and a model with the key trains over its scenes' own colours."""
    from particlesplat.training.loss import render_views

    model = tiny_model()
    rgb, depth, cams = _views()
    particles = model.encode(rgb, depth, cams)
    g = model.decode(particles)
    K, c2w = stack_cameras(cams)
    K, c2w = torch.stack([K, K]), torch.stack([c2w, c2w])
    colours = torch.tensor([[0.2, 0.4, 0.6], [1.0, 0.5, 0.0]], requires_grad=True)
    out, depth_hat, _ = render_views([g, g], K, c2w, 32, colours)
    for b in range(2):
        alone, _, _ = render_views([g], K[:1], c2w[:1], 32, colours[b].detach())
        torch.testing.assert_close(out[b], alone[0], atol=1e-5, rtol=1e-5)
    out.sum().backward()
    assert colours.grad is not None and bool((colours.grad > 0).all())  # every scene's colour shows somewhere

    views = tiny_model(bg_colour_from_views=True)
    _, z, _ = views(rgb[None], depth[None], K[:1], c2w[:1], sample=False)
    torch.testing.assert_close(z["backdrop"], FLOOR[None])
    _, z, _ = views(rgb[None], None, K[:1], c2w[:1], sample=False)
    torch.testing.assert_close(z["backdrop"], views.background_color()[None])  # no depth: the learned one


def test_a_hidden_block_takes_the_colour_of_the_surface_its_view_shows():
    """With ``background.hidden_from_views`` the background blocks an object hides are drawn in the median colour
    of the view's blocks whose anchor lies on the support surface; the others are as without the key. Anchors
    built by hand: blocks on the table plane (float64 ray-plane hits) in one colour, blocks 0.3 m above in another."""
    from particlesplat.core.sh import SH_C0
    from particlesplat.model.config import ModelConfig
    from particlesplat.model.decoder import background_gaussians, block_centres, support_colours
    from particlesplat.model.geometry import ray_dirs

    cfg = ModelConfig(resolution=32, bg_block=2, fg_evidence=True, bg_per_view=True, bg_latent_stride=2)
    cam = Camera.orbit((0.0, 0.0, 0.0), 20.0, 45.0, 1.0, width=32, height=32)
    K, c2w = stack_cameras([cam])
    K, c2w = K.double(), c2w.double()
    pix = block_centres(cfg, "cpu", torch.float64)[None]
    dirs = ray_dirs(pix, K, c2w)[0]  # (N, 3), camera z = 1
    on_plane = -c2w[0, 2, 3] / dirs[:, 2]  # planar depth where each block's ray meets z = 0
    N = pix.shape[1]
    gen = torch.Generator().manual_seed(0)
    kind = torch.randint(0, 3, (N,), generator=gen)  # 0: table, 1: 0.3 m above it, 2: hidden
    above = (0.3 - c2w[0, 2, 3]) / dirs[:, 2]
    anchor = torch.zeros(1, N, 5, dtype=torch.float64)
    anchor[0, :, 3] = torch.where(kind == 1, above, on_plane)
    anchor[0, :, :3] = torch.where((kind == 0)[:, None], TABLE.double(), FLOOR.double())
    anchor[0, :, 4] = (kind != 2).double()
    colours, found = support_colours(anchor, K, c2w, cfg)
    assert bool(found[0]) and torch.allclose(colours[0], TABLE.double())
    raw = torch.randn(1, N, 14, generator=gen, dtype=torch.float64)
    plain = background_gaussians(raw, K, c2w, cfg, anchor)
    keyed = background_gaussians(raw, K, c2w, replace(cfg, bg_hidden_from_views=True), anchor)
    rgb = keyed["sh"][0, :, 0, :] * SH_C0 + 0.5
    hidden = kind == 2
    assert torch.allclose(rgb[hidden], TABLE.double().expand(int(hidden.sum()), 3))
    assert torch.equal(keyed["sh"][0, ~hidden], plain["sh"][0, ~hidden])
    assert torch.equal(keyed["means"], plain["means"])
    # a camera 5 degrees above the horizon: its upper blocks' rays never meet the table, so an unseen block there
    # (no depth) is not one an object hides on the table, and keeps its latent's colour
    low = Camera.orbit((0.0, 0.0, 0.0), 20.0, 5.0, 1.0, width=32, height=32)
    K2, c2w2 = (t.double() for t in stack_cameras([low]))
    down = ray_dirs(pix, K2, c2w2)[0][:, 2] < 0
    assert bool(down.any()) and bool((~down).any())
    anchor2 = anchor.clone()
    anchor2[0, :, 3] = torch.where(down & (kind != 1), -c2w2[0, 2, 3] / ray_dirs(pix, K2, c2w2)[0][:, 2], 1.0)
    anchor2[0, ~down, 4] = 0.0  # the sky: no depth
    plain2 = background_gaussians(raw, K2, c2w2, cfg, anchor2)
    keyed2 = background_gaussians(raw, K2, c2w2, replace(cfg, bg_hidden_from_views=True), anchor2)
    assert torch.equal(keyed2["sh"][0, ~down], plain2["sh"][0, ~down])
    rgb2 = keyed2["sh"][0, :, 0, :] * SH_C0 + 0.5
    hidden2 = down & (kind == 2)
    assert torch.allclose(rgb2[hidden2], TABLE.double().expand(int(hidden2.sum()), 3))
