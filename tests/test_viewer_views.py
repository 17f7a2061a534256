"""Default view, --look/--fov parsing, orbit camera: shared by the viewer and `particlesplat render`."""

from __future__ import annotations

import math

import pytest
import torch

from particlesplat.core.camera import Camera
from particlesplat.core.viewpoints import (
    Look,
    default_context_views,
    default_view,
    focus_point,
    look_from_eye,
    parse_look,
)
from particlesplat.data import read_scene
from particlesplat.editing.open_scene import demo_scenes
from viewer.bench.random_gaussians import random_gaussians
from viewer.orbit import OrbitCamera


def test_parse_look():
    assert parse_look("30, -10.5,2") == Look(30.0, -10.5, 2.0)
    for bad in ("1,2", "a,b,c", "0,95,1", "0,10,-1", "0,10,inf"):
        with pytest.raises(ValueError, match="--look"):
            parse_look(bad)


@pytest.mark.parametrize("az,el,dist", [(0, 30, 3.3), (-120, 10, 2), (75, -40, 5)])
def test_look_from_eye_inverts_orbit_eye(az, el, dist):
    target = torch.tensor([0.3, -0.2, 0.15], dtype=torch.float64)
    look = look_from_eye(target, Camera.orbit_eye(target, az, el, dist))
    assert look.azimuth == pytest.approx(az, abs=1e-9)
    assert look.elevation == pytest.approx(el, abs=1e-9)
    assert look.distance == pytest.approx(dist, abs=1e-9)


def test_focus_point_of_cameras_looking_at_a_point():
    target = torch.tensor([0.0, 0.0, 0.15])
    cams = [Camera.orbit(target, az, el, d) for az, el, d in [(-100, 25, 3), (0, 40, 3.6), (90, 30, 3.2)]]
    assert torch.allclose(focus_point(cams).float(), target, atol=1e-4)


def test_default_view_of_demo_scene_reproduces_its_middle_camera():
    raw = read_scene(demo_scenes()[0])
    view = default_view(raw.cameras)
    mid = raw.cameras[len(raw.cameras) // 2]
    cam = view.camera(mid.width, mid.height)
    assert torch.allclose(cam.c2w, mid.c2w, atol=1e-4)
    assert torch.allclose(cam.K, mid.K, atol=1e-3)
    assert view.fov == pytest.approx(mid.fov_y, abs=1e-4)


def test_default_view_of_gaussians_frames_them():
    g = random_gaussians(3000, seed=1, extent=0.5)
    view = default_view(None, g)
    cam = view.camera(200, 200)
    uv, z = cam.project(g.means)
    inside = ((uv >= 0) & (uv < 200)).all(-1) & (z > 0)
    assert inside.float().mean() > 0.85


def test_default_context_views():
    assert default_context_views(21) == [4, 16]
    assert default_context_views(5) == [0, 4]
    assert default_context_views(1) == [0]


def test_orbit_camera_moves():
    view = default_view(read_scene(demo_scenes()[0]).cameras)
    oc = OrbitCamera.from_view(view)
    oc.orbit(100, 0)
    assert oc.view.look.azimuth == pytest.approx(view.look.azimuth - 30.0)
    oc.zoom(1)
    assert oc.view.look.distance == pytest.approx(view.look.distance * 0.9)
    before = oc.camera(100, 100)
    oc.pan(10, 0, 100)  # scene follows the mouse: the old target moves right on screen
    uv, _ = oc.camera(100, 100).project(torch.tensor(view.target, dtype=torch.float32)[None])
    uv0, _ = before.project(torch.tensor(view.target, dtype=torch.float32)[None])
    assert float(uv[0, 0] - uv0[0, 0]) == pytest.approx(10.0, abs=0.2)
    oc.reset()
    assert oc.view == view


def test_snap_to_input_camera_reproduces_it():
    raw = read_scene(demo_scenes()[0])
    oc = OrbitCamera.from_view(default_view(raw.cameras))
    for i in (0, 7, 20):
        oc.snap(raw.cameras[i])
        cam = oc.camera(raw.cameras[i].width, raw.cameras[i].height)
        assert torch.allclose(cam.c2w, raw.cameras[i].c2w, atol=1e-4)
        assert math.isclose(oc.view.fov, raw.cameras[i].fov_y, abs_tol=1e-4)
