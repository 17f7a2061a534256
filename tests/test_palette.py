"""One palette (particlesplat.core.palette) for the viewer's shader, its panel swatches and the headless figures:
one scene is coloured the same in both tools."""

from __future__ import annotations

import colorsys

import numpy as np
import pytest
import torch

from particlesplat.core import palette


def test_colours_are_golden_ratio_hues_and_a_grey_background():
    assert palette.colour(-1) == (palette.BACKGROUND,) * 3 == palette.colour(-7)
    for key in (0, 1, 5, 40):
        h = (key * palette.HUE_STEP + palette.HUE_OFFSET) % 1.0
        assert palette.colour(key) == colorsys.hsv_to_rgb(h, palette.SATURATION, palette.VALUE)
    labels = np.array([[-1, 0], [3, 3]])
    out = palette.colour_map(labels)
    assert out.shape == (2, 2, 3)
    for (y, x), key in np.ndenumerate(labels):
        assert tuple(out[y, x]) == palette.colour(int(key))
    # the shader reads the same numbers
    defines = palette.shader_defines()
    assert float(defines["PALETTE_HUE_OFFSET"]) == palette.HUE_OFFSET
    assert float(defines["PALETTE_BACKGROUND"]) == palette.BACKGROUND


def test_the_panel_swatches_are_the_palette():
    from viewer.ui.objects import segmentation_colour

    for key in (-1, 0, 2, 17):
        assert segmentation_colour(key) == palette.colour(key)


@pytest.mark.gl
def test_the_viewer_colours_particles_as_the_figures_do():
    """The shipped model's particles of a demo scene, coloured by particle: where one particle covers a pixel
    (its weight >= 0.98 of the pixel), the viewer's colour (the GL renderer's "colour by particle") equals
    ``particlesplat render --mode particles``' colour there."""
    from viewer_helpers import egl_context

    from particlesplat.analysis.figures import render_mode
    from particlesplat.analysis.particle_arrays import particle_arrays
    from particlesplat.editing.open_scene import demo_scenes, encode_scene
    from particlesplat.model import load_model
    from particlesplat.rendering.api import render
    from viewer.gl.renderer import SplatRenderer

    model = load_model(None)
    enc = encode_scene(model, demo_scenes()[0])
    with torch.no_grad():
        g = model.decode(enc.particles).detach().to("cpu")
    arrays = particle_arrays(model, enc.particles, g)
    cam = enc.particles.cameras[0].to("cpu")
    figure = render_mode(g, cam, "particles", arrays=arrays)
    ref = render(g, cam, owner_weights=True, num_owners=arrays.num_particles)
    weights = ref.owner_weights.numpy()  # (P, H, W)
    covered = weights.max(0) >= 0.98  # one particle draws the pixel
    owners = weights.argmax(0)[covered]
    assert covered.sum() >= 50 and len(np.unique(owners)) >= 3

    ctx = egl_context()
    try:
        r = SplatRenderer(ctx, color_dtype="f4")
        r.set_gaussians(g)
        r.render(cam, color_mode=1)
        rgba = r.read_rgba()  # premultiplied
        r.release()
    finally:
        ctx.release()
    viewer = rgba[..., :3] / np.maximum(rgba[..., 3:], 1e-6)
    np.testing.assert_allclose(viewer[covered], figure[covered], atol=0.03)
    expected = np.array([palette.colour(int(k)) for k in owners])
    np.testing.assert_allclose(figure[covered], expected, atol=1e-12)
