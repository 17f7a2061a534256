"""Objects as units: .ply export round trip, and an object of one demo scene inserted into another lands where
asked (float64 brute-force centroid of its decoded Gaussians), keeps its colour (arrays and render), and is an
object of its own that moves like B's."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from particlesplat import Gaussians
from particlesplat.cli.main import main
from particlesplat.core.sh import SH_C0
from particlesplat.editing.compose import (
    export_object_ply,
    insert_object,
    object_gaussians,
    object_members,
    scene_objects,
)
from particlesplat.editing.move import translate
from particlesplat.editing.open_scene import demo_scenes, encode_scene
from particlesplat.model import load_model
from particlesplat.rendering.api import render

AT = (0.8, 0.5)  # a free spot on scene_00000's floor


@pytest.fixture(scope="module")
def scenes():
    model = load_model()
    a, b = demo_scenes()[1], demo_scenes()[0]
    return model, encode_scene(model, a, [4, 16]), encode_scene(model, b, [4, 16])


def _weighted(g) -> np.ndarray:
    w, x = g.opacities.double().numpy(), g.means.double().numpy()
    return (w[:, None] * x).sum(0) / w.sum()


def _colour(g) -> np.ndarray:
    w = g.opacities.double().numpy()
    dc = np.clip(SH_C0 * g.sh[:, 0, :].double().numpy() + 0.5, 0, 1)
    return (w[:, None] * dc).sum(0) / w.sum()


def test_export_ply_round_trip(scenes, tmp_path):
    model, a, _ = scenes
    members = object_members(model, a.particles, 0)
    g = object_gaussians(model, a.particles, 0)
    assert set(g.owner.tolist()) == set(members)
    path = export_object_ply(model, a.particles, 0, tmp_path / "obj.ply")
    back = Gaussians.load_ply(path)
    assert back.num == g.num
    torch.testing.assert_close(back.means, g.means, atol=1e-6, rtol=0)
    torch.testing.assert_close(back.scales, g.scales, atol=1e-6, rtol=1e-5)
    torch.testing.assert_close(back.opacities, g.opacities.clamp(1e-7, 1 - 1e-7), atol=1e-6, rtol=0)
    torch.testing.assert_close(back.sh, g.sh, atol=1e-6, rtol=0)
    assert back.owner.tolist() == g.owner.tolist()
    with pytest.raises(ValueError, match="--object 99"):
        object_members(model, a.particles, 99)


@pytest.mark.parametrize("method", ["weighted", "resting"])
def test_inserted_object_lands_at_the_requested_place_with_its_colour(scenes, method):
    model, a, b = scenes
    src = object_gaussians(model, a.particles, 0)
    out, new = insert_object(model, b.particles, a.particles, 0, AT, method=method)
    assert out.num == b.particles.num + len(new) and len(new) == len(object_members(model, a.particles, 0))
    g = model.decode(out, torch.tensor(new), background=False)
    centre, centre_src = _weighted(g), _weighted(src)
    # the colour exactly: with every Gaussian drawing (the shipped support_cut hides what hangs under the floor,
    # and which of an object's Gaussians hang under it depends on where it stands)
    cut, model.config.support_cut = model.config.support_cut, -1.0
    try:
        g_all = model.decode(out, torch.tensor(new), background=False)
        src_all = object_gaussians(model, a.particles, 0)
    finally:
        model.config.support_cut = cut
    if method == "weighted":  # both demo scenes' floors are at z = 0: the height above the floor is kept
        assert np.linalg.norm(centre - np.array([AT[0], AT[1], centre_src[2]])) < 0.02
    else:  # the resting centre is elsewhere in z; its x, y are the opaque Gaussians' mean, near the weighted one
        assert np.linalg.norm(centre[:2] - np.array(AT)) < 0.02
    np.testing.assert_allclose(_colour(g_all), _colour(src_all), atol=1e-5)
    np.testing.assert_allclose(_colour(g), _colour(src), atol=0.01)  # as drawn: within what the cut hides
    # B's own particles are untouched
    for name in ("z_p", "z_s", "z_d", "z_t"):
        torch.testing.assert_close(getattr(out, name)[: b.particles.num], getattr(b.particles, name))


def test_inserted_object_renders_in_its_colour_and_is_an_editable_object(scenes):
    model, a, b = scenes
    out, new = insert_object(model, b.particles, a.particles, 0, AT)
    objects = scene_objects(model, out)
    assert len(set(objects[new].tolist())) == 1 and objects[new[0]] not in set(objects[: b.particles.num].tolist())

    def object_rgb(particles, members, camera):
        r = render(model.decode(particles), camera, owner_weights=True, num_owners=particles.num)
        mine = r.owner_weights[members].sum(0)
        mask = mine > 0.5 * r.alpha.clamp_min(1e-6)
        mask &= mine > 0.5
        assert int(mask.sum()) > 20
        return r.rgb[mask].double().mean(0).numpy(), mask

    members_a = object_members(model, a.particles, 0)
    rgb_a, _ = object_rgb(a.particles, members_a, a.particles.cameras[0])
    rgb_b, mask = object_rgb(out, new, b.particles.cameras[0])
    assert np.abs(rgb_a - rgb_b).max() < 0.08
    # editable like B's own: a move of its particles moves its centroid by the offset
    delta = torch.tensor([0.1, -0.2, 0.0])
    moved = out
    for i, attrs in translate(out, new, delta, model.config).items():
        for name, value in attrs.items():
            moved = moved.with_attribute(i, name, value)
    before = _weighted(model.decode(out, torch.tensor(new), background=False))
    after = _weighted(model.decode(moved, torch.tensor(new), background=False))
    assert np.linalg.norm(after - before - delta.numpy()) < 0.02


def test_object_command(tmp_path):
    scene_a, scene_b = demo_scenes()[1], demo_scenes()[0]
    ply = tmp_path / "o.ply"
    assert main(["object", "export", "--scene", str(scene_a), "--object", "0", "--out", str(ply)]) == 0
    assert Gaussians.load_ply(ply).num > 0
    out = tmp_path / "c.ply"
    assert (
        main(
            [
                "object",
                "insert",
                "--scene",
                str(scene_b),
                "--from",
                str(scene_a),
                "--object",
                "0",
                "--at",
                "0.8,0.5",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    composed = Gaussians.load_ply(out)
    assert composed.num > Gaussians.load_ply(ply).num
