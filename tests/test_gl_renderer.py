"""The GL splat renderer against the torch reference renderer (headless EGL), on each compositing path
given by ``--compositing`` (default: fetch and blend forced; see conftest.py)."""

from __future__ import annotations

import os
from dataclasses import replace

import numpy as np
import pytest
import torch
from reference_render import reference_render
from viewer_helpers import egl_context, psnr, small_model

from particlesplat import render
from particlesplat.core.camera import Camera
from particlesplat.core.gaussians import Gaussians
from particlesplat.rendering.projection import ALPHA_MAX
from particlesplat.rendering.rasterize import T_MIN
from viewer.bench.random_gaussians import random_gaussians
from viewer.gl.caps import probe
from viewer.gl.depth_sort import depth_order
from viewer.gl.renderer import SplatRenderer

pytestmark = pytest.mark.gl


@pytest.fixture(scope="module")
def ctx():
    c = egl_context()
    yield c
    c.release()


def gl_render(
    ctx, g: Gaussians, cam: Camera, compositing: str, primitive: str = "auto", **filt
) -> tuple[np.ndarray, np.ndarray, SplatRenderer]:
    r = SplatRenderer(ctx, color_dtype="f4", primitive=primitive, compositing=compositing)
    r.set_gaussians(g)
    if filt:
        r.set_filter(**filt)
    r.render(cam)
    rgba = r.read_rgba()
    return rgba[..., :3], rgba[..., 3], r


NO_STOP_GAP = T_MIN / (1.0 - ALPHA_MAX)  # the most the missing early stop can change a weight sum


def no_stop_truth(g: Gaussians, cam: Camera, **kw):
    """Float64 brute force with the blend path's rules: the torch renderer's, without the early stop."""
    return reference_render(g, cam, t_stop=-1.0, **kw)


def alpha_tolerance(r: SplatRenderer) -> float:
    """Largest |alpha - torch's alpha| allowed: 1e-3, plus NO_STOP_GAP on the blend path
    (test_blend_path_follows_the_rules_without_the_early_stop checks that path tightly)."""
    return 1e-3 + (NO_STOP_GAP if r.compositing == "blend" else 0.0)


CASES = [  # seed, n, sh degree, pixel scale, camera (azimuth, elevation, distance, fov, w, h)
    (0, 400, 0, 0.05, (30.0, 20.0, 3.5, 45.0, 96, 80)),
    (1, 3000, 3, 0.01, (-60.0, 35.0, 3.0, 40.0, 120, 90)),
    (2, 1500, 1, 0.03, (150.0, -10.0, 2.2, 60.0, 80, 100)),
    (3, 800, 2, 0.08, (10.0, 5.0, 1.2, 70.0, 64, 64)),  # close: Gaussians behind the camera and off-screen
]


@pytest.mark.parametrize("primitive", ["quads", "points"])
@pytest.mark.parametrize("seed,n,deg,ps,view", CASES)
def test_random_sets_match_torch(ctx, compositing, seed, n, deg, ps, view, primitive):
    g = random_gaussians(n, seed=seed, sh_degree=deg, pixel_scale=ps)
    az, el, dist, fov, w, h = view
    cam = Camera.orbit((0.1, -0.2, 0.0), az, el, dist, fov_y_deg=fov, width=w, height=h)
    ref = render(g, cam, background=(0.2, 0.3, 0.4))
    rgb, alpha, r = gl_render(ctx, g, cam, compositing, primitive)
    out = rgb + (1.0 - alpha[..., None]) * np.array([0.2, 0.3, 0.4], np.float32)
    assert psnr(out, ref.rgb.numpy()) >= 40.0
    assert np.abs(alpha - ref.alpha.numpy()).max() < alpha_tolerance(r)
    # the dominant owner per pixel (id pass) against the torch per-owner argmax
    ref_w = render(g, cam, owner_weights=True, num_owners=8)
    seg = r.segmentation(cam, 8)
    m = ref_w.alpha.numpy() > 0.5
    assert m.sum() > 50
    assert (seg == ref_w.segmentation().numpy())[m].mean() >= 0.95
    r.release()


def test_quads_footprint_on_long_thin_splats_cut_by_the_image_edge(ctx, compositing):
    """The quads interpolate the footprint (the pixel in the ellipse's scaled axes) instead of evaluating the conic
    per pixel: against the float64 brute force, on long, thin, rotated splats seen close, most of them larger than
    the image, so that GL clips their rectangles (noperspective interpolation came out wrong there on llvmpipe)."""
    g = random_gaussians(60, seed=21, sh_degree=1, pixel_scale=0.1)
    g = replace(g, scales=g.scales * torch.tensor([6.0, 0.25, 1.0]))
    cam = Camera.orbit((0.0, 0.0, 0.0), 35.0, 15.0, 1.3, fov_y_deg=60.0, width=64, height=48)
    rgb, alpha, r = gl_render(ctx, g, cam, compositing, "quads")
    radii = r.projected_splats()[:, 2:4]
    live = radii[:, 0] > 0
    assert (radii[live, 0] > 64).sum() > 10 and (radii[live, 1] < 0.25 * radii[live, 0]).mean() > 0.5
    truth = reference_render(g, cam) if r.compositing == "fetch" else no_stop_truth(g, cam)
    assert np.abs(alpha - truth.alpha.numpy()).max() < 1e-3
    assert psnr(rgb, truth.rgb.numpy()) >= 80.0  # 106-139 dB; 55 dB with the clipped noperspective varying
    r.release()


def _mask(r: SplatRenderer) -> np.ndarray:
    """The mask target after :meth:`SplatRenderer.render_mask`: (H, W) weight of that owner, rows top down (what
    the blit samples for the overlay)."""
    w, h = r.size
    raw = np.frombuffer(r._mask_fbo.read(components=4, dtype="f4"), np.float32).reshape(h, w, 4)
    return raw[::-1, :, 0]


def test_owner_weights_match_torch(ctx, compositing):
    g = random_gaussians(1200, seed=5, num_owners=30, pixel_scale=0.04)  # > 24 owners: two id passes
    cam = Camera.orbit((0, 0, 0), 20, 30, 3.0, width=72, height=60)
    ref = render(g, cam, owner_weights=True, num_owners=30)
    r = SplatRenderer(ctx, color_dtype="f4", compositing=compositing)
    r.set_gaussians(g)
    weights, alpha = r.owner_weights(cam, 30)
    if r.compositing == "blend":  # no early stop: the brute force without it, and close to torch
        for a, b in ((weights[1:], ref.owner_weights), (weights[0], ref.background_weight), (alpha, ref.alpha)):
            assert np.abs(a - b.numpy()).max() < NO_STOP_GAP + 2e-4
        ref = no_stop_truth(g, cam, num_owners=30)
    np.testing.assert_allclose(weights[1:], ref.owner_weights.numpy(), atol=2e-4)
    np.testing.assert_allclose(weights[0], ref.background_weight.numpy(), atol=2e-4)
    np.testing.assert_allclose(alpha, ref.alpha.numpy(), atol=2e-4)
    assert float(alpha.max()) > 0.9  # covered pixels, where the stop rule matters
    # the single-owner mask pass (mask overlay of the selected particle)
    for owner in (-1, 0, 17, 29):
        r.render_mask(cam, owner)
        truth = ref.background_weight if owner < 0 else ref.owner_weights[owner]
        np.testing.assert_allclose(_mask(r), truth.numpy(), atol=2e-4)
    # a 1x1 region (picking) gives the same weights as the full pass at that pixel
    w1, _ = r.owner_weights(cam, 30, region=(40, 25, 1, 1))
    np.testing.assert_allclose(w1[:, 0, 0], weights[:, 25, 40], atol=1e-6)
    r.release()


@pytest.mark.parametrize("primitive", ["quads", "points"])
def test_each_path_follows_its_stop_rule(ctx, compositing, primitive):
    """Opaque, overlapping splats, where the early stop (T <= T_MIN) changes pixels: fetch renders
    torch's rule, blend the same sums without the stop (float64 brute force), both tightly."""
    from dataclasses import replace

    g = random_gaussians(500, seed=11, sh_degree=1, pixel_scale=0.06)
    g = replace(g, opacities=0.9 + 0.1 * g.opacities)
    cam = Camera.orbit((0.0, 0.0, 0.0), 25.0, 20.0, 3.0, fov_y_deg=40.0, width=48, height=40)
    stop, free = render(g, cam), no_stop_truth(g, cam)
    assert np.abs(stop.alpha.numpy() - free.alpha.numpy()).max() > 1e-3  # the rule matters here
    rgb, alpha, r = gl_render(ctx, g, cam, compositing, primitive)
    truth = stop if r.compositing == "fetch" else free
    assert np.abs(alpha - truth.alpha.numpy()).max() < 2e-4
    assert psnr(rgb, truth.rgb.numpy()) >= 60.0
    r.release()


@pytest.mark.parametrize("which", ["shipped", "untrained"])
def test_model_decode_matches_torch(ctx, compositing, which):
    from particlesplat.editing.open_scene import demo_scenes, encode_scene
    from particlesplat.model import load_model

    model = load_model() if which == "shipped" else small_model()

    enc = encode_scene(model, demo_scenes()[0])
    g = model.decode(enc.particles)
    cam = enc.all_cameras[10].resized(96, 96)
    ref = render(g, cam, owner_weights=True, num_owners=enc.particles.num)
    rgb, alpha, r = gl_render(ctx, g, cam, compositing)
    assert psnr(rgb, ref.rgb.numpy()) >= 40.0
    seg = r.segmentation(cam, enc.particles.num)
    m = ref.alpha.numpy() > 0.5
    assert (seg == ref.segmentation().numpy())[m].mean() >= 0.95
    r.release()


def test_replace_owner_and_filter(ctx, compositing):
    g = random_gaussians(2000, seed=7, num_owners=5, pixel_scale=0.04)
    cam = Camera.orbit((0, 0, 0), 40, 20, 3.2, width=80, height=64)
    r = SplatRenderer(ctx, color_dtype="f4", compositing=compositing)
    r.set_gaussians(g)
    r.render(cam)
    # move owner 2's Gaussians (same count: in-place row upload) and recolour them
    m = g.owner == 2
    moved = g.subset(m)
    moved = Gaussians(
        moved.means + torch.tensor([0.3, 0.0, 0.1]),
        moved.quats,
        moved.scales * 1.5,
        moved.opacities,
        moved.sh.flip(-1),
        moved.owner,
    )
    r.replace_owner(2, moved)
    r.render(cam)
    expect = Gaussians.cat([g.subset(~m), moved])
    assert psnr(r.read_rgba()[..., :3], render(expect, cam).rgb.numpy()) >= 40.0
    # a different count re-packs everything
    fewer = moved.subset(torch.arange(moved.num) % 2 == 0)
    r.replace_owner(2, fewer)
    r.render(cam)
    expect = Gaussians.cat([g.subset(~m), fewer])
    assert r.num == expect.num
    assert psnr(r.read_rgba()[..., :3], render(expect, cam).rgb.numpy()) >= 40.0
    # owner and opacity filter = rendering the subset
    r.set_filter([-1, 0, 3], min_opacity=0.4)
    r.render(cam)
    keep = torch.isin(expect.owner, torch.tensor([-1, 0, 3])) & (expect.opacities >= 0.4)
    assert r.visible_count == int(keep.sum())
    assert psnr(r.read_rgba()[..., :3], render(expect.subset(keep), cam).rgb.numpy()) >= 40.0
    r.release()


def test_sort_and_projection_only_when_needed(ctx, compositing):
    g = random_gaussians(500, seed=3)
    cam = Camera.orbit((0, 0, 0), 0, 20, 3.0, width=48, height=48)
    r = SplatRenderer(ctx, color_dtype="f4", compositing=compositing)
    r.set_gaussians(g)
    assert r.render(cam).sorted
    assert not r.render(cam).sorted  # same view, same data: no sort
    r.set_filter(None, min_opacity=0.5)
    assert r.render(cam).sorted
    assert r.render(Camera.orbit((0, 0, 0), 5, 20, 3.0, width=48, height=48)).sorted
    r.release()


def test_auto_primitive_picks_points_only_when_exact(ctx, compositing):
    """Point sprites (drawn with a guard band, so off-screen centres still count) for many small
    splats, quads when a splat exceeds 255 px; both match torch. The choice is a software rasteriser's (a GPU
    takes quads): llvmpipe's name and point limit are assumed, so the test is the same on any driver."""
    g = random_gaussians(1500, seed=9, pixel_scale=0.01)
    cam = Camera.orbit((0, 0, 0), 0, 20, 2.0, fov_y_deg=60, width=160, height=120)  # many centres off screen
    real = probe(ctx)
    soft = replace(real, renderer="llvmpipe (assumed)", max_point_size=min(real.max_point_size, 255.0))
    r = SplatRenderer(ctx, color_dtype="f4", compositing=compositing, caps=soft)
    r.set_gaussians(g)
    assert r.render(cam).primitive == "points"
    assert psnr(r.read_rgba()[..., :3], render(g, cam).rgb.numpy()) >= 40.0
    big = Gaussians(g.means, g.quats, g.scales * 30.0, g.opacities, g.sh, g.owner)
    r.set_gaussians(big)
    assert r.render(cam).primitive == "quads"
    assert psnr(r.read_rgba()[..., :3], render(big, cam).rgb.numpy()) >= 40.0
    r.release()


def test_empty_and_all_behind_the_camera(ctx, compositing):
    cam = Camera.orbit((0, 0, 0), 0, 20, 3.0, width=32, height=24)
    r = SplatRenderer(ctx, color_dtype="f4", compositing=compositing)
    r.set_gaussians(Gaussians.empty(sh_degree=2))
    r.render(cam)
    assert np.array_equal(r.read_rgb((0.2, 0.3, 0.4)), np.broadcast_to(np.float32([0.2, 0.3, 0.4]), (24, 32, 3)))
    g = random_gaussians(100, seed=1)
    eye = Camera.orbit_eye((0, 0, 0), 0, 20, 3.0).float()
    behind = Gaussians(g.means * 0.1 + eye + (eye / eye.norm()) * 1.5, g.quats, g.scales, g.opacities, g.sh, g.owner)
    r.set_gaussians(behind)
    ft = r.render(cam)
    assert ft.drawn == 0 and float(r.read_rgba()[..., 3].max()) == 0.0
    r.release()


def test_depth_order_is_a_stable_sort_by_z():
    rng = np.random.default_rng(0)
    z = rng.choice(np.float32([0.5, 1.0, 1.0 + 1e-7, 2.0, 30.0]), size=1000)  # many exact ties
    index = rng.permutation(5000)[:1000]
    expect = index[np.lexsort((index, z))]
    np.testing.assert_array_equal(depth_order(index, z), expect)
    z[3] = -1.0  # non-positive depths take the general path
    np.testing.assert_array_equal(depth_order(index, z), index[np.lexsort((index, z))])


def test_projected_splats_match_torch_projection_and_the_bench_prints_its_floor(ctx, capsys):
    """The projection read back for the bench's sprite floor has the torch projection's centres (same
    camera), and `particlesplat bench viewer` prints the table with that column."""
    from particlesplat.rendering.projection import project_gaussians
    from viewer.bench import main as bench_main

    g = random_gaussians(300, seed=1)
    cam = Camera.orbit((0.0, 0.0, 0.0), 20.0, 25.0, 3.5, width=96, height=64)
    r = SplatRenderer(ctx, primitive="points", color_dtype="f4")
    r.set_gaussians(g)
    r.render(cam, finish=True)
    s = r.projected_splats()
    live = s[:, 2] > 0
    proj = project_gaussians(g, cam, 0.01, 1e10)
    z = (g.means[proj.index] - cam.c2w[:3, 3]) @ cam.c2w[:3, 2]
    ref = proj.means2d[torch.argsort(z, stable=True)].numpy()  # front to back, as the GL order
    assert len(s) == len(ref) and live.sum() >= 0.9 * len(ref)
    np.testing.assert_allclose(s[live][:, :2], ref[live], atol=1e-2)
    r.release()  # (its caps stay readable)
    bench = [
        "--sizes",
        "400",
        "--frames",
        "1",
        "--no-scene",
        "--width",
        "64",
        "--height",
        "48",
        "--primitive",
        "points",
        "--compositing",
    ]
    assert bench_main([*bench, "auto,blend,fetch" if r.caps.framebuffer_fetch else "auto,blend"]) == 0
    out = capsys.readouterr().out
    assert "sprite floor ms" in out and "| random 400 | 400 | blend | points |" in out
    psnr_db = {
        line.split("|")[3].strip(): float(line.split("|")[-2])
        for line in out.splitlines()
        if line.startswith("| random 400 |")
    }
    assert psnr_db["blend"] >= 40.0
    if r.caps.framebuffer_fetch:  # both paths side by side (auto is fetch here), and their ratio
        assert "| random 400 | 400 | fetch | points |" in out and psnr_db["fetch"] >= 40.0
        assert len(psnr_db) == 2 and "- random 400: blend " in out
    else:  # auto is blend: one path; fetch is refused
        assert len(psnr_db) == 1
        assert bench_main([*bench, "fetch"]) == 2 and "lacks GL_EXT_shader_framebuffer_fetch" in capsys.readouterr().err
    assert bench_main([*bench, "fetch,fast"]) == 2
    assert "--compositing" in capsys.readouterr().err


@pytest.mark.parametrize("primitive", ["quads", "points"])
def test_colour_by_object_is_colour_by_particle_of_the_relabelled_set(ctx, compositing, primitive):
    """Mode 2 with objects [0, 0, 2, 2, 4, ...] draws exactly what mode 1 draws when every Gaussian's
    owner is replaced by its object label; mode 1 itself tells the merged owners apart."""
    from dataclasses import replace

    g = random_gaussians(1500, seed=5, sh_degree=1, pixel_scale=0.03)
    cam = Camera.orbit((0.0, 0.0, 0.0), 40.0, 25.0, 3.0, fov_y_deg=45.0, width=80, height=64)
    num = int(g.owner.max()) + 1
    objects = [o - o % 2 for o in range(num)]
    relabelled = replace(g, owner=torch.where(g.owner >= 0, torch.tensor(objects)[g.owner.clamp_min(0)], g.owner))
    r = SplatRenderer(ctx, color_dtype="f4", primitive=primitive, compositing=compositing)
    r.set_gaussians(g)
    r.render(cam, color_mode=2, objects=objects)
    by_object = r.read_rgba()
    r.render(cam, color_mode=1)
    by_particle = r.read_rgba()
    r2 = SplatRenderer(ctx, color_dtype="f4", primitive=primitive, compositing=compositing)
    r2.set_gaussians(relabelled)
    r2.render(cam, color_mode=1)
    assert np.abs(by_object - r2.read_rgba()).max() < 1e-6
    assert np.abs(by_object - by_particle).max() > 0.1


@pytest.mark.parametrize("primitive", ["quads", "points"])
def test_the_profile_times_every_pass(capsys, compositing, primitive):
    """`particlesplat bench viewer --profile`: a row per path and scale with every pass timed, the splat pass split
    into the geometry (the same primitives, constant colour) and the rest."""
    from viewer.bench import main as bench_main

    args = ["--profile", "--sizes", "300", "--frames", "1", "--no-scene", "--width", "64", "--height", "48"]
    assert bench_main([*args, "--primitive", primitive, "--compositing", f"blend,{compositing}"]) == 0
    rows = [line.split("|") for line in capsys.readouterr().out.splitlines() if line.startswith("| random 300 |")]
    assert [row[5].strip() for row in rows] == ["1", "1", "0.5", "0.5"]
    assert {row[3].strip() for row in rows} <= {"blend", "fetch"} and rows[0][3].strip() == "blend"
    assert all(row[4].strip() == primitive and float(row[13]) > 0.0 for row in rows)  # the sum of the passes


@pytest.mark.skipif(
    not os.environ.get("PARTICLESPLAT_PEER"), reason="set PARTICLESPLAT_PEER to a GaussianSplattingViewer clone"
)
def test_bench_against_the_peer(capsys):
    """`particlesplat bench viewer --peer DIR` with a clone of limacv/GaussianSplattingViewer (its requirements
    importable, or their site-packages in PARTICLESPLAT_PEER_PATH): the peer takes its turns on the same cameras,
    draws the same Gaussians where ours do (PSNR against torch), and the ratios are printed."""
    from viewer.bench import main as bench_main

    extra = [
        a for p in os.environ.get("PARTICLESPLAT_PEER_PATH", "").split(os.pathsep) if p for a in ("--peer-path", p)
    ]
    args = [
        "--sizes",
        "500",
        "--frames",
        "2",
        "--no-scene",
        "--width",
        "96",
        "--height",
        "64",
        "--compositing",
        "blend",
    ]
    assert bench_main([*args, "--peer", os.environ["PARTICLESPLAT_PEER"], *extra]) == 0
    out = capsys.readouterr().out
    rows = {line.split("|")[3].strip(): line for line in out.splitlines() if line.startswith("| random 500 |")}
    assert set(rows) == {"blend", "limacv"}
    assert float(rows["limacv"].split("|")[-2]) >= 25.0  # its own rules (3 sigma, 8-bit), same image
    assert "- random 500: blend " in out and "x moving" in out


@pytest.mark.parametrize("seed,n,deg,ps,view", [CASES[1], CASES[3]])
def test_the_viewers_normalized_target_shows_what_torch_shows(ctx, compositing, seed, n, deg, ps, view):
    """The viewer's 16-bit normalized colour target (the default), read back and presented by the blit into an
    8-bit framebuffer over a background: the torch image over that background, clamped to [0, 1] as a display
    shows it. The close case stops pixels early (fetch keeps T as 0.5 + 0.5 T, 0.5 T once stopped)."""
    g = random_gaussians(n, seed=seed, sh_degree=deg, pixel_scale=ps)
    az, el, dist, fov, w, h = view
    cam = Camera.orbit((0.1, -0.2, 0.0), az, el, dist, fov_y_deg=fov, width=w, height=h)
    bg = (0.2, 0.3, 0.4)
    ref = render(g, cam, background=bg)
    shown = np.clip(ref.rgb.numpy(), 0.0, 1.0)
    r = SplatRenderer(ctx, compositing=compositing)
    assert r.color_dtype == "nu2"
    r.set_gaussians(g)
    r.render(cam)
    assert psnr(np.clip(r.read_rgb(bg), 0.0, 1.0), shown) >= 40.0
    # no pixel off by more than a missed early stop (a splat's alpha x colour above 1 is kept: COLOR_SCALE)
    assert np.abs(np.clip(r.read_rgb(bg), 0.0, 1.0) - shown).max() < 0.01
    # T in 16 bits (fetch: steps of 2 / 65535) can move a pixel's early stop by a splat, as the blend path's
    # missing stop does: within NO_STOP_GAP
    assert np.abs(r.read_rgba()[..., 3] - ref.alpha.numpy()).max() < 1e-3 + NO_STOP_GAP
    if compositing == "fetch" and seed == 3:  # stopped pixels are stored below 0.5
        raw = np.frombuffer(r._color_fbo.read(components=4, dtype="f4"), np.float32).reshape(h, w, 4)
        assert (raw[..., 3] < 0.5).sum() > 20
    fbo = ctx.simple_framebuffer((w, h), components=4)
    fbo.use()
    r.blit((0, 0, w, h), bg)
    blitted = np.frombuffer(fbo.read(components=3), np.uint8).reshape(h, w, 3)[::-1] / 255.0
    assert psnr(blitted, shown) >= 40.0
    fbo.release()
    r.release()


def test_the_blit_draws_the_support_map_behind_the_render_as_its_torch_twin(ctx, compositing):
    """blit.frag's SUPPORT_MAP part against particlesplat.model.support_map.support_map_image: the ray-cast world's
    map (tests/test_support_map.py) behind a few Gaussians, in a camera that sees the table, past it and the sky,
    blitted into an 8-bit framebuffer at the render's size; and without the camera, the colour alone."""
    from test_support_map import _context

    from particlesplat.model.geometry import stack_cameras
    from particlesplat.model.support_map import support_map_image, views_support_map

    rgb, depth, cams = _context()
    m = views_support_map(rgb, depth, *stack_cameras(cams))
    assert m is not None
    g = random_gaussians(60, seed=4, pixel_scale=0.03)
    cam = Camera.orbit((0.0, 0.0, 0.0), 160.0, 16.0, 1.0, fov_y_deg=50.0, width=96, height=72)
    bg = (0.2, 0.3, 0.4)
    back = support_map_image(m, torch.tensor(bg), cam)
    assert float((back - torch.tensor(bg)).abs().amax(-1).gt(0.05).float().mean()) > 0.2  # the map shows
    shown = np.clip(render(g, cam, background=back).rgb.numpy(), 0.0, 1.0)
    r = SplatRenderer(ctx, compositing=compositing)
    r.set_gaussians(g)
    r.set_support_map(m.permute(1, 2, 0).numpy())
    r.render(cam)
    np.testing.assert_allclose(np.clip(r.read_rgb(back.numpy()), 0, 1), shown, atol=0.01)  # the screenshot's path
    fbo = ctx.simple_framebuffer((96, 72), components=4)
    fbo.use()
    r.blit((0, 0, 96, 72), bg, support_camera=cam)
    blitted = np.frombuffer(fbo.read(components=3), np.uint8).reshape(72, 96, 3)[::-1] / 255.0
    assert psnr(blitted, shown) >= 40.0
    assert np.abs(blitted - shown).max() < 0.03  # half-float texels, 8-bit output
    r.blit((0, 0, 96, 72), bg)  # no camera: the colour
    plain = np.frombuffer(fbo.read(components=3), np.uint8).reshape(72, 96, 3)[::-1] / 255.0
    assert psnr(plain, np.clip(render(g, cam, background=bg).rgb.numpy(), 0, 1)) >= 40.0
    r.set_support_map(None)
    fbo.release()
    r.release()
