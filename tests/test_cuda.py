"""``--device cuda`` gives what the CPU gives: the rasterizer's images and gradients, and ``eval``'s metrics.

The CUDA tests run only where torch sees a CUDA GPU (CI has none). The rasterizer's image is discontinuous at
its cut-offs (α ≥ 1/255, and T stops a pixel's list), so float32 rounding of another device moves a few
pixels by up to a cut-off Gaussian's contribution: the comparison allows what a rounding-level perturbation of
the means does on the CPU alone (the first test, which runs everywhere, measures that).
"""

from __future__ import annotations

import dataclasses
import json

import pytest
import torch
from model_data import TINY_MODEL, tiny_dataset
from torch import Tensor

from particlesplat import render
from particlesplat.cli.main import main
from particlesplat.core.camera import Camera
from particlesplat.model import ModelConfig, ParticleSplat, save_checkpoint
from viewer.bench.random_gaussians import random_gaussians

needs_cuda = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")


def _render_with_grads(n: int, device: str, means_scale: Tensor | None = None) -> list[Tensor]:
    """Colour (H, W, 3), depth (H, W) and the gradients of means, opacities and SH of random set ``n``."""
    g = random_gaussians(n, seed=n, pixel_scale=0.01)
    if means_scale is not None:
        g = dataclasses.replace(g, means=g.means * means_scale)
    cam = Camera.orbit((0.0, 0.0, 0.0), 30.0, 25.0, 3.5, fov_y_deg=45.0, width=128, height=128)
    gd = g.to(device).detach()
    leaves = [gd.means.requires_grad_(), gd.opacities.requires_grad_(), gd.sh.requires_grad_()]
    r = render(gd, cam.to(device), background=(0.2, 0.3, 0.4))
    (r.rgb * torch.tensor([0.2, 0.5, 1.0], device=device)).sum().add(r.depth.sum() * 0.01).backward()
    return [r.rgb.detach().cpu(), r.depth.detach().cpu()] + [t.grad.cpu() for t in leaves]


def _assert_same_up_to_cutoffs(a: list[Tensor], b: list[Tensor]) -> None:
    """Two renders agree but for the few pixels where rounding flips a cut-off.

    Measured on the CPU (six 1e-7 relative perturbations of the means, 20,000 Gaussians; the first test makes
    three): at most 13 of 16,384 pixels moved by more than 1e-4 (the largest by 1.0e-2), the mean colour change
    was at most 1.4e-6, and the gradients moved by at most 6.4e-4 of their norm.
    """
    colour, depth = (a[0] - b[0]).abs(), (a[1] - b[1]).abs()
    pixels = colour.shape[0] * colour.shape[1]
    assert int((colour > 1e-4).any(-1).sum()) <= 0.005 * pixels
    assert float(colour.mean()) < 1e-5
    assert int((depth > 1e-3).sum()) <= 0.005 * pixels  # metres
    assert float(depth.mean()) < 1e-5
    for ga, gb in zip(a[2:], b[2:], strict=True):
        assert float((ga - gb).norm()) <= 5e-3 * float(ga.norm())


@pytest.mark.parametrize("n", [2000, 20000])
def test_a_rounding_level_change_moves_only_pixels_at_the_cutoffs(n):
    ref = _render_with_grads(n, "cpu")
    for seed in range(3):
        torch.manual_seed(seed)
        scale = 1.0 + 1e-7 * torch.randn(n, 3)
        _assert_same_up_to_cutoffs(ref, _render_with_grads(n, "cpu", scale))


@needs_cuda
@pytest.mark.parametrize("n", [2000, 20000])
def test_rasterizer_on_cuda_matches_the_cpu(n):
    _assert_same_up_to_cutoffs(_render_with_grads(n, "cpu"), _render_with_grads(n, "cuda"))


@needs_cuda
def test_eval_on_cuda_reports_the_cpu_metrics(tmp_path_factory, tmp_path):
    data = tiny_dataset(tmp_path_factory)
    torch.manual_seed(0)
    ckpt = tmp_path / "m.pt"
    save_checkpoint(ckpt, ParticleSplat(ModelConfig(**TINY_MODEL)), step=0)
    means = {}
    for device in ("cpu", "cuda"):
        out = tmp_path / f"{device}.json"
        args = ["eval", "--checkpoint", str(ckpt), "--data", str(data / "val"), "--json", str(out)]
        assert main([*args, "--device", device, "--prune", "--figures", str(tmp_path / device)]) == 0
        means[device] = json.loads(out.read_text())["mean"]
    for key in ("psnr", "ssim", "fg_ari", "miou", "active_particles", "gaussians"):
        assert means["cuda"][key] == pytest.approx(means["cpu"][key], rel=1e-3, abs=1e-3), key
