"""The viewer's keypoints / boxes segmentation modes: the marks are those of ``particlesplat render --mode``, follow
the particles through edits, and a .ply session (no particles) draws none."""

from __future__ import annotations

import pytest
import torch
from viewer_helpers import small_model

from particlesplat.analysis.figures import overlay_marks
from particlesplat.analysis.particle_arrays import particle_arrays
from particlesplat.core.camera import Camera
from particlesplat.editing.open_scene import demo_scenes, encode_scene
from viewer.particle_overlay import ParticleOverlay
from viewer.session import EditableScene, PlyScene
from viewer.state import SEG_MODES


@pytest.fixture(scope="module")
def session():
    model = small_model()
    return EditableScene(model, encode_scene(model, demo_scenes()[0], [4, 16]), model_name="small")


def test_modes_are_segmentation_modes():
    assert "keypoints" in SEG_MODES and "boxes" in SEG_MODES


def test_marks_match_the_render_modes_and_follow_edits(session):
    cam = Camera.orbit((0.0, 0.0, 0.15), 15.0, 30.0, 3.3, width=160, height=120)
    overlay = ParticleOverlay()
    arrays = particle_arrays(session.model, session.editor.particles)
    assert arrays.active.any()
    for mode in ("keypoints", "boxes"):
        assert overlay.marks(session, mode, cam) == overlay_marks(arrays, cam, mode)
    assert overlay.marks(session, "normal", cam) == []
    # keypoints: one dot per drawing particle in front of the camera, at its projected anchor
    dots = [m for m in overlay.marks(session, "keypoints", cam) if m.kind == "dot"]
    first = int(arrays.active.nonzero()[0][0])
    uv, _ = cam.to(dtype=torch.float64).project(torch.tensor(arrays.anchor[first], dtype=torch.float64))
    assert dots[0].points[0] == pytest.approx(tuple(uv.tolist()), abs=1e-6)
    # an edit bumps the session version: the marks follow the moved particle
    z_p = session.editor.value(first, "z_p")
    session.editor.set_attribute(first, "z_p", (z_p[0] + 0.2, z_p[1]))
    after = particle_arrays(session.model, session.editor.particles)
    assert float(abs(after.anchor[first] - arrays.anchor[first]).max()) > 0.05  # metres
    assert overlay.marks(session, "keypoints", cam) == overlay_marks(after, cam, "keypoints")
    session.editor.undo()


def test_a_ply_session_has_no_marks(session):
    g = session.gaussians()
    ply = PlyScene(g, source="x.ply")
    cam = Camera.orbit((0.0, 0.0, 0.15), 15.0, 30.0, 3.3, width=64, height=48)
    assert ParticleOverlay().marks(ply, "keypoints", cam) == []
