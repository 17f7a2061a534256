"""The viewer applies the crop box the edits set: the scene's Gaussians (what the view uploads, picks, screenshots
and exports) and each particle's re-decoded Gaussians keep only those whose means lie in the box, counted here
against a brute-force test of every mean, axis by axis."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import yaml
from viewer_helpers import egl_context, small_model

from particlesplat.editing.crop_box import CropBox
from particlesplat.editing.open_scene import demo_scenes, encode_scene
from viewer.gl.renderer import SplatRenderer
from viewer.scene_view import SceneView
from viewer.session import EditableScene
from viewer.state import ViewState


@pytest.fixture(scope="module")
def encoded():
    model = small_model()
    return model, encode_scene(model, demo_scenes()[0])


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
