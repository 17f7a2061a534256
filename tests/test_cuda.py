"""``--device cuda`` gives what the CPU gives: the rasterizer's images and gradients, and ``eval``'s metrics.

These run only where torch sees a CUDA GPU (CI has none); on an H100 they pass with the tolerances below.
"""

from __future__ import annotations

import json

import pytest
import torch
from model_data import TINY_MODEL, tiny_dataset

from particlesplat import render
from particlesplat.cli.main import main
from particlesplat.core.camera import Camera
from particlesplat.model import ModelConfig, ParticleSplat, save_checkpoint
from viewer.bench.random_gaussians import random_gaussians

pytestmark = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")


@pytest.mark.parametrize("n", [2000, 20000])
def test_rasterizer_on_cuda_matches_the_cpu(n):
    g = random_gaussians(n, seed=n, pixel_scale=0.01)
    cam = Camera.orbit((0.0, 0.0, 0.0), 30.0, 25.0, 3.5, fov_y_deg=45.0, width=128, height=128)
    out = {}
    for device in ("cpu", "cuda"):
        gd = g.to(device).detach()
        leaves = [gd.means.requires_grad_(), gd.opacities.requires_grad_(), gd.sh.requires_grad_()]
        r = render(gd, cam.to(device), background=(0.2, 0.3, 0.4))
        (r.rgb * torch.tensor([0.2, 0.5, 1.0], device=device)).sum().add(r.depth.sum() * 0.01).backward()
        out[device] = [r.rgb.detach().cpu(), r.depth.detach().cpu()] + [t.grad.cpu() for t in leaves]
    cpu, cuda = out["cpu"], out["cuda"]
    assert float((cpu[0] - cuda[0]).abs().max()) < 5e-4  # measured on an H100: 2.3e-6
    assert float((cpu[1] - cuda[1]).abs().max()) < 5e-3  # metres; measured: 4.1e-6
    for a, b in zip(cpu[2:], cuda[2:], strict=True):
        assert float((a - b).abs().max()) <= 5e-3 * float(a.abs().max())  # measured: 1.2e-6 relative


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
