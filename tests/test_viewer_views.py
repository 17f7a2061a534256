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


def test_a_robot_scene_opens_with_its_whole_arm_in_view():
    """A robot demo scene's default view shows the arm whole: every joint, the base and the gripper's tip (from
    the scene's joint angles by forward kinematics) and the table top's corners project inside a square image
    through the view's own camera, though the middle camera's framing cuts the arm off. The camera only rises and
    backs off: azimuth and elevation stay the middle camera's, and no more than needed (a shorter distance leaves
    a point out)."""
    from dataclasses import replace

    from particlesplat.core.panda_arm import arm_points
    from particlesplat.core.viewpoints import KEEP_BACKOFF, KEEP_MARGIN
    from particlesplat.data.scene_meta import read_arm_state, read_framing

    def inside(view, pts, margin=1.0):
        cam = view.camera(200, 200)
        uv, z = cam.project(pts.float())
        lo, hi = 100 * (1 - margin), 100 * (1 + margin)
        return bool((z > 0).all() and ((uv >= lo) & (uv <= hi)).all())

    robots = [p for p in demo_scenes() if "robot" in str(p)]
    assert robots
    cut_before = 0
    for scene in robots:
        framing = read_framing(scene)
        state = read_arm_state(scene)
        assert framing is not None and state is not None
        pts = torch.tensor(arm_points(state), dtype=torch.float64)
        assert torch.allclose(torch.tensor(framing.keep[: len(pts)], dtype=torch.float64), pts)
        corners = torch.tensor(framing.keep[len(pts) :], dtype=torch.float64)
        assert corners.shape == (4, 3) and bool((corners[:, :2].abs() > 0.3).all())  # the 0.8 m table's corners
        pts = torch.cat([pts, corners])
        cams = read_scene(scene).cameras
        plain = default_view(cams, framing=replace(framing, keep=()))
        view = default_view(cams, framing=framing)
        cut_before += not inside(plain, pts)
        assert inside(view, pts, KEEP_MARGIN + 1e-6), scene
        assert view.look.azimuth == pytest.approx(plain.look.azimuth)
        assert view.look.elevation == pytest.approx(plain.look.elevation)
        assert view.target[2] >= plain.target[2] and view.look.distance >= plain.look.distance
        if view.look.distance > plain.look.distance * (1 + 1e-9):  # backed off: one step less would not fit
            closer = replace(
                view, look=replace(view.look, distance=view.look.distance - KEEP_BACKOFF[2] * plain.look.distance)
            )
            assert not inside(closer, pts, KEEP_MARGIN)
    assert cut_before >= 1  # the check means something: the cameras' own framing cuts an arm off
