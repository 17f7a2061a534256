"""Objects stop at the surface they rest on when lowered (the viewer's Ctrl + drag)."""

from __future__ import annotations

import pytest
import torch

from particlesplat.editing import demo_scenes
from particlesplat.editing.editor import SceneEditor
from particlesplat.editing.grouping import OPAQUE
from particlesplat.editing.move import stop_at_support
from particlesplat.editing.open_scene import load_model_scene


@pytest.mark.parametrize(
    ("dz", "bottom", "support", "allowed"),
    [
        (0.3, 0.1, 0.0, 0.3),  # up: always
        (-0.05, 0.1, 0.0, -0.05),  # down, still above the surface
        (-0.5, 0.1, 0.0, -0.1),  # down past it: to the surface
        (-0.5, -0.2, 0.0, 0.0),  # already under it: no lower
        (0.2, -0.2, 0.0, 0.2),  # but up, yes
        (-1.0, 1.3, 1.0, -0.3),  # another support height
    ],
)
def test_stop_at_support(dz, bottom, support, allowed):
    assert stop_at_support(dz, bottom, support) == pytest.approx(allowed)


def test_a_lowered_object_stops_at_the_floor():
    """On a demo scene, an object lowered by a metre through the rule ends with its bottom on the floor."""
    torch.set_num_threads(1)
    model, enc, _ = load_model_scene(None, demo_scenes()[0], "4,16")
    ed = SceneEditor(model, enc.particles, enc.all_cameras, enc.context)
    labels = ed.objects()
    index = int((labels >= 0).nonzero()[0, 0])
    bottom = ed.object_bottom(index)
    g = model.decode(ed.particles, torch.tensor(ed.object_members(index)), background=False)
    z = g.means[:, 2][g.opacities >= OPAQUE].detach().double()
    assert bottom == pytest.approx(float(torch.quantile(z, 0.02)))  # independent of the editor's own code path
    ed.move_object(index, [0.0, 0.0, 0.3])  # lift it clear of the floor first
    lifted = ed.object_bottom(index)
    assert lifted > bottom + 0.25
    support = ed.support_height()
    dz = stop_at_support(-1.0, lifted, support)
    ed.move_object(index, [0.0, 0.0, dz])
    # on the floor, not through it (a move is rigid up to the perspective error editing.move documents)
    assert ed.object_bottom(index) == pytest.approx(support, abs=0.03)
