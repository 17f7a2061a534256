"""The default view, the orbit and the zoom follow the scene, not one family: a robot-like rig 1 m from the table
opens framed, orbits about the table and renders without clipping; a tabletop rig 3-3.6 m away stays as it was;
scene.json's look_at and distance are read when present; the demo scene list holds both families."""

from __future__ import annotations

import argparse
import json
import math
import shutil
from pathlib import Path

import pytest
import torch

from particlesplat.core.camera import Camera
from particlesplat.core.gaussians import Gaussians
from particlesplat.core.viewpoints import Framing, default_view, focus_point
from particlesplat.data import read_scene
from particlesplat.data.scene import SceneFormatError
from particlesplat.data.scene_meta import read_framing
from particlesplat.editing.open_scene import demo_scene_name, demo_scenes
from particlesplat.rendering.api import render
from viewer.orbit import ZOOM_RANGE, OrbitCamera

ROBOT_LOOK_AT = (0.0, 0.0, 0.05)


def _rig(look_at, distances, elevations, azimuths=range(-120, 121, 12), fov=40.0, size=(128, 96)) -> list[Camera]:
    return [
        Camera.orbit(look_at, float(az), el, d, fov_y_deg=fov, width=size[0], height=size[1])
        for az, el, d in zip(azimuths, elevations, distances, strict=True)
    ]


def _robot_rig() -> list[Camera]:
    """21 cameras about 1 m from (0, 0, 0.05) at 30-45 degrees of elevation (distances 0.9-1.1 m)."""
    n = 21
    return _rig(ROBOT_LOOK_AT, [0.9 + 0.2 * i / (n - 1) for i in range(n)], [30 + 15 * (i % 4) / 3 for i in range(n)])


def _assert_framed(cam: Camera, look_at, table_half: float = 0.28) -> None:
    """The look-at projects within 1 pixel of the image centre, and the table's object area (+-table_half m,
    z = 0) lies inside the image in front of the camera."""
    uv, z = cam.project(torch.tensor([look_at], dtype=cam.c2w.dtype))
    assert float(z[0]) > 0
    assert abs(float(uv[0, 0]) - cam.width / 2) < 1.0 and abs(float(uv[0, 1]) - cam.height / 2) < 1.0
    h = table_half
    corners = torch.tensor([[x, y, 0.0] for x in (-h, h) for y in (-h, h)], dtype=cam.c2w.dtype)
    uv, z = cam.project(corners)
    assert bool((z > 0).all())
    assert bool(((uv[:, 0] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] >= 0) & (uv[:, 1] < cam.height)).all()), uv


def test_robot_rig_opens_framed_about_the_table():
    cams = _robot_rig()
    view = default_view(cams)
    assert torch.allclose(torch.tensor(view.target), torch.tensor(ROBOT_LOOK_AT), atol=1e-5)
    median = sorted(float(torch.linalg.norm(c.center.double() - torch.tensor(ROBOT_LOOK_AT).double())) for c in cams)
    assert view.look.distance == pytest.approx(median[len(median) // 2], abs=1e-5)
    assert 0.95 < view.look.distance < 1.05
    mid = cams[len(cams) // 2]  # from the middle camera's direction, with its field of view
    eye = Camera.orbit_eye(view.target, view.look.azimuth, view.look.elevation, 1.0)
    direction = (mid.center.double() - torch.tensor(view.target).double()).to(eye.dtype)
    assert torch.allclose((eye - torch.tensor(view.target).double()), direction / direction.norm(), atol=1e-5)
    assert view.fov == pytest.approx(40.0, abs=1e-4)
    _assert_framed(view.camera(640, 480), ROBOT_LOOK_AT)


def test_robot_rig_orbits_about_the_table_and_zooms_within_its_scale():
    oc = OrbitCamera.from_view(default_view(_robot_rig()))
    for dx, dy in ((200, 0), (-350, 40), (90, -60)):
        oc.orbit(dx, dy)
        # about the table: its look-at stays in the middle of the picture at the same distance
        _assert_framed(oc.camera(640, 480), ROBOT_LOOK_AT, table_half=0.2)
        assert oc.view.look.distance == oc.home.look.distance
    home = oc.home.look.distance
    oc.zoom(1000)
    assert oc.view.look.distance == pytest.approx(ZOOM_RANGE[0] * home)
    oc.zoom(-5000)
    assert oc.view.look.distance == pytest.approx(ZOOM_RANGE[1] * home)


def test_robot_scene_renders_without_clipping():
    """Small Gaussians on the table (objects' heights, the table's corners) all draw in the default view: each
    covers its own pixel (nothing culled by the near or far plane)."""
    view = default_view(_robot_rig())
    cam = view.camera(160, 120)
    pts = torch.tensor([[0.0, 0.0, 0.05], [0.25, 0.2, 0.02], [-0.25, -0.2, 0.1], [0.2, -0.25, 0.2], [-0.22, 0.24, 0.0]])
    n = pts.shape[0]
    g = Gaussians(
        pts,
        torch.tensor([[1.0, 0.0, 0.0, 0.0]]).repeat(n, 1),
        torch.full((n, 3), 0.004),
        torch.full((n,), 0.99),
        torch.full((n, 1, 3), 0.5),
        torch.arange(n),
    )
    res = render(g, cam, background=torch.zeros(3))
    uv, _ = cam.project(pts)
    for u, v in uv.round().long().tolist():
        assert float(res.alpha[v, u]) > 0.5, (u, v)


def test_tabletop_rig_stays_as_before():
    """The demo scene (3.06 m from (0, 0, 0.15)): the default view is its middle camera, framed by the cameras or
    by its scene.json alike."""
    scene = demo_scenes()[0]
    raw = read_scene(scene)
    meta = json.loads((scene / "scene.json").read_text())
    framing = read_framing(scene)
    assert framing == Framing(tuple(meta["look_at"]), meta["distance"])
    assert framing.target == (0.0, 0.0, 0.15) and 3.0 <= framing.distance <= 3.6
    mid = raw.cameras[len(raw.cameras) // 2]
    for view in (default_view(raw.cameras), default_view(raw.cameras, framing=framing)):
        assert torch.allclose(torch.tensor(view.target), torch.tensor([0.0, 0.0, 0.15]), atol=1e-4)
        assert view.look.distance == pytest.approx(meta["distance"], abs=1e-4)
        cam = view.camera(mid.width, mid.height)
        assert torch.allclose(cam.c2w, mid.c2w, atol=1e-4)
        assert torch.allclose(cam.K, mid.K, atol=1e-3)
    oc = OrbitCamera.from_view(default_view(raw.cameras))
    oc.zoom(1)
    assert oc.view.look.distance == pytest.approx(meta["distance"] * 0.9, abs=1e-4)


def test_scene_json_framing_wins_over_the_cameras(tmp_path):
    """Fixed cameras aimed at different points (RLBench-style): scene.json's look_at and distance frame the view;
    without them the view is about the point nearest all axes at the cameras' median distance."""
    cams = [
        Camera.look_at(eye, target, fov_y_deg=40.0, width=128, height=128)
        for eye, target in [
            ((0.55, 0.55, 0.55), (0.0, -0.1, 0.0)),
            ((0.0, -1.1, 0.6), (0.0, 0.0, 0.05)),
            ((-0.55, 0.55, 0.55), (0.0, -0.1, 0.0)),
            ((0.0, -0.05, 1.25), (0.0, 0.0, 0.0)),
        ]
    ]
    (tmp_path / "scene.json").write_text(json.dumps({"look_at": [0.0, 0.0, 0.05], "distance": 1.0}))
    framing = read_framing(tmp_path)
    view = default_view(cams, framing=framing)
    assert view.target == (0.0, 0.0, 0.05) and view.look.distance == 1.0
    _assert_framed(view.camera(640, 480), (0.0, 0.0, 0.05), table_half=0.2)
    derived = default_view(cams)
    focus = focus_point(cams)
    assert torch.allclose(torch.tensor(derived.target, dtype=torch.float64), focus)
    assert float(torch.linalg.norm(focus - torch.tensor([0.0, -0.05, 0.0], dtype=torch.float64))) < 0.15
    dists = sorted(float(torch.linalg.norm(c.center.double() - focus)) for c in cams)
    assert derived.look.distance == pytest.approx(dists[1], abs=1e-6)  # torch's median: the lower middle value
    assert 0.8 < derived.look.distance < 1.4


def test_one_camera_looks_at_the_support_plane():
    cam = Camera.look_at((0.3, -0.8, 0.6), (0.1, 0.1, 0.0), width=64, height=64)
    assert torch.allclose(focus_point([cam]).float(), torch.tensor([0.1, 0.1, 0.0]), atol=1e-5)
    view = default_view([cam])
    assert view.look.distance == pytest.approx(math.dist((0.3, -0.8, 0.6), (0.1, 0.1, 0.0)), abs=1e-5)


def test_read_framing_absent_and_bad(tmp_path):
    assert read_framing(tmp_path) is None  # no scene.json
    (tmp_path / "scene.json").write_text(json.dumps({"objects": []}))
    assert read_framing(tmp_path) is None  # no look_at: the cameras frame the scene
    (tmp_path / "scene.json").write_text(json.dumps({"look_at": [0.0, 0.0, 0.05]}))
    assert read_framing(tmp_path) == Framing((0.0, 0.0, 0.05), None)
    for meta, key in (
        ({"look_at": [0, 0]}, "look_at"),
        ({"look_at": [0, "a", 0]}, "look_at"),
        ({"look_at": [0, 0, 0], "distance": -1}, "distance"),
        ({"look_at": [0, 0, 0], "distance": float("inf")}, "distance"),
    ):
        (tmp_path / "scene.json").write_text(json.dumps(meta))
        with pytest.raises(SceneFormatError) as e:
            read_framing(tmp_path)
        assert str(tmp_path / "scene.json") in str(e.value) and f"'{key}'" in str(e.value) and "\n" not in str(e.value)
    (tmp_path / "scene.json").write_text("{not json")
    with pytest.raises(SceneFormatError, match="not valid JSON"):
        read_framing(tmp_path)


def test_viewer_and_render_take_the_framing_from_scene_json(tmp_path):
    """The viewer's initial view and ``particlesplat render``'s default camera read the scene folder's scene.json
    (here: a look-at the cameras' axes do not share, and a distance none of them has)."""
    from particlesplat.cli.render import resolve_camera
    from viewer.app import initial_view

    cams = _robot_rig()
    (tmp_path / "scene.json").write_text(json.dumps({"look_at": [0.05, -0.02, 0.08], "distance": 1.2}))

    class Session:  # the attributes initial_view reads
        cameras = cams
        source = str(tmp_path)

    view = initial_view(Session(), None, None)
    assert view.target == (0.05, -0.02, 0.08) and view.look.distance == 1.2
    looked = initial_view(Session(), "30,20,0.5", None)  # --look: about the same target
    assert looked.target == view.target and (looked.look.azimuth, looked.look.distance) == (30.0, 0.5)
    args = argparse.Namespace(width=320, height=240, view=None, look=None, fov=None, camera_from=None)
    cam, rview = resolve_camera(args, cams, None, read_framing(tmp_path))
    assert rview == view
    _assert_framed(cam, (0.05, -0.02, 0.08))


def test_demo_scenes_list_both_families(tmp_path, monkeypatch):
    import importlib.resources

    real = demo_scenes()
    assert real and all(demo_scene_name(p) == p.name for p in real if p.parent.parent.name != "robot")
    assert all(demo_scene_name(p) == f"robot/{p.name}" for p in real if p.parent.parent.name == "robot")
    for sub in ("scenes/scene_00001", "scenes/scene_00000", "robot/scenes/scene_00000", "robot/scenes/notes"):
        (tmp_path / sub).mkdir(parents=True)
    for sub in ("scenes/scene_00001", "scenes/scene_00000", "robot/scenes/scene_00000"):
        shutil.copy(real[0] / "transforms.json", tmp_path / sub / "transforms.json")
    monkeypatch.setattr(importlib.resources, "files", lambda package: Path(tmp_path))
    found = demo_scenes()
    assert found == [
        tmp_path / "scenes/scene_00000",
        tmp_path / "scenes/scene_00001",
        tmp_path / "robot/scenes/scene_00000",
    ]
    assert [demo_scene_name(p) for p in found] == ["scene_00000", "scene_00001", "robot/scene_00000"]
    shutil.rmtree(tmp_path / "robot")
    assert demo_scenes() == found[:2]  # no robot demo scenes: the tabletop ones alone
