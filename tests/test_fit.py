"""Test-time fitting of the particle latents to the context views (``particlesplat.model.fit``)."""

from __future__ import annotations

import pytest
import torch
from test_model import scene_inputs, tiny_model

from particlesplat.core.choices import FITTED
from particlesplat.model.fit import fit_particles
from particlesplat.model.losses import view_error
from particlesplat.rendering.api import render


def test_fitting_lowers_the_context_error_and_leaves_the_model_alone():
    """fit_particles (test-time fitting): 0 steps returns the particles as encoded; 5 Adam steps lower the
    context-view error (recomputed independently with the torch renderer), move only the fitted latents, and
    leave the decoder's weights and their gradients untouched; bad input is refused by name."""
    m = tiny_model(6)
    rgb, depth, cs = scene_inputs(2)
    p = m.encode(rgb, depth, cs)
    assert fit_particles(m, p, rgb, depth, steps=0) is p
    weights = {k: v.clone() for k, v in m.state_dict().items()}

    @torch.no_grad()
    def error(q):
        g = m.decode(q)
        total = 0.0
        for v, cam in enumerate(cs):
            r = render(g, cam, background=m.background_color())
            total += float(
                view_error(
                    r.rgb.permute(2, 0, 1)[None], rgb[v : v + 1], r.depth[None, None], depth[v : v + 1], None, 0.5
                ).sum()
            )
        return total

    fitted = fit_particles(m, p, rgb, depth, steps=5, lr=0.05, latents=FITTED)
    assert error(fitted) < 0.95 * error(p)
    assert not torch.equal(fitted.z_f, p.z_f) and not torch.equal(fitted.z_p, p.z_p)
    assert torch.equal(fitted.z_t, p.z_t) and torch.equal(fitted.background, p.background)
    for k, v in m.state_dict().items():
        assert torch.equal(v, weights[k]), k
    assert all(w.grad is None for w in m.parameters())
    with pytest.raises(ValueError, match=r"rgb must be \(2, 3, 32, 32\)"):
        fit_particles(m, p, rgb[:1], depth)
    only_f = fit_particles(m, p, rgb, depth, steps=2, lr=0.05)  # the default: the appearance alone
    assert torch.equal(only_f.z_p, p.z_p) and not torch.equal(only_f.z_f, p.z_f)
    with pytest.raises(ValueError, match="latents must be some of z_p, z_s, z_d, z_e, z_f, got z_t"):
        fit_particles(m, p, rgb, depth, latents=("z_t",))
    with pytest.raises(ValueError, match="steps must be >= 0"):
        fit_particles(m, p, rgb, depth, steps=-1)
