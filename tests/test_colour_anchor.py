"""Particles that keep the colours their context view shows under their cells (``patch.colour_anchor``): an
untrained decoder draws each cell in exactly that colour, the colours travel with the particle through
``Particles`` rows, and a model without the option is unchanged."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from model_data import TINY_MODEL

from particlesplat.core.camera import Camera
from particlesplat.core.sh import SH_C0
from particlesplat.model import ModelConfig, ParticleSplat
from particlesplat.model.decoder import cell_pixels

RES = TINY_MODEL["resolution"]


def _scene():
    g = torch.Generator().manual_seed(0)
    rgb = torch.rand(2, 3, RES, RES, generator=g)
    depth = 2.0 + torch.rand(2, 1, RES, RES, generator=g)
    cams = []
    for x in (-0.3, 0.3):
        c2w = torch.eye(4)
        c2w[0, 3], c2w[2, 3] = x, -3.0
        cams.append(Camera(torch.tensor([[40.0, 0, RES / 2], [0, 40.0, RES / 2], [0, 0, 1]]), c2w, RES, RES))
    return rgb, depth, cams


def _model(anchor: bool) -> ParticleSplat:
    torch.manual_seed(1)
    return ParticleSplat(ModelConfig(**{**TINY_MODEL, "patch_colour_anchor": anchor, "refine_steps": 0})).eval()


def test_an_untrained_decoder_draws_each_cell_in_the_colour_under_it():
    """Each front Gaussian's colour equals the context image sampled at its cell's centre (the decoder's residual
    and offsets start at zero), to 2e-3."""
    rgb, depth, cams = _scene()
    model = _model(True)
    p = model.encode(rgb, depth, cams)
    S = model.config.patch_gaussians
    assert p.z_f.shape[-1] == model.config.d_obj + 2 * S * S * 3
    g = model.decode(p, z_t_threshold=0.0, background=False)
    colour = (SH_C0 * g.sh[:, 0, :] + 0.5).reshape(p.num, 2 * S * S, 3)[:, : S * S]
    pix = cell_pixels(p.z_p, p.z_s, S, (RES, RES))
    grid = (pix / RES * 2.0 - 1.0)[:, :, None, :]
    want = F.grid_sample(rgb[p.view], grid, mode="bilinear", padding_mode="border", align_corners=False)
    torch.testing.assert_close(colour, want[..., 0].transpose(1, 2), atol=2e-3, rtol=0)


def test_the_colours_travel_with_the_particle_rows():
    """Taking rows keeps each particle's colours: a particle decoded alone from a subset draws as it did."""
    rgb, depth, cams = _scene()
    model = _model(True)
    p = model.encode(rgb, depth, cams)
    whole = model.decode(p, z_t_threshold=0.0, background=False)
    alone = model.decode(p.take([2]), z_t_threshold=0.0, background=False)
    mine = whole.owner == 2
    torch.testing.assert_close(alone.sh, whole.sh[mine], atol=1e-6, rtol=0)


def test_a_model_without_the_option_keeps_its_features_only():
    rgb, depth, cams = _scene()
    model = _model(False)
    assert model.encode(rgb, depth, cams).z_f.shape[-1] == model.config.d_obj
