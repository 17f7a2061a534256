"""Edit replay costs what the edits change: the editor's Gaussians are kept current particle by particle, a pick
composites one pixel from the Gaussians that reach it, and a file that would grow the scene past its cap is
refused before any work. Checked against the full decode and the full render."""

from __future__ import annotations

import pytest
import torch

from particlesplat.core.camera import Camera
from particlesplat.core.gaussians import Gaussians
from particlesplat.editing.editor import MAX_EDIT_PARTICLES, EditFile, EditsError, Pick, SceneEditor
from particlesplat.editing.open_scene import demo_scenes, load_model_scene
from particlesplat.editing.operations import Duplicate, Translate
from particlesplat.rendering.api import render
from particlesplat.rendering.pixel import pixel_weights

FIELDS = ("means", "scales", "opacities", "sh", "owner")


@pytest.fixture(scope="module")
def scene():
    torch.set_num_threads(1)
    model, enc, _ = load_model_scene(None, demo_scenes()[0], "4,16")
    return model, enc


def editor(scene) -> SceneEditor:
    model, enc = scene
    return SceneEditor(model, enc.particles, enc.all_cameras, enc.context)


def assert_decodes_as_model(ed: SceneEditor) -> None:
    """The editor's kept Gaussians equal the model's full decode (to float32 rounding: a decode batches the
    particles it is given, and a batch of another size rounds its last bits differently). Orientation is compared
    as the covariance: where two scales are (nearly) equal the rotation within their plane is not defined, and a
    last-bit difference in the factored covariance turns the quaternion by more than the rounding."""
    kept, full = ed.decode(), ed.model.decode(ed.particles).detach()
    torch.testing.assert_close(kept.covariances(), full.covariances(), atol=1e-8, rtol=1e-5, msg="covariances")
    var = full.scales.square().sort(-1).values  # quaternions where the rotation is defined: no two axes within 5 %
    distinct = ((var[:, 1:] - var[:, :-1]) > 0.05 * var[:, 2:]).all(-1)
    assert distinct.float().mean() > 0.25  # (0.43 of the demo scene's)
    torch.testing.assert_close(kept.quats[distinct], full.quats[distinct], atol=1e-5, rtol=1e-5, msg="quats")
    for k in FIELDS:
        a, b = getattr(kept, k), getattr(full, k)
        assert a.shape == b.shape, k
        if k == "owner":
            assert torch.equal(a, b)
        else:
            torch.testing.assert_close(a, b, atol=1e-5, rtol=1e-5, msg=k)


def first_object(ed: SceneEditor) -> int:
    return int(torch.nonzero(ed.objects() >= 0)[0])


def test_kept_gaussians_follow_do_undo_redo_and_added_rows(scene):
    ed = editor(scene)
    assert_decodes_as_model(ed)
    obj = first_object(ed)
    ed.move_object(obj, (0.05, 0.0, 0.0))
    assert_decodes_as_model(ed)
    first = ed.duplicate_object(obj, (0.0, 0.1, 0.0))
    assert_decodes_as_model(ed)
    ed.undo()  # the copy's rows go ...
    assert_decodes_as_model(ed)
    ed.duplicate_object(obj, (0.0, -0.1, 0.0))  # ... and another copy takes their indices: decoded anew
    assert ed.num_particles > first
    assert_decodes_as_model(ed)
    ed.remove_object(obj)
    assert_decodes_as_model(ed)
    while ed.undo():
        pass
    assert_decodes_as_model(ed)
    while ed.redo():
        pass
    assert_decodes_as_model(ed)


def test_a_pick_sees_what_the_full_render_shows_at_every_pixel(scene):
    ed = editor(scene)
    obj = first_object(ed)
    ed.duplicate_object(obj, (0.03, 0.02, 0.0))  # a copy overlapping its original
    ed.move_object(obj, (0.0, 0.04, 0.0))
    shown = 0
    for frame in (4, 16, 0):
        cam = ed.frame_cameras[frame]
        full = ed.object_map(frame)
        for y in range(0, cam.height, 2):
            for x in range(0, cam.width, 2):
                assert ed._pixel_object(frame, cam, (x, y)) == int(full[y, x]), (frame, x, y)
        shown += int((full >= 0).sum())
    assert shown > 100  # objects were in view


def test_replay_decodes_each_particle_once_per_change(scene):
    ed = editor(scene)
    obj = first_object(ed)
    pick = ed.pick_for(obj)
    start, encoded = ed._decoded.rows_decoded, ed.num_particles
    assert start == encoded
    ops = [Duplicate(pick=pick, offset=(0.0, 0.0, 0.0)) for _ in range(12)]
    ops += [Translate(pick=pick, offset=(0.01, 0.0, 0.0)) for _ in range(12)]
    ed.apply_file(EditFile(2, operations=ops))
    ed.decode()
    members = len(ed.object_members(obj))
    # each copy's particles once and each move's particles once: linear in the operations (decoding every
    # particle for every pick would be over 24 x 16 particles)
    assert ed._decoded.rows_decoded - start == (ed.num_particles - encoded) + 12 * members
    # a replayed file saves the picks it was read with
    assert [op.pick for op in ed.operations()] == [pick] * 24


def test_a_file_past_the_particle_cap_is_refused_before_any_work(scene):
    ed = editor(scene)
    pick = ed.pick_for(first_object(ed))
    room = MAX_EDIT_PARTICLES - ed.num_particles
    ops = [Translate(pick=pick, offset=(0.01, 0.0, 0.0))] + [
        Duplicate(pick=pick, offset=(0.0, 0.0, 0.0)) for _ in range(room + 1)
    ]
    before = ed._decoded.rows_decoded
    with pytest.raises(EditsError, match=rf"my.yaml: operations\[{room + 1}\] \(duplicate\): .*more than the 1024"):
        ed.apply_file(EditFile(2, operations=ops), "my.yaml")
    assert not ed.history.undo and ed._decoded.rows_decoded == before  # nothing done, nothing decoded


def test_pixel_weights_are_the_renderers_at_every_pixel():
    """Random overlapping Gaussians (some off screen, some behind others) in float64: per pixel, the weights
    :func:`pixel_weights` gives summed per owner equal render's owner weights, and 1 − Σw its empty remainder."""
    gen = torch.Generator().manual_seed(3)
    n = 300
    g = Gaussians(
        means=torch.rand(n, 3, generator=gen, dtype=torch.float64) * torch.tensor([2.0, 2.0, 1.0]) - 1.0,
        quats=torch.randn(n, 4, generator=gen, dtype=torch.float64),
        scales=torch.rand(n, 3, generator=gen, dtype=torch.float64) * 0.15 + 0.01,
        opacities=torch.rand(n, generator=gen, dtype=torch.float64) * 0.98 + 0.02,
        sh=torch.rand(n, 1, 3, generator=gen, dtype=torch.float64),
        owner=torch.randint(-1, 6, (n,), generator=gen),
    )
    K = torch.tensor([[30.0, 0, 13.0], [0, 28.0, 9.5], [0, 0, 1]], dtype=torch.float64)
    c2w = torch.eye(4, dtype=torch.float64)
    c2w[2, 3] = -3.0
    cam = Camera(K=K, c2w=c2w, width=27, height=21)
    res = render(g, cam, owner_weights=True, num_owners=6)
    owner_w, bg_w = res.owner_weights, res.background_weight
    assert owner_w is not None and bg_w is not None
    for y in range(cam.height):
        for x in range(cam.width):
            index, w = pixel_weights(g, cam, (x, y))
            own = g.owner[index]
            per = torch.zeros(6, dtype=torch.float64).index_add_(0, own.clamp_min(0), w * (own >= 0))
            torch.testing.assert_close(per, owner_w[:, y, x], atol=1e-9, rtol=1e-7)
            torch.testing.assert_close(w[own < 0].sum(), bg_w[y, x], atol=1e-9, rtol=1e-7)
            torch.testing.assert_close(1.0 - w.sum(), 1.0 - res.alpha[y, x], atol=1e-9, rtol=1e-7)


def test_pick_outside_any_object_still_names_the_background(scene):
    ed = editor(scene)
    from particlesplat.editing.editor import PickError

    with pytest.raises(PickError, match="hits no object"):
        ed.pick(Pick(4, (0, 0)))
