"""The benchmark's naive splatter (viewer.naive) is a real splatter: close to the torch renderer on
small splats, where its 3-sigma quads and missing Jacobian clamp matter little (headless EGL)."""

from __future__ import annotations

import numpy as np
import pytest
from viewer_helpers import egl_context, psnr

from particlesplat import render
from particlesplat.camera import Camera
from viewer.random_gaussians import random_gaussians

pytestmark = pytest.mark.gl


def test_naive_splatter_draws_the_scene():
    from viewer.naive import NaiveSplatter

    ctx = egl_context()
    g = random_gaussians(3000, seed=1, sh_degree=3, pixel_scale=0.01)
    cam = Camera.orbit((0.0, 0.0, 0.0), 30.0, 20.0, 3.0, width=96, height=72)
    r = NaiveSplatter(ctx)
    r.set_gaussians(g)
    ft = r.render(cam, finish=True)
    assert ft.drawn == g.num
    out, ref = r.read_rgb((0.2, 0.3, 0.4)), render(g, cam, background=(0.2, 0.3, 0.4)).rgb.numpy()
    assert psnr(out, ref) >= 35.0
    assert np.abs(out - np.float32([0.2, 0.3, 0.4])).max() > 0.2  # it drew something
    r.set_filter(min_opacity=0.5)
    assert r.visible_count == int((g.opacities >= 0.5).sum())
    r.render(cam)
    assert psnr(r.read_rgb(), render(g.subset(g.opacities >= 0.5), cam).rgb.numpy()) >= 35.0
    r.release()
    ctx.release()
