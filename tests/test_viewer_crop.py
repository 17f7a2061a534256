"""The viewer applies the crop box the edits set: the scene's Gaussians (what the view uploads, picks, screenshots
and exports) and each particle's re-decoded Gaussians keep only those whose means lie in the box, counted here
against a brute-force test of every mean, axis by axis."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import yaml
from viewer_helpers import egl_context, encoded_robot_demo, recording_target, small_model

from particlesplat.editing.crop_box import CropBox, workspace_box
from particlesplat.editing.open_scene import demo_scenes, encode_scene
from viewer.actions import run
from viewer.gl.renderer import SplatRenderer
from viewer.scene_view import SceneView
from viewer.session import EditableScene
from viewer.state import ViewState
from viewer.tools.crop_box import EDGES, applied_box, corners, edge_segments, set_bound, shown_box


@pytest.fixture(scope="module")
def encoded():
    model = small_model()
    return model, encode_scene(model, demo_scenes()[0])


@pytest.fixture(scope="module")
def robot():
    return encoded_robot_demo()


def _inside(means: np.ndarray, lo, hi) -> np.ndarray:
    """Which means (N, 3) lie in [lo, hi]: each axis compared on its own."""
    keep = np.ones(len(means), dtype=bool)
    for axis in range(3):
        keep &= (means[:, axis] >= lo[axis]) & (means[:, axis] <= hi[axis])
    return keep


def _box_about_half(scene: EditableScene) -> tuple[list[float], list[float]]:
    """A box holding some of the scene's Gaussians and leaving out others: its means' 20th to 80th percentiles."""
    means = scene.editor.decode().means.detach().numpy()
    lo, hi = np.percentile(means, 20, axis=0), np.percentile(means, 80, axis=0)
    return [round(float(v), 3) for v in lo], [round(float(v), 3) for v in hi]


def _edit_file(tmp_path, lo, hi):
    path = tmp_path / "crop.edits.yaml"
    path.write_text(yaml.safe_dump({"version": 2, "operations": [{"crop": {"min": lo, "max": hi}}]}))
    return path


def test_an_edit_file_box_shows_only_the_gaussians_inside(encoded, tmp_path):
    model, enc = encoded
    scene = EditableScene(model, enc)
    everything = scene.editor.decode()
    assert scene.gaussians().num == everything.num  # no box: all of them
    lo, hi = _box_about_half(scene)
    assert scene.load_edits(_edit_file(tmp_path, lo, hi)) is None
    assert scene.editor.crop_box == CropBox(tuple(lo), tuple(hi))
    inside = _inside(everything.means.detach().numpy(), lo, hi)
    shown = scene.gaussians()
    assert 0 < inside.sum() < everything.num and shown.num == int(inside.sum())
    assert _inside(shown.means.detach().numpy(), lo, hi).all()
    # each particle re-decoded alone (an edit re-uploads only its particles) is cropped the same way
    for owner in scene.owner_ids():
        mine = everything.owner.numpy() == owner
        assert scene.particle_gaussians(owner).num == int((inside & mine).sum())
    assert scene.editor.undo() is not None and scene.gaussians().num == everything.num
    scene.editor.set_crop(CropBox.everything())  # crop: false shows everything
    assert scene.gaussians().num == everything.num


def test_the_view_uploads_and_exports_only_what_is_inside(encoded, tmp_path):
    model, enc = encoded
    scene, state = EditableScene(model, enc), ViewState()
    view = SceneView(SplatRenderer(egl_context(), color_dtype="f4"))
    view.sync(scene, state)
    everything = scene.editor.decode()
    assert view.renderer.num == everything.num
    lo, hi = _box_about_half(scene)
    scene.editor.set_crop(CropBox(tuple(lo), tuple(hi)))
    view.sync(scene, state)
    want = int(_inside(everything.means.detach().numpy(), lo, hi).sum())
    assert view.renderer.num == want and view.visible_gaussians(scene, state).num == want
    # an object's move re-uploads its particles only: they stay cropped
    obj = int(torch.nonzero(scene.editor.objects() >= 0)[0])
    scene.editor.move_object(obj, [0.05, 0.0, 0.0])
    changed = scene.take_changes()
    assert changed  # only the moved particles, not everything
    for owner in sorted(changed):
        view.renderer.replace_owner(owner, scene.particle_gaussians(owner))
    moved = scene.editor.decode()
    assert view.renderer.num == int(_inside(moved.means.detach().numpy(), lo, hi).sum()) == scene.gaussians().num


def test_the_switch_and_the_fields_edit_through_the_editor_one_step_each(encoded):
    model, enc = encoded
    scene = EditableScene(model, enc)
    ctx, said = recording_target(scene)
    ed, everything = scene.editor, scene.editor.decode()
    assert shown_box(scene) is None  # a tabletop scene: no box until one is set
    assert run("crop", ctx) and len(ed.history.undo) == 1
    box = applied_box(scene)
    assert box is not None and said[-1] == f"cropped to {box.text()}"
    assert scene.gaussians().num == everything.num  # the box about every mean hides nothing yet
    # a field's drag of three steps is one edit; its box is the last step's, min kept below max
    lo = list(box.lo)
    for step in (0.1, 0.2, 0.3):
        set_bound(scene, "min", [lo[0] + step, lo[1], lo[2]], gesture="crop min")
    ed.end_gesture()
    assert len(ed.history.undo) == 2 and applied_box(scene) == CropBox((lo[0] + 0.3, lo[1], lo[2]), box.hi)
    want = int(_inside(everything.means.detach().numpy(), (lo[0] + 0.3, lo[1], lo[2]), box.hi).sum())
    assert 0 < want < everything.num and scene.gaussians().num == want
    set_bound(scene, "max", [box.hi[0], lo[1] - 5.0, box.hi[2]])  # past min: stops a centimetre above it
    dragged = applied_box(scene)
    assert dragged is not None and dragged.hi[1] == pytest.approx(lo[1] + 0.01) and len(ed.history.undo) == 3
    ed.undo()
    # off shows everything; on again brings back the box switched off, not the default
    assert run("crop", ctx) and applied_box(scene) is None and scene.gaussians().num == everything.num
    assert run("crop", ctx) and applied_box(scene) == CropBox((lo[0] + 0.3, lo[1], lo[2]), box.hi)
    assert [op.kind for op in ed.history.undo] == ["crop"] * 4


def test_a_robot_scene_shows_its_workspace_and_saves_no_box_until_one_is_set(robot, tmp_path):
    model, enc, folder = robot
    scene = EditableScene(model, enc, source=str(folder))
    ctx, said = recording_target(scene)
    workspace = workspace_box(folder)
    assert workspace is not None and scene.workspace == workspace
    assert shown_box(scene) == (workspace, False)  # outlined, hiding nothing
    everything = scene.editor.decode()
    assert scene.gaussians().num == everything.num and not scene.unsaved
    saved = yaml.safe_load(scene.save_edits(tmp_path / "none.edits.yaml").read_text())
    assert "crop" not in str(saved.get("operations"))  # a box the user did not set is not in their file
    assert run("crop", ctx) and shown_box(scene) == (workspace, True) and scene.unsaved
    inside = _inside(everything.means.detach().numpy(), workspace.lo, workspace.hi)
    assert 0 < inside.sum() < everything.num and scene.gaussians().num == int(inside.sum())
    saved = yaml.safe_load(scene.save_edits(tmp_path / "set.edits.yaml").read_text())
    assert saved["operations"][-1] == {
        "crop": {"min": pytest.approx(list(workspace.lo), abs=1e-3), "max": pytest.approx(list(workspace.hi), abs=1e-3)}
    }


def test_the_wireframe_is_the_boxs_twelve_edges_cut_at_the_camera(encoded):
    model, enc = encoded
    cam = enc.all_cameras[0]
    box = CropBox((-0.2, -0.2, 0.0), (0.2, 0.2, 0.3))
    c = corners(box)
    assert len(EDGES) == 12 and all(np.count_nonzero(c[i] != c[j]) == 1 for i, j in EDGES)
    seg = edge_segments(box, cam)
    uv, _ = cam.project(torch.tensor(c, dtype=torch.float64).to(cam.K.dtype))
    ends = {tuple(np.round(p, 3)) for p in seg.reshape(-1, 2)}
    assert len(seg) == 12 and ends == {tuple(np.round(p, 3)) for p in uv.double().numpy()}
    # the camera inside a box: the edges behind it are cut or left out, none drawn mirrored or infinite
    eye = cam.c2w[:3, 3].double().tolist()
    around = CropBox(tuple(v - 0.5 for v in eye), tuple(v + 0.5 for v in eye))
    inner = edge_segments(around, cam)
    assert 0 < len(inner) < 12 and np.isfinite(inner).all()


def test_a_handle_is_found_at_its_face_and_follows_the_mouse_along_its_axis(encoded):
    from viewer.tools.crop_handles import axis_value, face_centres, handle_at, projected_faces

    model, enc = encoded
    cam = enc.all_cameras[0].to("cpu", torch.float64)
    box = CropBox((-0.3, -0.2, 0.0), (0.4, 0.3, 0.5))
    faces = face_centres(box)
    assert faces[1] == pytest.approx([0.4, 0.05, 0.25]) and faces[4] == pytest.approx([0.05, 0.05, 0.0])
    uv, front = projected_faces(box, cam)
    assert front.all()
    for face in range(6):
        assert handle_at(box, cam, uv[face, 0] + 1.0, uv[face, 1] - 1.0, 3.0) == face
    assert handle_at(box, cam, -500.0, -500.0, 3.0) is None
    # the mouse on the projection of a point 0.15 m further along x: the x face's value is that point's x
    for axis in range(3):
        moved = faces[2 * axis + 1].copy()
        moved[axis] += 0.15
        (u, v), _ = cam.project(torch.tensor(moved, dtype=torch.float64))
        value = axis_value(cam, faces[2 * axis + 1], axis, float(u), float(v))
        assert value == pytest.approx(moved[axis], abs=1e-6)
