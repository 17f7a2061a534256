"""Viewer object tools: sliding an object on the floor follows the mouse ray, the gizmo's GL matrices
project as the camera does, the outline hull (Del / Ctrl+D and the gizmo in a window: test_viewer_app.py)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from particlesplat.core.camera import Camera
from particlesplat.editing.move import anchor_points
from particlesplat.editing.open_scene import demo_scenes, encode_scene
from particlesplat.model import load_model
from viewer.session import EditableScene
from viewer.tools.object_tools import FloorDrag, convex_hull, floor_point, gl_projection, gl_view, object_centre


@pytest.fixture(scope="module")
def session_parts():
    torch.set_num_threads(1)
    model = load_model(None)
    return model, encode_scene(model, demo_scenes()[0], [4, 16])


def test_gl_matrices_project_like_the_camera():
    cam = Camera.orbit((0.1, -0.2, 0.15), 35.0, 30.0, 3.2, fov_y_deg=40.0, width=200, height=120)
    cam = Camera(cam.K.clone(), cam.c2w, 200, 120)
    cam.K[0, 2] += 7.0  # an off-centre principal point
    pts = torch.rand(50, 3, dtype=torch.float64) - 0.5
    uv, z = cam.to(dtype=torch.float64).project(pts)
    clip = (gl_projection(cam) @ gl_view(cam) @ np.c_[pts.numpy(), np.ones(50)].T).T
    ndc = clip[:, :3] / clip[:, 3:]
    px = np.stack([(ndc[:, 0] + 1) * 0.5 * 200, (1 - ndc[:, 1]) * 0.5 * 120], 1)
    np.testing.assert_allclose(px, uv.numpy(), atol=1e-6)
    assert (np.abs(ndc[:, 2]) < 1).all() and (z.numpy() > 0).all()


def test_floor_point_lies_on_the_plane_under_the_pixel():
    cam = Camera.orbit((0.0, 0.0, 0.15), -20.0, 35.0, 3.3, width=160, height=120).to(dtype=torch.float64)
    p = floor_point(cam, 50.5, 70.25, 0.12)
    assert abs(float(p[2]) - 0.12) < 1e-12
    uv, _ = cam.project(p[None])
    np.testing.assert_allclose(uv[0].numpy(), [50.5, 70.25], atol=1e-9)
    assert floor_point(cam, 80.0, 0.0, 5.0) is None  # the plane above the camera, looked at from below: behind


def test_convex_hull_of_a_square_with_inner_points():
    pts = np.array([[0, 0], [2, 0], [2, 2], [0, 2], [1, 1], [0.5, 1.5], [1, 0]], dtype=float)
    hull = convex_hull(pts)
    assert {tuple(p) for p in hull} == {(0, 0), (2, 0), (2, 2), (0, 2)}
    area = 0.5 * sum(a[0] * b[1] - b[0] * a[1] for a, b in zip(hull, np.roll(hull, -1, 0), strict=False))
    assert area == pytest.approx(4.0)  # counter-clockwise


def test_floor_drag_slides_the_object_on_its_plane_as_one_undo_step(session_parts):
    model, enc = session_parts
    s = EditableScene(model, enc, source=str(enc.path))
    g = s.editor.decode()
    labels = s.objects()
    own, opacity = g.owner[g.owner >= 0], g.opacities[g.owner >= 0]
    keep = labels[own] >= 0
    weight = torch.zeros(s.editor.num_particles).index_add_(0, labels[own][keep], opacity[keep].float())
    index = int(torch.nonzero(labels == int(weight.argmax()))[0])  # the heaviest object's first particle
    members = s.editor.object_members(index)
    cam = Camera.orbit((0.0, 0.0, 0.15), 10.0, 40.0, 3.4, width=320, height=240)
    centre = object_centre(s.editor, index)
    (u, v), _ = cam.project(centre[None].float())[0][0], None
    drag = FloorDrag()
    assert drag.start(s.editor, index, cam, float(u), float(v))
    a0 = anchor_points(s.editor.particles, members, model.config).double()
    n_ops = len(s.editor.history.undo)
    path = [(float(u) + 6.0 * k, float(v) - 3.0 * k) for k in range(1, 6)]
    for x, y in path:
        assert drag.update(s.editor, cam, x, y) is None
    drag.stop()
    s.editor.end_gesture()
    assert len(s.editor.history.undo) == n_ops + 1
    expected = floor_point(cam, *path[-1], drag.height or float(centre[2])) - floor_point(
        cam, float(u), float(v), float(centre[2])
    )
    assert abs(float(expected[2])) < 1e-9
    moved = anchor_points(s.editor.particles, members, model.config).double() - a0
    np.testing.assert_allclose(moved.numpy(), expected[None].expand_as(moved).numpy(), atol=1e-4)
    # the object's centre is now under the mouse: it projects to the last pixel (within the move's perspective error)
    uv, _ = cam.project(object_centre(s.editor, index)[None].float())
    assert float((uv[0] - torch.tensor(path[-1])).norm()) < 2.0
    assert s.editor.undo() and all(
        torch.equal(getattr(s.editor.particles, k), getattr(s.editor.original, k)) for k in ("z_p", "z_d")
    )
