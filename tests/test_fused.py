"""The fused CPU kernels against their pure-torch twin and against float64 truth.

The rendering suites (test_render.py and the others marked with the ``rasterizer`` fixture) run every case with
both rasterizers against the float64 brute force; this file checks the kernels' own seams: the projection and its
analytic backward against autograd through the twin's formulas, gradients of a full render, serial against
parallel kernels, the switch, and a training run's losses.
"""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import torch

from particlesplat.core.camera import Camera
from particlesplat.core.gaussians import Gaussians, quats_to_rotations
from particlesplat.rendering.api import render, render_batch
from particlesplat.rendering.choice import resolve_rasterizer, set_default_rasterizer, use_rasterizer
from particlesplat.rendering.fused_projection import project_views_fused
from particlesplat.rendering.projection import project_views


def random_gaussians(n: int, seed: int, dtype=torch.float32, spread=(2.0, 2.0, 1.0), size=0.012) -> Gaussians:
    gen = torch.Generator().manual_seed(seed)
    means = (torch.rand(n, 3, generator=gen, dtype=torch.float64) - 0.5) * torch.tensor(spread, dtype=torch.float64)
    quats = torch.randn(n, 4, generator=gen, dtype=torch.float64)
    scales = torch.exp(torch.randn(n, 3, generator=gen, dtype=torch.float64) * 0.5) * size
    opacities = torch.rand(n, generator=gen, dtype=torch.float64) * 0.9 + 0.05
    sh = torch.randn(n, 4, 3, generator=gen, dtype=torch.float64) * 0.3
    owner = torch.randint(-1, 6, (n,), generator=gen)
    return Gaussians(*(t.to(dtype) for t in (means, quats, scales, opacities, sh)), owner)


def cameras(dtype=torch.float64) -> list[Camera]:
    """Three views: centred, off-axis and close (splats off screen and past the field of view's clamp), and a
    non-square one with its principal point off centre."""
    off = Camera.orbit((0.4, -0.3, 0.1), 70.0, 15.0, 0.9, width=48, height=40)
    K = off.K.clone()
    K[0, 2] += 7.0
    K[1, 2] -= 5.0
    return [
        Camera.orbit((0.0, 0.0, 0.0), 20.0, 30.0, 3.0, width=64, height=64).to(dtype=dtype),
        Camera(K, off.c2w, 48, 40).to(dtype=dtype),
        Camera.orbit((0.0, 0.0, 0.0), -110.0, 60.0, 1.2, width=40, height=56).to(dtype=dtype),
    ]


def _projection_and_grads(project, g: Gaussians, cams: list[Camera]):
    n = len(g)
    rows = torch.cat([torch.arange(n)] * len(cams))
    view = torch.repeat_interleave(torch.arange(len(cams)), n)
    means, quats, scales = (t.detach().clone().requires_grad_() for t in (g.means, g.quats, g.scales))
    proj = project(means, quats_to_rotations(quats), scales, rows, view, cams, 0.01, 1e10)
    gen = torch.Generator().manual_seed(3)
    weights = [torch.randn(t.shape, generator=gen, dtype=torch.float64) for t in (proj.means2d, proj.conics)]
    depth_w = torch.randn(proj.depths.shape, generator=gen, dtype=torch.float64)
    loss = (
        (proj.means2d * weights[0]).sum()
        + (proj.conics.double() * weights[1]).sum() * 100
        + (proj.depths.double() * depth_w).sum()
    )
    loss.backward()
    return proj, (means.grad, quats.grad, scales.grad)


def _rel(a: torch.Tensor, b: torch.Tensor) -> float:
    a, b = a.detach().double(), b.detach().double()
    return float((a - b).norm() / b.norm().clamp_min(1e-30))


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_projection_and_its_backward_match_the_twin(dtype):
    """Values and gradients of means, quaternions and scales, over views that clamp the Jacobian and cull."""
    g = random_gaussians(600, seed=1, dtype=dtype, spread=(3.0, 3.0, 2.0), size=0.05)
    cams = cameras(dtype)
    twin, twin_grads = _projection_and_grads(project_views, g, cams)
    fused, fused_grads = _projection_and_grads(project_views_fused, g, cams)
    assert torch.equal(twin.index, fused.index) and 0 < len(twin.index) < 3 * len(g)  # some culled
    tol = 1e-12 if dtype == torch.float64 else 2e-6
    for a, b in [
        (fused.means2d, twin.means2d),
        (fused.conics, twin.conics),
        (fused.depths, twin.depths),
        (fused.cov2d_diag, twin.cov2d_diag),
    ]:
        assert a.dtype == b.dtype and _rel(a, b) < tol
    for a, b in zip(fused_grads, twin_grads, strict=True):
        assert a.dtype == b.dtype and _rel(a, b) < tol * 10


def test_projection_backward_is_the_derivative_float64():
    """Finite differences of the fused projection itself (not just agreement with the twin)."""
    g = random_gaussians(5, seed=7, dtype=torch.float64, spread=(0.6, 0.6, 0.4), size=0.08)
    cams = cameras(torch.float64)[:2]
    rows = torch.cat([torch.arange(5)] * 2)
    view = torch.repeat_interleave(torch.arange(2), 5)

    def f(means, quats, scales):
        p = project_views_fused(means, quats_to_rotations(quats), scales, rows, view, cams, 0.01, 1e10)
        return p.means2d, p.conics, p.depths

    inputs = tuple(t.detach().clone().requires_grad_() for t in (g.means, g.quats, g.scales))
    assert torch.autograd.gradcheck(f, inputs, eps=1e-7, atol=1e-6, rtol=1e-5)


def _render_grads(g: Gaussians, cams: list[Camera], rasterizer: str):
    params = [t.detach().clone().requires_grad_() for t in (g.means, g.quats, g.scales, g.opacities, g.sh)]
    gg = Gaussians(*params, g.owner)
    out = render_batch([(gg, c) for c in cams], rasterizer=rasterizer, foreground=True, background=(0.1, 0.2, 0.3))
    gen = torch.Generator().manual_seed(5)
    loss = sum(
        (getattr(r, k) * torch.randn(getattr(r, k).shape, generator=gen, dtype=g.means.dtype)).sum()
        for r in out
        for k in ("rgb", "alpha", "depth", "foreground")
    )
    loss.backward()
    return out, [p.grad for p in params]


def test_render_and_gradients_match_the_twin_float32():
    """A 20k-splat batch of three views: images and gradients of means, quaternions, scales, opacities and SH."""
    g = random_gaussians(20000, seed=2)
    cams = [c.to(dtype=torch.float32) for c in cameras()]
    fused, fused_grads = _render_grads(g, cams, "fused")
    twin, twin_grads = _render_grads(g, cams, "torch")
    for a, b in zip(fused, twin, strict=True):
        for k in ("rgb", "alpha", "depth", "foreground"):
            assert (getattr(a, k) - getattr(b, k)).abs().max() < 2e-5, k
    for name, a, b in zip(("means", "quats", "scales", "opacities", "sh"), fused_grads, twin_grads, strict=True):
        assert _rel(a, b) < 1e-4, name


def test_parallel_kernels_give_the_serial_result():
    """Tiles run in parallel over threads; each pair belongs to one tile, so the result is bit for bit the same."""
    g = random_gaussians(5000, seed=4)
    cams = [c.to(dtype=torch.float32) for c in cameras()]
    before = torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        serial, serial_grads = _render_grads(g, cams, "fused")
        torch.set_num_threads(2)
        parallel, parallel_grads = _render_grads(g, cams, "fused")
    finally:
        torch.set_num_threads(before)
    for a, b in zip(serial, parallel, strict=True):
        assert torch.equal(a.rgb, b.rgb) and torch.equal(a.depth, b.depth)
    for a, b in zip(serial_grads, parallel_grads, strict=True):
        assert torch.allclose(a, b, rtol=1e-6, atol=1e-9)  # the per-Gaussian sums may add in another order


def test_owner_weights_ride_along_in_both():
    g = random_gaussians(3000, seed=6)
    cam = cameras(torch.float32)[0]
    a = render(g, cam, owner_weights=True, rasterizer="fused")
    b = render(g, cam, owner_weights=True, rasterizer="torch")
    assert (a.require_owner_weights() - b.require_owner_weights()).abs().max() < 1e-5
    assert torch.equal(a.segmentation(), b.segmentation())


def test_the_switch():
    from particlesplat.rendering.measured import measured_choice

    cpu = torch.device("cpu")
    measured = measured_choice(False)  # the CPU default: the one measured faster on this machine
    assert resolve_rasterizer(None, cpu) == measured
    assert resolve_rasterizer("torch", cpu) == "torch"
    assert resolve_rasterizer("auto", torch.device("cuda")) == "torch"  # the twin is the CUDA path
    with pytest.raises(ValueError, match="runs on the CPU"):
        resolve_rasterizer("fused", torch.device("cuda"))
    with use_rasterizer("torch"):
        assert resolve_rasterizer(None, cpu) == "torch"
        assert resolve_rasterizer("fused", cpu) == "fused"  # a render's own choice wins
    assert resolve_rasterizer(None, cpu) == measured
    with pytest.raises(ValueError, match="unknown rasterizer"):
        set_default_rasterizer("cuda")


def test_environment_variable(monkeypatch):
    monkeypatch.setenv("PARTICLESPLAT_RASTERIZER", "torch")
    assert resolve_rasterizer(None, torch.device("cpu")) == "torch"
    monkeypatch.setenv("PARTICLESPLAT_RASTERIZER", "gpu")
    with pytest.raises(ValueError, match="PARTICLESPLAT_RASTERIZER: unknown rasterizer 'gpu'"):
        resolve_rasterizer(None, torch.device("cpu"))


def test_empty_and_all_culled():
    g = random_gaussians(10, seed=0)
    behind = Camera.orbit((0.0, 0.0, 0.0), 0.0, 0.0, 3.0, width=16, height=16)
    far_away = Gaussians(g.means + torch.tensor([0.0, 0.0, 1e4]), g.quats, g.scales, g.opacities, g.sh, g.owner)
    out = render(far_away, behind, rasterizer="fused", background=(0.5, 0.5, 0.5))
    assert torch.all(out.alpha == 0) and torch.allclose(out.rgb, torch.full_like(out.rgb, 0.5))
    empty = Gaussians(*(t[:0] for t in (g.means, g.quats, g.scales, g.opacities, g.sh)), g.owner[:0])
    assert torch.all(render(empty, behind, rasterizer="fused").alpha == 0)


def _brute_force_tile_lists(means2d, conics, log_o, radius, depths, view, sizes) -> list[list[int]]:
    """Each tile's list under the documented rule, in float64 and image coordinates: Gaussian i is a candidate
    for the tiles holding a pixel whose centre lies in its box [m - r, m + r], and is listed in one iff
    ln o - d^T C d / 2 >= ln(1/255) - 1e-3 at one of that tile's 16 pixel centres; each list front to back by
    depth, ties by row."""
    from particlesplat.rendering.rasterize import TILE, tile_grids

    grids = tile_grids(sizes)
    lists: list[list[tuple[float, int]]] = [[] for _ in range(sum(tx * ty for tx, ty, _ in grids))]
    thresh = math.log(1 / 255) - 1e-3
    offsets = torch.arange(TILE, dtype=torch.float64) + 0.5
    for i in range(means2d.shape[0]):
        v = int(view[i])
        (w, h), (tx, _, first) = sizes[v], grids[v]
        (mx, my), (rx, ry) = means2d[i].tolist(), radius[i].tolist()
        if rx < 0:
            continue
        a, b, c = conics[i].tolist()
        covered_x = [u for u in range(w) if mx - rx <= u + 0.5 <= mx + rx]
        covered_y = [u for u in range(h) if my - ry <= u + 0.5 <= my + ry]
        for t in {(u // TILE, r // TILE) for u in covered_x for r in covered_y}:
            dx = (t[0] * TILE + offsets)[None, :] - mx
            dy = (t[1] * TILE + offsets)[:, None] - my
            e = float(log_o[i]) - 0.5 * (a * dx * dx + 2 * b * dx * dy + c * dy * dy)
            if float(e.max()) >= thresh:
                lists[first + t[1] * tx + t[0]].append((float(depths[i]), i))
    return [[i for _, i in sorted(tile)] for tile in lists]


def test_tile_lists_match_a_brute_force_with_tied_depths():
    """The fused binning (candidate boxes, the nearest-pixel shortcut before the 16-pixel test, the packed depth
    sort) against the rule written out per tile; depths rounded to a few values so that most rows tie."""
    from particlesplat.rendering.fused import bin_fused

    g = random_gaussians(400, seed=11, size=0.05)
    cams = [c.to(dtype=torch.float32) for c in cameras()]
    rows = torch.cat([torch.arange(len(g))] * len(cams))
    view = torch.repeat_interleave(torch.arange(len(cams)), len(g))
    proj = project_views(g.means, quats_to_rotations(g.quats), g.scales, rows, view, cams, 0.01, 1e10)
    kept_view = view[proj.index]
    opac = g.opacities[rows[proj.index]]
    log_o = torch.log(opac.clamp_min(1e-30))
    radius = 3.0 * proj.cov2d_diag.double().sqrt()  # a generous box: the exact test decides
    radius[::7] = -1.0  # and some rows without a footprint
    for depths in (torch.round(proj.depths * 4) / 4, proj.depths.double()):
        sizes = [(c.width, c.height) for c in cams]
        bins = bin_fused(proj.means2d, proj.conics, log_o, radius, depths, kept_view, sizes)
        truth = _brute_force_tile_lists(
            proj.means2d.double(), proj.conics.double(), log_o, radius, depths, kept_view, sizes
        )
        got = [bins.gauss[bins.tile_start[t] : bins.tile_start[t + 1]].tolist() for t in range(len(truth))]
        assert sum(map(len, truth)) > 1000
        assert got == truth


def test_depth_order_is_a_stable_sort_by_depth():
    """The packed float32 key against torch's stable sort: ties, negative depths, -0.0 beside 0.0; float64 too."""
    from particlesplat.rendering.depth_order import depth_order

    gen = torch.Generator().manual_seed(5)
    d = torch.randint(-20, 20, (5000,), generator=gen).float() / 8
    d[::13] = -0.0
    d[1::17] = 0.0
    d[2::19] = torch.tensor([3.4028e38, -3.4028e38, 1e-45, -1e-45]).repeat(100)[: d[2::19].numel()]
    rows = torch.nonzero(torch.rand(5000, generator=gen) < 0.8).squeeze(1)
    for depths in (d, d.double()):
        truth = rows[torch.sort(depths[rows], stable=True).indices]
        assert torch.equal(torch.from_numpy(depth_order(depths[rows].numpy(), rows.numpy())), truth)


def test_summing_pairs_per_gaussian_is_index_add_bit_for_bit():
    from particlesplat.rendering.fused_kernels import scatter_add_rows

    gen = torch.Generator().manual_seed(8)
    for dtype in (torch.float32, torch.float64):
        values = torch.randn(20000, 11, generator=gen, dtype=dtype) * torch.logspace(-6, 6, 11, dtype=dtype)
        index = torch.randint(0, 300, (20000,), generator=gen)
        out = torch.zeros(300, 11, dtype=dtype)
        scatter_add_rows(index.numpy(), values.numpy(), out.numpy())
        assert torch.equal(out, torch.zeros(300, 11, dtype=dtype).index_add_(0, index, values))


@pytest.mark.slow
def test_training_losses_match_the_twin(tmp_path_factory, tmp_path):
    """The first 100 losses of a training run on the fused kernels and on the twin agree to float32 rounding.

    The two differ only in rounding (the kernels sum in float64, the twin in float32), so now and then a pair-pixel
    lands on the other side of a cut-off (α ≥ 1/255, the 0.99 clamp, T ≤ 1e-4) and that step's loss moves (measured
    on this run: median 9e-8, 95th step 1.1e-4, worst 4.0e-4; how far depends on the run's path, since a flip moves
    what the next steps see); the runs do not drift apart, which the median holds.
    """
    from model_data import TINY_MODEL, tiny_dataset

    from particlesplat.model import ModelConfig, TrainConfig
    from particlesplat.training.trainer import Trainer

    data = Path(tiny_dataset(tmp_path_factory))
    losses = {}
    for name in ("torch", "fused"):
        tc = TrainConfig(batch_size=2, target_views=1, steps=100, lr=1e-3, seed=3)
        with use_rasterizer(name):
            trainer = Trainer(ModelConfig(**TINY_MODEL), tc, data, tmp_path / name, "cpu", False)
            try:
                losses[name] = [float(trainer.train_step()["loss"]) for _ in range(100)]
            finally:
                trainer.lock.release()
    rel = sorted(abs(a - b) / abs(b) for a, b in zip(losses["fused"], losses["torch"], strict=True))
    assert all(math.isfinite(r) for r in rel)
    assert rel[50] < 2e-6  # the median step: float32 rounding, no drift
    assert rel[90] < 1e-4  # 90 of the 100 steps within 1e-4
    assert rel[-1] < 1e-3  # and no step beyond a few cut-off flips' size
