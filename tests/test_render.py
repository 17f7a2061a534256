"""``particlesplat.render`` against the independent float64 brute force, analytic cases,
gradcheck and a suite of hard cases."""

from __future__ import annotations

import math
import os
import subprocess
import sys
import textwrap
from dataclasses import replace

import pytest
import torch
from reference_render import reference_render
from render_checks import (
    BG,
    F32,
    F64,
    SH_C0,
    check_against_reference,
    leaves,
    make,
    pinhole,
    random_scene,
)

from particlesplat import Camera, Gaussians, render

pytestmark = pytest.mark.usefixtures("rasterizer")  # every test: fused kernels and torch twin


# ---------------------------------------------------------------------------------------------- random sets
@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_random_sets_match_reference(seed: int, degree: int) -> None:
    gs, cam = random_scene(seed, 40, degree)
    ref = check_against_reference(gs, cam, background=BG, grads=(seed == 0))
    assert ref.alpha.max() > 0.5  # the scene is actually visible


@pytest.mark.parametrize("size", [(37, 23), (23, 37), (1, 1), (64, 48), (17, 1)])
def test_image_sizes_match_reference(size) -> None:
    gs, cam = random_scene(3, 60, 1, width=size[0], height=size[1])
    check_against_reference(gs, cam, background=BG, grads=size == (37, 23), check64=False)


def test_principal_point_and_aspect_not_centred() -> None:
    gs, _ = random_scene(4, 40, 2)
    c2w = Camera.look_at((0.5, -3.5, 0.8), (0.0, 0.0, 0.0), dtype=F64).c2w
    K = torch.tensor([[40.0, 0.0, 11.3], [0.0, 28.0, 15.9], [0.0, 0.0, 1.0]], dtype=F64)
    check_against_reference(gs, Camera(K, c2w, 37, 23), background=BG)


def test_near_far_culling_matches_reference() -> None:
    gs, cam = random_scene(5, 60, 0)
    check_against_reference(gs, cam, background=BG, near=3.6, far=4.4, grads=False)


def test_foreground_weight_matches_reference_and_has_the_opacity_gradient() -> None:
    """foreground = Σ T·α over owners >= 0 (float64 reference), and its gradient with respect to an
    opacity matches a central finite difference of the float64 renderer."""
    gs, cam = random_scene(6, 50, 1)
    ref = reference_render(gs, cam, background=BG, num_owners=5)
    res = render(gs, cam.to(dtype=F32), background=BG, foreground=True)
    assert res.owner_weights is None
    assert (res.foreground.double() - ref.owner_weights.sum(0)).abs().max() <= 1e-5
    both = render(gs, cam.to(dtype=F32), background=BG, foreground=True, owner_weights=True, num_owners=5)
    torch.testing.assert_close(both.foreground, res.foreground)
    assert (both.owner_weights.double() - ref.owner_weights).abs().max() <= 1e-5
    g64 = gs.to(dtype=F64)
    opac = g64.opacities.clone().requires_grad_(True)
    fg = render(replace(g64, opacities=opac), cam, background=BG, foreground=True).foreground
    weights = torch.linspace(0.5, 1.5, fg.numel(), dtype=F64).reshape(fg.shape)
    (fg * weights).sum().backward()
    particle = (gs.owner >= 0).nonzero()[:5, 0]
    assert bool((opac.grad[particle].abs() > 0).any())
    for i in particle.tolist():
        h = 1e-6
        vals = []
        for sgn in (1, -1):
            o = g64.opacities.clone()
            o[i] += sgn * h
            vals.append(
                float(
                    (render(replace(g64, opacities=o), cam, background=BG, foreground=True).foreground * weights).sum()
                )
            )
        assert float(opac.grad[i]) == pytest.approx((vals[0] - vals[1]) / (2 * h), rel=1e-4, abs=1e-7)


def test_owner_weights_and_segmentation_match_reference() -> None:
    gs, cam = random_scene(6, 50, 1)
    ref = reference_render(gs, cam, background=BG, num_owners=5)
    res = render(gs, cam.to(dtype=F32), background=BG, owner_weights=True, num_owners=5)
    assert res.owner_weights.shape == (5, 23, 37)
    assert (res.owner_weights.double() - ref.owner_weights).abs().max() <= 1e-5
    assert (res.background_weight.double() - ref.background_weight).abs().max() <= 1e-5
    # owner maps and the background map partition alpha
    total = res.owner_weights.sum(0) + res.background_weight
    assert (total - res.alpha).abs().max() <= 1e-5
    assert ref.owner_weights[4].abs().max() == 0  # owner 4 has no Gaussians
    seg, seg_ref = res.segmentation(), ref.segmentation()
    assert seg.dtype == torch.int64 and seg.shape == (23, 37)
    # compare wherever the winner is not a near tie
    scores = torch.cat([(ref.background_weight + ref.transmittance)[None], ref.owner_weights])
    top2 = scores.topk(2, dim=0).values
    clear = (top2[0] - top2[1]) > 1e-4
    assert clear.float().mean() > 0.95
    assert torch.equal(seg[clear], seg_ref[clear])
    assert {-1, 0, 1, 2, 3} <= set(seg.unique().tolist())
    # default P is max owner + 1
    res_default = render(gs, cam.to(dtype=F32), owner_weights=True)
    assert res_default.owner_weights.shape[0] == int(gs.owner.max()) + 1


def test_segmentation_clear_cases() -> None:
    cam = pinhole(21, 15)
    gs = make(
        [[-0.3, 0.0, 2.0], [0.3, 0.0, 2.0], [0.0, 0.0, 1.5]],
        scales=[[0.08] * 3, [0.08] * 3, [0.02] * 3],
        opacities=[0.95, 0.95, 0.99],
        owner=[0, 2, -1],
    )
    res = render(gs, cam, owner_weights=True)
    seg = res.segmentation()
    u0, u1 = int(10.5 - 30 * 0.15), int(10.5 + 30 * 0.15)
    assert seg[7, u0] == 0 and seg[7, u1] == 2
    assert seg[7, 10] == -1  # the background-owned splat in front wins
    assert seg[0, 0] == -1  # empty
    assert res.owner_weights.shape == (3, 15, 21) and res.owner_weights[1].abs().max() == 0
    with pytest.raises(ValueError):
        render(gs, cam).segmentation()


# ---------------------------------------------------------------------------------------------- analytic
def _sigma_px2(f: float, s: float, z: float) -> float:
    return (f * s / z) ** 2 + 0.3


def test_analytic_isotropic_facing_camera() -> None:
    f, s, z, o = 40.0, 0.2, 2.0, 0.9
    cam = pinhole(33, 33, f)
    sh = torch.zeros(1, 1, 3, dtype=F64)
    sh[0, 0] = torch.tensor([0.3, -0.2, 0.1], dtype=F64) / SH_C0  # colour 0.8, 0.3, 0.6
    color = torch.tensor([0.8, 0.3, 0.6], dtype=F64)
    res = render(make([[0.0, 0.0, z]], scales=[[s, s, s]], opacities=[o], sh=sh, dtype=F64), cam, background=BG)
    s2 = _sigma_px2(f, s, z)  # 16.3 px^2
    v, u = torch.meshgrid(torch.arange(33, dtype=F64), torch.arange(33, dtype=F64), indexing="ij")
    r2 = (u + 0.5 - 16.5) ** 2 + (v + 0.5 - 16.5) ** 2
    contour_r2 = 2 * s2 * math.log(255 * o)  # the alpha = 1/255 contour, 177.2 px^2
    assert (r2 - contour_r2).abs().min() > 0.5  # configuration: no pixel centre near the contour
    inside = r2 <= contour_r2
    assert torch.equal(res.alpha > 0, inside)
    # Gauss circle count of lattice points with dx² + dy² <= 177.2: Σ_a (2⌊√(177.2 - a²)⌋ + 1) = 553
    assert int(inside.sum()) == 553
    alpha = torch.where(inside, o * torch.exp(-0.5 * r2 / s2), torch.zeros_like(r2))
    torch.testing.assert_close(res.alpha, alpha, atol=1e-12, rtol=0)
    assert abs(float(res.alpha[16, 16]) - o) < 1e-12  # peak
    torch.testing.assert_close(
        res.depth, torch.where(inside, torch.full_like(r2, z), torch.zeros_like(r2)), atol=1e-12, rtol=0
    )
    want = alpha[..., None] * color + (1 - alpha[..., None]) * torch.tensor(BG, dtype=F64)
    torch.testing.assert_close(res.rgb, want, atol=1e-12, rtol=0)
    # opacity 1: the peak is clamped to 0.99
    res1 = render(make([[0.0, 0.0, z]], scales=[[s, s, s]], opacities=[1.0], dtype=F64), cam)
    assert abs(float(res1.alpha[16, 16]) - 0.99) < 1e-12


def test_analytic_footprint_float32() -> None:
    """The float32 renderer covers exactly the alpha >= 1/255 disc (no 3-sigma cut)."""
    f, s, z, o = 40.0, 0.2, 2.0, 0.9
    cam = pinhole(33, 33, f)
    res = render(make([[0.0, 0.0, z]], scales=[[s, s, s]], opacities=[o]), cam)
    v, u = torch.meshgrid(torch.arange(33, dtype=F64), torch.arange(33, dtype=F64), indexing="ij")
    r2 = (u - 16.0) ** 2 + (v - 16.0) ** 2
    inside = r2 <= 2 * _sigma_px2(f, s, z) * math.log(255 * o)
    assert torch.equal(res.alpha > 0, inside)
    # the 1/255 contour lies at 3.3 sigma here, beyond a 3-sigma cut
    assert math.sqrt(2 * math.log(255 * o)) > 3.2


def test_analytic_rotated_anisotropic_wxyz() -> None:
    """A Gaussian rotated by theta about the optical axis: Σ2D = (f/z)² R diag(sx², sy²) Rᵀ + 0.3 I."""
    f, z, o, theta = 30.0, 3.0, 0.8, 0.6
    sx, sy, sz = 0.5, 0.15, 0.7
    cam = pinhole(37, 23, f)
    q = [math.cos(theta / 2), 0.0, 0.0, math.sin(theta / 2)]  # wxyz
    res = render(make([[0.0, 0.0, z]], quats=[q], scales=[[sx, sy, sz]], opacities=[o], dtype=F64), cam)
    c, s = math.cos(theta), math.sin(theta)
    R2 = torch.tensor([[c, -s], [s, c]], dtype=F64)
    cov = (f / z) ** 2 * R2 @ torch.diag(torch.tensor([sx * sx, sy * sy], dtype=F64)) @ R2.T
    cov = cov + 0.3 * torch.eye(2, dtype=F64)
    v, u = torch.meshgrid(torch.arange(23, dtype=F64), torch.arange(37, dtype=F64), indexing="ij")
    d = torch.stack([u + 0.5 - 18.5, v + 0.5 - 11.5], -1)
    m = (d @ torch.linalg.inv(cov) * d).sum(-1)
    a = o * torch.exp(-0.5 * m)
    a = torch.where(a >= 1 / 255, a, torch.zeros_like(a))
    torch.testing.assert_close(res.alpha, a, atol=1e-12, rtol=0)
    # the main axis runs along +theta: the pixel 5 px along it is brighter than 5 px across it
    assert res.alpha[11 + round(5 * s), 18 + round(5 * c)] > 5 * res.alpha[11 + round(5 * c), 18 - round(5 * s)]


@pytest.mark.parametrize("x_over_z,s", [(0.2, 0.35), (1.9, 1.0), (-2.5, 1.4)])
def test_analytic_off_axis_jacobian_and_fov_clamp(x_over_z: float, s: float) -> None:
    """Isotropic Σ = s²I off axis: Σ2D = s²(f/z)² [[1+tx², tx·ty], [tx·ty, 1+ty²]] + 0.3 I with
    tx, ty clamped to the field of view + 30 %; the centre itself is not clamped."""
    f, z, o = 30.0, 2.0, 0.9
    W, H = 37, 23
    cam = pinhole(W, H, f)
    y_over_z = 0.15
    mean = [x_over_z * z, y_over_z * z, z]
    res = render(make([mean], scales=[[s, s, s]], opacities=[o], dtype=F64), cam)
    limx = (W / 2) / f + 0.3 * 0.5 * W / f
    tx = max(-limx, min(limx, x_over_z))
    ty = y_over_z
    cov = s * s * (f / z) ** 2 * torch.tensor([[1 + tx * tx, tx * ty], [tx * ty, 1 + ty * ty]], dtype=F64)
    cov = cov + 0.3 * torch.eye(2, dtype=F64)
    mu = torch.tensor([f * x_over_z + W / 2, f * y_over_z + H / 2], dtype=F64)
    v, u = torch.meshgrid(torch.arange(H, dtype=F64), torch.arange(W, dtype=F64), indexing="ij")
    d = torch.stack([u + 0.5, v + 0.5], -1) - mu
    a = o * torch.exp(-0.5 * (d @ torch.linalg.inv(cov) * d).sum(-1))
    a = torch.where(a >= 1 / 255, a, torch.zeros_like(a))
    assert a.max() > 0.01  # the footprint is on screen even when the centre is not
    torch.testing.assert_close(res.alpha, a, atol=1e-12, rtol=0)


def test_analytic_compositing_and_termination() -> None:
    """Front-to-back at the centre pixel, termination before the Gaussian taking T to <= 1e-4, and a
    stopped pixel stays stopped (a later faint Gaussian would not reach the threshold)."""
    cam = pinhole(33, 33, 40.0)
    cols = torch.tensor([[0.9, 0.1, 0.1], [0.1, 0.9, 0.1], [0.1, 0.1, 0.9], [0.5, 0.5, 0.5]], dtype=F64)
    sh = ((cols - 0.5) / SH_C0)[:, None, :]
    # listed back to front on purpose; opacities 0.995 (alpha 0.99), 0.98, 0.9, 0.1 by depth
    z = [5.0, 4.0, 3.0, 2.0]
    opac = [0.1, 0.9, 0.98, 0.995]
    gs = make([[0.0, 0.0, zi] for zi in z], scales=[[0.3] * 3] * 4, opacities=opac, sh=sh.flip(0), dtype=F64)
    res = render(gs, cam, background=BG)
    a1, a2 = 0.99, 0.98
    T = (1 - a1) * (1 - a2)  # 2e-4 > 1e-4; the next (0.9) would take it to 2e-5: stop
    rgb = a1 * cols[0] + a2 * (1 - a1) * cols[1] + T * torch.tensor(BG, dtype=F64)
    torch.testing.assert_close(res.rgb[16, 16], rgb, atol=1e-12, rtol=0)
    assert abs(float(res.alpha[16, 16]) - (1 - T)) < 1e-12
    assert abs(float(res.depth[16, 16]) - (a1 * 2.0 + a2 * (1 - a1) * 3.0) / (1 - T)) < 1e-12
    # two Gaussians, no termination
    res2 = render(
        make([[0.0, 0.0, 3.0], [0.0, 0.0, 2.0]], scales=[[0.3] * 3] * 2, opacities=[0.6, 0.5], sh=sh[:2], dtype=F64),
        cam,
        background=BG,
    )
    rgb2 = 0.5 * cols[1] + 0.6 * 0.5 * cols[0] + 0.5 * 0.4 * torch.tensor(BG, dtype=F64)
    torch.testing.assert_close(res2.rgb[16, 16], rgb2, atol=1e-12, rtol=0)
    assert abs(float(res2.depth[16, 16]) - (0.5 * 2.0 + 0.3 * 3.0) / 0.8) < 1e-12


def test_sh_view_dependence_matches_reference() -> None:
    """Degree-1 colour depends on the direction camera -> mean (here B_1 = -C1·y)."""
    cam = pinhole(33, 33, 40.0)
    sh = torch.zeros(2, 4, 3, dtype=F64)
    sh[:, 1, 0] = 1.0  # red channel follows -C1 * dir_y
    gs = make([[0.0, -0.5, 2.0], [0.0, 0.5, 2.0]], scales=[[0.05] * 3] * 2, opacities=[0.9, 0.9], sh=sh, dtype=F64)
    res = render(gs, cam)
    c1 = math.sqrt(3 / (4 * math.pi))
    for v, dir_y in ((6, -0.5 / math.hypot(0.5, 2.0)), (26, 0.5 / math.hypot(0.5, 2.0))):
        assert float(res.alpha[v, 16]) > 0.5
        red = float(res.rgb[v, 16, 0]) / float(res.alpha[v, 16])
        assert abs(red - (0.5 - c1 * dir_y)) < 1e-9
        assert abs(float(res.rgb[v, 16, 1]) / float(res.alpha[v, 16]) - 0.5) < 1e-9


# ---------------------------------------------------------------------------------------------- gradients
def _gradcheck(renderer, cam: Camera, params: tuple[torch.Tensor, ...], owner: torch.Tensor, fast_mode: bool) -> bool:
    """torch.autograd.gradcheck of ``renderer`` w.r.t. (means, quats, scales, opacities, sh)."""

    def fn(m, q, s, o, c):
        r = renderer(Gaussians(m, q, s, o, c, owner), cam, background=BG)
        return r.rgb, r.alpha, r.depth

    inputs = tuple(t.clone().requires_grad_(True) for t in params)
    return torch.autograd.gradcheck(fn, inputs, eps=1e-6, atol=1e-6, rtol=1e-4, fast_mode=fast_mode)


def test_gradcheck_float64() -> None:
    """Smooth configuration: every pixel well inside every footprint, no clamp, no termination."""
    cam = pinhole(9, 7, 12.0)
    gen = torch.Generator().manual_seed(3)
    params = (
        torch.tensor([[0.05, -0.02, 2.0], [-0.1, 0.08, 2.5], [0.12, 0.1, 3.1]], dtype=F64),
        torch.randn(3, 4, generator=gen, dtype=F64),
        torch.tensor([[0.9, 0.6, 0.5], [0.7, 1.1, 0.8], [1.0, 0.8, 1.2]], dtype=F64),
        torch.tensor([0.5, 0.6, 0.7], dtype=F64),
        torch.randn(3, 4, 3, generator=gen, dtype=F64) * 0.2,
    )
    owner = torch.tensor([0, 1, -1])
    ref = reference_render(make(*params, owner, dtype=F64), cam)
    assert ref.alpha.min() > 0.5 and ref.transmittance.min() > 1e-3  # every pixel, every Gaussian counts
    assert _gradcheck(render, cam, params, owner, fast_mode=True)


def test_gradcheck_float64_full_jacobian_small() -> None:
    params = (
        torch.tensor([[0.03, -0.02, 1.5], [-0.05, 0.04, 2.0]], dtype=F64),
        torch.tensor([[0.9, 0.1, -0.3, 0.2], [0.5, -0.5, 0.4, 0.1]], dtype=F64),
        torch.tensor([[0.6, 0.4, 0.5], [0.5, 0.7, 0.3]], dtype=F64),
        torch.tensor([0.45, 0.65], dtype=F64),
        torch.tensor([[[0.3, -0.1, 0.2]], [[-0.2, 0.4, 0.1]]], dtype=F64),
    )
    assert _gradcheck(render, pinhole(5, 4, 8.0), params, torch.tensor([0, 0]), fast_mode=False)


def test_reference_gradcheck() -> None:
    """The reference's own autograd (used as gradient truth above) against finite differences."""
    params = (
        torch.tensor([[0.05, -0.02, 2.0], [-0.1, 0.08, 2.5]], dtype=F64),
        torch.tensor([[0.9, 0.1, -0.3, 0.2], [0.5, -0.5, 0.4, 0.1]], dtype=F64),
        torch.tensor([[0.9, 0.6, 0.5], [0.7, 1.1, 0.8]], dtype=F64),
        torch.tensor([0.5, 0.6], dtype=F64),
        torch.randn(2, 4, 3, generator=torch.Generator().manual_seed(0), dtype=F64) * 0.2,
    )
    assert _gradcheck(reference_render, pinhole(6, 5, 10.0), params, torch.tensor([0, 1]), fast_mode=True)


# ---------------------------------------------------------------------------------------------- misc
def test_empty_and_all_culled() -> None:
    cam = pinhole()
    res = render(Gaussians.empty(1), cam, background=BG, owner_weights=True, num_owners=2)
    torch.testing.assert_close(res.rgb, torch.tensor(BG).expand(23, 37, 3), atol=0, rtol=0)
    assert res.alpha.abs().max() == 0 and res.depth.abs().max() == 0
    assert res.owner_weights.shape == (2, 23, 37) and (res.segmentation() == -1).all()
    d, g = leaves(make([[0.0, 0.0, -1.0]]), F32)
    r = render(g, cam, background=BG)
    r.rgb.sum().backward()
    assert d["means"].grad.abs().max() == 0


def test_memory_is_bounded_for_200k_gaussians() -> None:
    """Forward + backward of 200k Gaussians at 256²: an all-pairs renderer would need ~50 GB per
    float32 buffer; the peak resident memory must stay a small fraction of that."""
    code = textwrap.dedent("""
        import resource, torch
        from particlesplat import Camera, Gaussians, render
        n, S = 200_000, 256
        g = torch.Generator().manual_seed(0)
        cam = Camera.look_at((0.0, -4.0, 1.0), (0.0, 0.0, 0.0), width=S, height=S)
        leaves = [(torch.rand(n, 3, generator=g) - 0.5) * 3, torch.randn(n, 4, generator=g),
                  torch.rand(n, 3, generator=g) * 0.02 + 0.002, torch.rand(n, generator=g),
                  torch.randn(n, 1, 3, generator=g) * 0.3]
        for t in leaves:
            t.requires_grad_(True)
        gs = Gaussians(*leaves, torch.randint(-1, 5, (n,), generator=g))
        before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        r = render(gs, cam)
        (r.rgb.sum() + r.depth.sum()).backward()
        assert bool(torch.isfinite(leaves[0].grad).all())
        after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        print((after - before) // 1024, float(r.alpha.mean()))
    """)
    out = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        timeout=600,
        env={"OMP_NUM_THREADS": "2", **os.environ},
    )
    assert out.returncode == 0, out.stderr
    grew_mb, mean_alpha = out.stdout.split()
    assert float(mean_alpha) > 0.5
    assert int(grew_mb) < 1500, f"peak memory grew by {grew_mb} MB"
