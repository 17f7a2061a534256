"""The scene session (edits as do/undo operations) and the incremental GL update."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from viewer_helpers import egl_context, psnr, small_model

from particlesplat import render
from particlesplat.editing.open_scene import demo_scenes, encode_scene
from viewer.gl.renderer import SplatRenderer
from viewer.scene_view import SceneView
from viewer.screenshot import save_numbered, save_screenshot
from viewer.session import EditableScene, PlyScene
from viewer.state import ViewState


@pytest.fixture(scope="module")
def encoded():
    model = small_model()
    return model, encode_scene(model, demo_scenes()[0])


def test_the_background_is_an_owner_the_renderer_can_replace(encoded):
    """particle_gaussians(-1) hands out the background as gaussians() holds it (what take_changes reports when an
    edit uncovered the table under an object), and replacing it in the renderer leaves the picture as it was."""
    model, enc = encoded
    s = EditableScene(model, enc)
    g = s.gaussians()
    bg = s.particle_gaussians(-1)
    assert torch.equal(bg.means, g.means[g.owner < 0]) and bool((bg.owner == -1).all())
    from particlesplat.core.viewpoints import default_view

    r = SplatRenderer(egl_context())
    r.set_gaussians(g)
    cam = default_view(enc.all_cameras).camera(64, 64)
    r.render(cam, finish=True)
    before = r.read_rgb().copy()
    r.replace_owner(-1, bg)
    r.render(cam, finish=True)
    assert np.array_equal(r.read_rgb(), before)
    r.release()


def test_edit_undo_redo(encoded):
    model, enc = encoded
    s = EditableScene(model, enc)
    assert s.take_changes() is None  # first sync uploads everything
    z0 = s.editor.value(1, "z_p")
    s.editor.set_attribute(1, "z_p", [0.3, -0.2])
    assert s.take_changes() == {1}
    assert s.editor.value(1, "z_p") == pytest.approx((0.3, -0.2))
    assert s.editor.edits() == {1: {"z_p": pytest.approx((0.3, -0.2))}}
    assert s.editor.undo() and s.editor.value(1, "z_p") == z0 and s.editor.edits() == {}
    assert s.take_changes() == {1}
    assert s.editor.redo() and s.editor.value(1, "z_p") == pytest.approx((0.3, -0.2))
    assert not s.editor.redo()
    # a new edit clears the redo stack
    s.editor.undo()
    s.editor.set_attribute(0, "z_t", [0.0])
    assert not s.editor.redo()


def test_objects_are_grouped_once_on_the_encoded_scene(encoded):
    from particlesplat.editing.grouping import dense_objects, drawing_particles, particle_objects

    model, enc = encoded
    s = EditableScene(model, enc)
    g = model.decode(enc.particles)
    groups = particle_objects(g, enc.particles.num)  # numbered as particlesplat encode numbers them
    want = dense_objects(groups, drawing_particles(enc.particles, g, model.config.bg_mask_threshold))
    assert torch.equal(s.objects(), want)
    s.editor.set_attribute(0, "z_p", [0.9, 0.9])  # an edit moves a particle but does not regroup
    assert torch.equal(s.objects(), want)
    g = model.decode(enc.particles)
    assert torch.equal(PlyScene(g).objects(), torch.arange(int(g.owner.max()) + 1))


def test_move_object_moves_every_member_as_one_undo_step(encoded):
    from particlesplat.editing.move import MoveError, anchor_points

    model, enc = encoded
    s = EditableScene(model, enc)
    s.editor.scene._labels = torch.tensor([0, 1, 0, 3, 4, 5])[: s.editor.num_particles]  # particles 0 and 2: one object
    assert s.editor.object_members(2) == [0, 2]
    before = anchor_points(s.editor.particles, [0, 2], model.config)
    for _ in range(3):  # a drag of three steps of 0.05 m along x
        s.editor.move_object(2, [0.05, 0.0, 0.0], gesture="drag")
    s.editor.end_gesture()
    after = anchor_points(s.editor.particles, [0, 2], model.config)
    torch.testing.assert_close(after - before, torch.tensor([[0.15, 0.0, 0.0]] * 2), rtol=0, atol=1e-4)
    assert s.editor.object_offset(0) == pytest.approx((0.15, 0.0, 0.0), abs=1e-4)
    assert len(s.editor.history.undo) == 1 and set(s.editor.edits()) == {0, 2}
    s.take_changes()
    assert s.editor.undo() and s.editor.edits() == {} and s.take_changes() == {0, 2}
    with pytest.raises(MoveError):
        s.editor.move_object(0, [0.0, 0.0, 50.0])
    assert s.editor.edits() == {} and len(s.editor.history.undo) == 0


def test_drag_gesture_is_one_operation(encoded):
    model, enc = encoded
    s = EditableScene(model, enc)
    d0 = s.editor.value(2, "z_d")[0]
    for k in range(1, 6):
        s.editor.set_attribute(2, "z_d", [d0 + 0.1 * k], gesture="drag")
    s.editor.end_gesture()
    s.editor.set_attribute(2, "z_d", [d0 + 1.0], gesture="drag")  # a new gesture after end_gesture
    assert len(s.editor.history.undo) == 2
    s.editor.undo()
    assert s.editor.value(2, "z_d")[0] == pytest.approx(d0 + 0.5)
    s.editor.undo()
    assert s.editor.value(2, "z_d")[0] == pytest.approx(d0)


def test_reset_and_load_edits(encoded, tmp_path):
    model, enc = encoded
    s = EditableScene(model, enc, model_name="small")
    s.editor.set_attribute(0, "z_s", [1.0, 1.0])
    s.editor.set_attribute(0, "z_e", [2.0])
    s.editor.reset_particle(0)
    assert s.editor.edits() == {}
    s.editor.set_attribute(3, "z_d", [0.7])
    s.save_edits(tmp_path / "e.yaml")
    s2 = EditableScene(model, enc)
    s2.load_edits(tmp_path / "e.yaml")
    assert s2.editor.edits() == s.editor.edits()
    assert s2.editor.undo() and s2.editor.edits() == {}
    with pytest.raises(IndexError):
        s.editor.set_attribute(99, "z_d", [0.0])
    with pytest.raises(KeyError):
        s.editor.set_attribute(0, "z_f", [0.0])


def test_edit_redecodes_only_that_particle_and_matches_torch(encoded, compositing):
    """After an edit the GL renderer holds exactly the full decode of the edited particles."""
    model, enc = encoded
    ctx = egl_context()
    s = EditableScene(model, enc)
    view = SceneView(SplatRenderer(ctx, color_dtype="f4", compositing=compositing))
    state = ViewState()
    cam = enc.all_cameras[10].resized(80, 80)
    view.draw(s, state, cam)
    s.editor.set_attribute(2, "z_p", [0.1, 0.1])
    s.editor.set_attribute(4, "z_d", [2.0])
    calls = []
    orig = s.particle_gaussians
    s.particle_gaussians = lambda i: calls.append(i) or orig(i)
    assert view.draw(s, state, cam) is not None
    assert sorted(calls) == [2, 4]
    assert view.draw(s, state, cam) is None  # nothing changed: no redraw
    ref = render(s.gaussians(), cam, background=state.background)
    assert psnr(view.renderer.read_rgb(state.background), ref.rgb.numpy()) >= 40.0
    # picking (background hidden: the untrained particles are faint): the most clearly owned pixel
    state.seg_mode = "background hidden"
    view.draw(s, state, cam)
    res = render(view.visible_gaussians(s, state), cam, owner_weights=True, num_owners=s.num_owners())
    w = res.owner_weights.numpy()
    margin = w.max(0) - (res.background_weight + 1.0 - res.alpha).numpy()
    y, x = np.unravel_index(np.argmax(margin), margin.shape)
    assert margin[y, x] > 0
    assert view.pick(s, cam, int(x), int(y)) == int(w[:, y, x].argmax())
    assert view.pick(s, cam, 0, 0) == int(res.segmentation()[0, 0])
    state.seg_mode = "normal"
    # hidden particles and pruning = the torch render of the filtered set
    state.hidden = {0, 1}
    state.prune = 0.3
    view.draw(s, state, cam)
    g = view.visible_gaussians(s, state)
    assert not torch.isin(g.owner, torch.tensor([0, 1])).any() and bool((g.opacities >= 0.3).all())
    assert psnr(view.renderer.read_rgb(state.background), render(g, cam, background=state.background).rgb.numpy()) >= 40
    view.renderer.release()
    ctx.release()


def test_numbered_files_never_overwrite(tmp_path):
    (tmp_path / "particlesplat_0001.png").write_bytes(b"keep")
    img = np.zeros((4, 5, 3), np.float32)
    a = save_screenshot(tmp_path, img, {"camera": "{}"})
    b = save_screenshot(tmp_path, img, {"camera": "{}"})
    assert (a.name, b.name) == ("particlesplat_0002.png", "particlesplat_0003.png")
    assert (tmp_path / "particlesplat_0001.png").read_bytes() == b"keep"
    c = save_numbered(tmp_path, "particlesplat_", ".ply", lambda p: p.write_text("x"))
    assert c.name == "particlesplat_0001.ply"
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "particlesplat_0001.ply",
        "particlesplat_0001.png",
        "particlesplat_0002.png",
        "particlesplat_0003.png",
    ]
    # a screenshot has the permissions of any new file (the umask's), not a temporary file's 0600
    assert a.stat().st_mode == (tmp_path / "particlesplat_0001.png").stat().st_mode


def test_both_kinds_of_scene_are_scenes_and_only_the_model_scene_has_an_editor(encoded):
    """Composition: an editable scene holds a SceneEditor (every edit goes through it); a .ply is a PlyScene whose
    editor is None. Both give the viewer what the Scene protocol names, with the same answers for a model scene
    as its editor's."""
    from particlesplat.editing.editor import SceneEditor
    from viewer.bench.random_gaussians import random_gaussians
    from viewer.session import Scene

    model, enc = encoded
    s: Scene = EditableScene(model, enc)
    assert not isinstance(s, SceneEditor) and isinstance(s.editor, SceneEditor)
    s.editor.set_attribute(1, "z_p", [0.1, 0.2])
    assert s.version == s.editor.version > 0 and s.num_owners() == s.editor.num_particles and s.unsaved
    assert torch.equal(s.objects(), s.editor.objects()) and s.context == enc.context
    g = random_gaussians(20, seed=3)
    ply: Scene = PlyScene(g, source="x.ply")
    assert ply.editor is None and ply.model is None and not ply.unsaved and ply.cameras == []
    assert ply.take_changes() == set() and ply.edit_chunk() == {} and ply.autosave("out") is None
    assert ply.num_owners() == int(g.owner.max()) + 1 and ply.name == "x"
