"""The support surface's map read from the context views (``background.support_map``), against a ray-cast world
with a known table: a table top of one colour on the plane z = 0, a floor 0.8 m under it, and a ball on the table
that hides part of it from the context views."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from test_model import tiny_model

from particlesplat.core.camera import Camera
from particlesplat.model.geometry import stack_cameras
from particlesplat.model.support_map import CELLS, HALF_EXTENT, push_pull, support_map_image, views_support_map
from particlesplat.rendering.api import render, render_batch

TABLE_HALF, FLOOR_Z = 0.4, -0.8
TABLE, FLOOR, BALL = torch.tensor([0.7, 0.5, 0.3]), torch.tensor([0.1, 0.2, 0.3]), torch.tensor([0.9, 0.1, 0.1])
BACK = torch.tensor([0.0, 0.6, 0.2])  # the colour behind everything else
BALL_CENTRE, BALL_RADIUS = torch.tensor([0.05, 0.0, 0.1], dtype=torch.float64), 0.1


def cast(cam: Camera) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Float64 ray cast of the world in ``cam``: rgb (3, H, W), planar depth (1, H, W) (0 where a ray meets
    nothing), and (H, W) what each pixel shows: 0 nothing, 1 table, 2 floor, 3 ball."""
    c = cam.to(dtype=torch.float64)
    origins, dirs = c.rays()  # a direction's camera z is 1: t is the planar depth
    o, d = origins.reshape(-1, 3), dirs.reshape(-1, 3)
    inf = torch.full((len(d),), math.inf, dtype=torch.float64)
    t_table = torch.where(d[:, 2] < 0, (0.0 - o[:, 2]) / d[:, 2], inf)
    hit = o + t_table[:, None] * d
    t_table = torch.where((hit[:, :2].abs() <= TABLE_HALF).all(-1), t_table, inf)
    t_floor = torch.where(d[:, 2] < 0, (FLOOR_Z - o[:, 2]) / d[:, 2], inf)
    oc = o - BALL_CENTRE
    a, b, cc = (d * d).sum(-1), 2 * (oc * d).sum(-1), (oc * oc).sum(-1) - BALL_RADIUS**2
    disc = b * b - 4 * a * cc
    t_ball = torch.where(disc >= 0, (-b - disc.clamp_min(0).sqrt()) / (2 * a), inf)
    ts = torch.stack([t_table, t_floor, t_ball], -1)
    t, which = ts.min(-1)
    shows = torch.where(torch.isinf(t), 0, which + 1)
    colours = torch.stack([BACK, TABLE, FLOOR, BALL]).to(torch.float64)[shows]
    depth = torch.where(torch.isinf(t), 0.0, t)
    H, W = cam.height, cam.width
    return (
        colours.T.reshape(3, H, W).float(),
        depth.reshape(1, H, W).float(),
        shows.reshape(H, W),
    )


def _context(size: int = 96, turn: float = 0.0):
    """Two context views on an arc, 1.2 m from the table centre at 35 degrees (turned by ``turn`` degrees)."""
    cams = [Camera.orbit((0.0, 0.0, 0.0), az + turn, 35.0, 1.2, width=size, height=size) for az in (-50.0, 50.0)]
    casts = [cast(c) for c in cams]
    return torch.stack([x[0] for x in casts]), torch.stack([x[1] for x in casts]), cams


def _cell_centres() -> torch.Tensor:
    """(CELLS, CELLS, 2) world xy of the map's cell centres (rows along y)."""
    c = (torch.arange(CELLS, dtype=torch.float64) + 0.5) / CELLS * 2 * HALF_EXTENT - HALF_EXTENT
    y, x = torch.meshgrid(c, c, indexing="ij")
    return torch.stack([x, y], -1)


def test_push_pull_fills_holes_with_their_surroundings_and_a_limit_keeps_far_ones_empty():
    values = torch.full((1, 16, 16), 0.25)
    weight = torch.ones(16, 16)
    weight[4:8, 4:8] = 0.0  # a 4-cell hole
    values = values * weight
    torch.testing.assert_close(push_pull(values, weight), torch.full((1, 16, 16), 0.25))
    weight2 = torch.zeros(16, 16)
    weight2[0, 0] = 2.0  # one corner cell with evidence (its summed value 2 x 0.5)
    filled = push_pull(torch.where(weight2 > 0, 1.0, 0.0)[None], weight2)
    torch.testing.assert_close(filled, torch.full((1, 16, 16), 0.5))  # all levels: everywhere its mean
    limited = push_pull(torch.where(weight2 > 0, 1.0, 0.0)[None], weight2, levels=1)
    assert limited[0, 0, 0] == 0.5 and limited[0, 1, 1] == 0.5  # within the next level's 2 x 2 cell
    assert float(limited[0, 2:, 2:].abs().max()) == 0.0  # farther: nothing


def test_the_map_holds_the_table_where_the_views_saw_it_or_an_object_hid_it():
    rgb, depth, cams = _context()
    K, c2w = stack_cameras(cams)
    m = views_support_map(rgb, depth, K, c2w)
    assert m is not None and m.shape == (4, CELLS, CELLS)
    xy = _cell_centres()
    cell = 2 * HALF_EXTENT / CELLS
    inside = (xy.abs() <= TABLE_HALF - 2 * cell).all(-1)
    assert bool((m[3][inside] > 0.99).all())  # support everywhere on the table, under the ball too
    torch.testing.assert_close(m[:3].permute(1, 2, 0)[inside], TABLE.expand(int(inside.sum()), 3))
    under_ball = (xy - BALL_CENTRE[:2]).norm(dim=-1) < 0.5 * BALL_RADIUS
    assert bool(under_ball.any()) and bool((m[3][under_ball] > 0.99).all())
    # past the table's edge where the views saw the floor through the plane: not support
    seen_floor = torch.zeros(CELLS, CELLS, dtype=torch.bool)
    for cam in cams:
        c = cam.to(dtype=torch.float64)
        o, d = c.rays()
        shows = cast(cam)[2]
        t = -o[..., 2] / d[..., 2]
        cross = (o + t[..., None] * d)[..., :2][shows == 2]
        ij = ((cross + HALF_EXTENT) / (2 * HALF_EXTENT) * CELLS).floor().long()
        ok = ((ij >= 0) & (ij < CELLS)).all(-1)
        seen_floor[ij[ok, 1], ij[ok, 0]] = True
    outside = seen_floor & ~(xy.abs() <= TABLE_HALF + 2 * cell).all(-1)
    assert int(outside.sum()) > 50
    assert bool((m[3][outside] < 0.01).all())
    # without depth, or with no pixel on the plane: no map
    assert views_support_map(rgb, None, K, c2w) is None
    assert views_support_map(rgb, torch.full_like(depth, 0.3), K, c2w) is None


def test_a_novel_view_shows_the_table_where_its_rays_meet_it_and_the_backdrop_elsewhere():
    rgb, depth, cams = _context()
    K, c2w = stack_cameras(cams)
    m = views_support_map(rgb, depth, K, c2w)
    assert m is not None
    novel = Camera.orbit((0.0, 0.0, 0.0), 180.0, 12.0, 1.5, width=80, height=60)  # behind, lower: the sky too
    image = support_map_image(m, BACK, novel)
    assert image.shape == (60, 80, 3)
    c = novel.to(dtype=torch.float64)
    o, d = c.rays()
    t = -o[..., 2] / d[..., 2]
    hit = (o + t[..., None] * d)[..., :2]
    cell = 2 * HALF_EXTENT / CELLS
    on_table = (d[..., 2] < 0) & (hit.abs() <= TABLE_HALF - 2 * cell).all(-1)
    off = (d[..., 2] >= 0) | ((d[..., 2] < 0) & (hit.abs() >= TABLE_HALF + 3 * cell).any(-1))
    assert int(on_table.sum()) > 300 and int((d[..., 2] >= 0).sum()) > 100
    torch.testing.assert_close(image[on_table], TABLE.expand(int(on_table.sum()), 3))
    # off the table: the backdrop, except where the map had no evidence either way near a seen table cell
    close = (image[off] - BACK).abs().max(-1).values < 1e-6
    assert float(close.float().mean()) > 0.95


def _turned(cam: Camera, degrees: float) -> Camera:
    """``cam`` with the world turned by ``degrees`` about z: the same image of the turned world."""
    a = math.radians(degrees)
    turn = torch.eye(4, dtype=torch.float64)
    turn[:2, :2] = torch.tensor([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]], dtype=torch.float64)
    return Camera(cam.K, (turn @ cam.c2w.double()).to(cam.c2w.dtype), cam.width, cam.height)


def test_a_quarter_turn_of_the_world_turns_the_map_with_it():
    rgb, depth, cams = _context()
    turned = [_turned(c, 90.0) for c in cams]  # cameras and world turned, images unchanged
    m = views_support_map(rgb, depth, *stack_cameras(cams))
    m_t = views_support_map(rgb, depth, *stack_cameras(turned))
    assert m is not None and m_t is not None
    # x' = -y, y' = x: cell (i, j) of the turned map is cell (N - 1 - j, i) of the map (rows along y)
    torch.testing.assert_close(m_t, torch.rot90(m, -1, dims=(1, 2)), atol=1e-5, rtol=0)
    novel = Camera.orbit((0.0, 0.0, 0.0), 170.0, 30.0, 1.4, width=64, height=64)
    image, image_t = support_map_image(m, BACK, novel), support_map_image(m_t, BACK, _turned(novel, 90.0))
    torch.testing.assert_close(image_t, image, atol=1e-4, rtol=0)


def test_a_model_with_the_key_carries_the_map_and_every_render_of_the_scene_composites_over_it():
    rgb, depth, cams = _context(size=32)
    assert tiny_model().encode(rgb, depth, cams).support_map is None
    model = tiny_model(bg_support_map=True)
    particles = model.encode(rgb, depth, cams)
    assert particles.support_map is not None and particles.support_map.shape == (4, CELLS, CELLS)
    for edited in (particles.take([0, 1]), particles.cat(particles), particles.clone(), particles.detach()):
        assert edited.support_map is not None and torch.equal(edited.support_map, particles.support_map)
    novel = Camera.orbit((0.0, 0.0, 0.0), 0.0, 30.0, 1.3, width=40, height=30)
    back = model.backdrop_image(particles, novel)
    torch.testing.assert_close(back, support_map_image(particles.support_map, model.backdrop(particles), novel))
    # the renderer composites any Gaussians over the per-pixel image: nothing drawn shows it exactly
    empty = model.decode(particles, background=False, z_t_threshold=1.1)
    torch.testing.assert_close(render(empty, novel, background=back).rgb, back)
    g = model.decode(particles)
    drawn = render(g, novel, background=(0.0, 0.0, 0.0))
    over = render(g, novel, background=back)
    torch.testing.assert_close(over.rgb, drawn.rgb + (1 - drawn.alpha)[..., None] * back)
    both = render_batch([(g, novel), (g, novel)], backgrounds=[back, torch.zeros(3)])
    torch.testing.assert_close(both[0].rgb, over.rgb)
    torch.testing.assert_close(both[1].rgb, drawn.rgb)
    with pytest.raises(ValueError, match="background must be"):
        render(g, novel, background=back[:10])
    with pytest.raises(ValueError, match="2 backgrounds for 1 views"):
        render_batch([(g, novel)], backgrounds=[back, back])
    assert model.backdrop_image(model.encode(rgb, None, cams), novel).shape == (3,)  # no depth: one colour


def test_the_key_is_an_inference_key(tmp_path):
    from particlesplat.cli.main import main
    from particlesplat.model import load_model, save_checkpoint

    path, out = tmp_path / "m.pt", tmp_path / "map.pt"
    save_checkpoint(path, tiny_model(), 0)
    assert main(["model", "set", str(path), "background.support_map=true", "--out", str(out)]) == 0
    assert load_model(out).config.bg_support_map and not load_model(path).config.bg_support_map


def test_the_viewer_s_cpu_backdrop_is_the_library_s(tmp_path):
    """What a screenshot composites over (SceneView.backdrop) is the library's image over the user's colour."""
    from viewer.scene_view import SceneView
    from viewer.state import ViewState

    rgb, depth, cams = _context(size=32)
    m = views_support_map(rgb, depth, *stack_cameras(cams))
    assert m is not None
    view = SceneView.__new__(SceneView)
    view._support_map = m
    state = ViewState(background=(0.1, 0.2, 0.3))
    novel = Camera.orbit((0.0, 0.0, 0.0), 0.0, 30.0, 1.3, width=40, height=30)
    expect = support_map_image(m, torch.tensor([0.1, 0.2, 0.3]), novel).numpy()
    np.testing.assert_allclose(view.backdrop(state, novel), expect, atol=1e-6)
    state.seg_mode = "colour by particle"  # a colour per particle: the plain background behind them
    assert view.backdrop(state, novel) == (0.1, 0.2, 0.3)
    state.seg_mode = "normal"
    state.support_map = False
    assert view.backdrop(state, novel) == (0.1, 0.2, 0.3)


def test_training_renders_each_view_over_its_scene_s_map(rasterizer):
    """With the key, the training pass carries each scene's map (share 0 for a scene without depth) and the training
    render composites each view over its own image, as a render of that view over it does."""
    from particlesplat.training.loss import render_views, support_map_images

    rgb, depth, cams = _context(size=32)
    model = tiny_model(bg_support_map=True, bg_colour_from_views=True)
    K, c2w = stack_cameras(cams)
    _, z, gaussians = model(rgb[None], depth[None], K[None], c2w[None], sample=False)
    m = views_support_map(rgb, depth, K, c2w)
    assert m is not None
    torch.testing.assert_close(z["support_map"], m[None])
    _, z_none, _ = model(rgb[None], None, K[None], c2w[None], sample=False)
    assert float(z_none["support_map"].abs().max()) == 0.0  # no depth: nothing read, the colour alone
    images = support_map_images(z["support_map"], z["backdrop"], K[None], c2w[None], 32)
    assert images.shape == (1, 2, 32, 32, 3)
    for v, cam in enumerate(cams):
        torch.testing.assert_close(images[0, v], support_map_image(m, z["backdrop"][0], cam))
    out, _, _ = render_views(gaussians, K[None], c2w[None], 32, images)
    for v, cam in enumerate(cams):
        alone = render(gaussians[0], cam, background=images[0, v]).rgb.permute(2, 0, 1)
        torch.testing.assert_close(out[0, v], alone, atol=1e-5, rtol=1e-5)
