"""The app in-process in a real window (CI runs pytest under xvfb-run): picking, dragging a
particle, undo, screenshot and .ply export requests, opening another scene, the idle loop; once per
compositing path (``--compositing``, see conftest.py)."""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np
import pytest
import torch
from imgui_bundle import imgui
from PIL import Image
from viewer_helpers import psnr, small_model

from particlesplat import render
from particlesplat.core.gaussians import Gaussians
from particlesplat.core.userdirs import autosave_dir
from particlesplat.model import save_checkpoint
from viewer import app as A
from viewer.bench.random_gaussians import random_gaussians
from viewer.launch import build_parser

pytestmark = pytest.mark.window


@pytest.fixture(scope="module")
def window():
    """One window and its moderngl context for the module's apps (moderngl detects a window's
    context once, and a process cannot open a GL window again after closing one on EGL)."""
    import moderngl

    if not os.environ.get("DISPLAY"):
        pytest.fail("no DISPLAY: run the tests under xvfb-run (see the README's test command)")
    w = A.create_window((160, 120))
    yield w, moderngl.create_context()
    A.destroy_window(w)


@pytest.fixture(scope="module")
def app(tmp_path_factory, window, compositing):
    import glfw

    window, ctx = window
    tmp = tmp_path_factory.mktemp("app")
    ckpt = tmp / "small.pt"
    save_checkpoint(ckpt, small_model(), 0)
    args = build_parser().parse_args(
        ["--checkpoint", str(ckpt), "--size", "160x120", "--output-dir", str(tmp), "--compositing", compositing]
    )
    session = A.load_session(args)
    glfw.set_window_size(window, *args.size)
    a = A.App(window, session, A.initial_view(session, None, None), args, ctx=ctx)
    a.run(2)
    yield a
    a.scene_view.renderer.release()


def test_pick_selects_the_dominant_particle(app):
    app.state.seg_mode = "background hidden"  # untrained particles are faint next to the background
    app.run(1)
    cam = app.view_camera(1.0)
    g = app.scene_view.visible_gaussians(app.session, app.state)
    res = render(g, cam, owner_weights=True, num_owners=app.session.num_owners())
    margin = res.owner_weights.max(0).values - (res.background_weight + 1.0 - res.alpha)
    y, x = np.unravel_index(int(margin.argmax()), margin.shape)
    app.controls.pick(app.viewport(), float(x), float(y))
    assert app.state.selected == int(res.owner_weights[:, y, x].argmax())
    app.state.seg_mode = "normal"


def test_screenshot_and_export(app, tmp_path):
    app.fields.output_dir = str(tmp_path)
    app.fields.shot_size = [64, 48]
    app.req.screenshot = True
    app.req.export_ply = True
    app.state.prune = 0.2
    app.run(1)
    shots = sorted(tmp_path.glob("particlesplat_*.png"))
    plys = sorted(tmp_path.glob("particlesplat_*.ply"))
    assert [p.name for p in shots] == ["particlesplat_0001.png"] and len(plys) == 1
    img = Image.open(shots[0])
    assert img.size == (64, 48) and "camera" in img.text
    ref = render(
        app.scene_view.visible_gaussians(app.session, app.state),
        app.orbit.camera(64, 48),
        background=app.state.background,
    ).rgb.numpy()
    assert psnr(np.asarray(img.convert("RGB"), np.float64) / 255.0, ref) >= 40.0
    exported = Gaussians.load_ply(plys[0])
    assert exported.num == app.scene_view.visible_gaussians(app.session, app.state).num
    assert bool((exported.opacities >= 0.2 - 1e-6).all())
    app.state.prune = 0.0


def test_export_object_ply(app, tmp_path):
    """The panel's "Export object": the selected particle's object alone, its Gaussians as decoded."""
    s = app.session
    i = next(k for k in range(s.editor.num_particles) if s.editor.is_active(k))
    app.fields.output_dir = str(tmp_path)
    app.state.selected = i
    app.req.export_object = True
    app.run(1)
    plys = sorted(tmp_path.glob("particlesplat_*.ply"))
    assert len(plys) == 1, app.fields.status
    exported = Gaussians.load_ply(plys[0])
    members = s.editor.object_members(i)
    ref = s.model.decode(s.editor.particles, torch.tensor(members), background=False)
    assert set(exported.owner.tolist()) <= set(members)
    ref = ref.subset(ref.opacities >= app.state.prune)
    assert exported.num == ref.num
    torch.testing.assert_close(exported.means, ref.means.detach().float(), atol=1e-6, rtol=0)
    app.state.selected = None


def test_export_menu_writes_an_object_bundle(app, tmp_path):
    """The format menu's "bundle": a folder of one .ply an object plus rest.ply and manifest.json, together the
    Gaussians drawn."""
    import json

    from particlesplat.formats.splat_files import read_gaussians

    app.fields.output_dir, app.fields.export_format = str(tmp_path), "bundle"
    app.req.export_ply = True
    app.run(1)
    app.fields.export_format = ".ply"
    out = tmp_path / "particlesplat_0001.bundle"
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["by"] == "object" and manifest["parts"][-1]["file"] == "rest.ply", app.fields.status
    drawn = app.scene_view.visible_gaussians(app.session, app.state)
    assert read_gaussians(out / "manifest.json").means.shape[0] == drawn.num == manifest["gaussians"]


def test_insert_object_request(app):
    """The panel's "Insert object from another scene": the app encodes the scene and inserts the object (undoable)."""
    from particlesplat.editing.open_scene import demo_scenes

    s = app.session
    n = s.editor.num_particles
    app.fields.insert.scene, app.fields.insert.object, app.fields.insert.at = str(demo_scenes()[1]), 0, [0.8, 0.5]
    app.req.insert = True
    app.run(1)
    assert s.editor.num_particles > n, app.fields.status
    assert app.state.selected == n and s.editor.operations()[-1].kind == "insert"
    assert s.editor.object_members(n) == list(range(n, s.editor.num_particles))
    s.editor.undo()
    assert s.editor.num_particles == n
    app.state.selected = None
    app.run(1)


def test_render_scale_and_no_redraw_when_still(app):
    fw, fh = app.framebuffer_size()
    app.controls.last_move = time.perf_counter() + 60.0  # moving (whatever the machine's speed)
    app.run(1)
    assert app.scene_view.renderer.size == (round(fw * 0.5), round(fh * 0.5))
    app.controls.last_move = time.perf_counter() - A.STILL_AFTER - 0.01  # stopped just long enough
    app.run(1)
    assert app.scene_view.renderer.size == (fw, fh)
    last = app.scene_view.last_times
    app.run(2)
    assert app.scene_view.last_times is last  # nothing changed: nothing re-rendered


def press(app, *keys) -> None:
    """Press keys (modifiers first) for one frame, release them in the next."""
    io = imgui.get_io()
    for k in keys:
        io.add_key_event(k, True)
    app.run(1)
    for k in reversed(keys):
        io.add_key_event(k, False)
    app.run(1)


def chord(app, key: str, shift: bool = False) -> None:
    """A Ctrl chord as glfw's key callback reports it (the key with its modifiers), then two frames."""
    import glfw

    code = {"z": glfw.KEY_Z, "y": glfw.KEY_Y, "s": glfw.KEY_S, "d": glfw.KEY_D}[key]
    app.chords.on_key(app.window, code, 0, glfw.PRESS, glfw.MOD_CONTROL | (glfw.MOD_SHIFT if shift else 0))
    app.run(1)
    app.run(1)


def test_keyboard_shortcuts(app, tmp_path):
    K = imgui.Key
    s = app.session
    z0 = s.editor.value(0, "z_d")
    s.editor.set_attribute(0, "z_d", [z0[0] + 1.0])
    chord(app, "z")
    assert s.editor.value(0, "z_d") == z0
    chord(app, "z", shift=True)
    assert s.editor.value(0, "z_d")[0] == pytest.approx(z0[0] + 1.0)
    mode = app.state.seg_mode
    press(app, K.m)
    assert app.state.seg_mode != mode
    app.state.seg_mode = mode
    app.orbit.orbit(50, 0)
    press(app, K.r)
    assert app.orbit.view == app.orbit.home
    press(app, K._3)  # input camera 3: numbered from 0, as --context and render --view
    cams = app.session.cameras
    assert app.orbit.view.fov == pytest.approx(cams[3].fov_y)
    c2w = app.orbit.camera(8, 8).c2w.double()
    torch.testing.assert_close(c2w[:3, 2], cams[3].c2w[:3, 2].double(), atol=1e-4, rtol=0)  # its axis
    torch.testing.assert_close(c2w[:3, 3], cams[3].c2w[:3, 3].double(), atol=1e-4, rtol=0)  # its centre
    app.fields.output_dir = str(tmp_path)
    press(app, K.p)
    assert len(list(tmp_path.glob("particlesplat_*.png"))) == 1


def test_open_ply_replaces_the_session(app, tmp_path):
    g = random_gaussians(200, seed=1)
    g.save_ply(tmp_path / "g.ply")
    app.req.open_path = str(tmp_path / "g.ply")
    app.run(1)
    assert app.session.editor is None and app.scene_view.renderer.num == 200
    app.req.open_path = str(tmp_path / "missing")
    app.run(1)
    assert "error" in app.fields.status and "missing" in app.fields.status


def test_export_menu_writes_every_format_and_the_file_box_opens_it(app, tmp_path):
    """The Output section's format: each Gaussian file format is written, read back whole by the format's reader,
    and opened again through the file box."""
    from particlesplat.formats.splat_files import SUFFIXES, read_gaussians

    random_gaussians(200, seed=2).save_ply(tmp_path / "g.ply")
    app.req.open_path = str(tmp_path / "g.ply")
    app.run(1)
    kept = app.fields.output_dir, app.fields.export_format
    app.fields.output_dir = str(tmp_path / "out")
    seen: set = set()
    for suffix in SUFFIXES:
        app.fields.export_format = suffix
        app.req.export_ply = True
        app.run(1)
        new = set((tmp_path / "out").glob("particlesplat_*")) - seen
        assert len(new) == 1 and next(iter(new)).name.endswith(suffix), (suffix, app.fields.status)
        seen |= new
        path = next(iter(new))
        assert read_gaussians(path).means.shape[0] == 200
        app.req.open_path = str(path)
        app.run(1)
        assert "error" not in app.fields.status and app.scene_view.renderer.num == 200, app.fields.status
    app.fields.output_dir, app.fields.export_format = kept


def test_open_keeps_unsaved_edits_and_offers_them_back(app, tmp_path):
    from particlesplat.editing.open_scene import demo_scenes

    scene = demo_scenes()[0]
    app.fields.output_dir = str(tmp_path)
    app.open(str(scene))
    app.session.editor.set_attribute(1, "z_p", [0.3, -0.2])
    assert app.session.unsaved
    app.req.open_path = str(scene)  # the same scene again: the edits would be gone
    app.run(1)
    kept = app.session.autosave_path(autosave_dir())  # keyed by the resolved path and content of the scene
    assert kept.name.startswith(f"tabletop-{scene.name}-") and kept.is_file()
    assert kept.parent == Path(os.environ["XDG_STATE_HOME"]) / "particlesplat" / "autosave"
    assert not list(tmp_path.glob("*.yaml"))  # the output folder holds no autosave
    assert f"unsaved edits of the previous scene kept in {kept}" in app.fields.status
    assert "Load edits restores them" in app.fields.status and app.fields.edits_path == str(kept)
    assert app.session.editor.edits() == {} and not app.session.unsaved
    app.req.load_edits = True
    app.run(1)
    assert app.session.editor.value(1, "z_p") == pytest.approx((0.3, -0.2)) and not app.session.unsaved


def test_orbit_frames_move_like_a_drag_then_the_still_frame(app):
    fw, fh = app.framebuffer_size()
    look = app.orbit.view.look
    app.run(2, orbit=True)
    assert app.orbit.view.look.azimuth == pytest.approx(look.azimuth + 2 * A.ORBIT_STEP)
    assert app.scene_view.renderer.size == (round(fw * app.state.moving_scale), round(fh * app.state.moving_scale))
    assert app.still_frame() > 0.0
    assert app.scene_view.renderer.size == (fw, fh)


def test_idle_loop_draws_only_after_events(app):
    """Idle, the loop sleeps and draws nothing; a window event draws the settle frames; a motion
    is followed by one full-scale frame without further input."""
    import glfw

    from viewer.redraw import SETTLE_FRAMES

    app.run(seconds=0.3)  # let earlier frames and events settle
    drawn = len(app.frame_times)
    app.run(seconds=0.5)
    assert len(app.frame_times) == drawn  # no input, nothing changed: no frame
    events = app.redraw.events
    glfw.set_window_size(app.window, 170, 120)  # a real window event through glfw's callbacks
    app.run(seconds=0.5)
    assert app.redraw.events > events
    assert SETTLE_FRAMES <= len(app.frame_times) - drawn <= SETTLE_FRAMES + 2  # (+1 for the re-render at the new size)
    assert app.scene_view.renderer.size == app.framebuffer_size()
    glfw.set_window_size(app.window, 160, 120)
    app.run(seconds=0.3)
    # a drag's last frame renders at the moving scale; the full-scale frame follows when it stops
    app.controls.last_move = time.perf_counter()
    app.orbit.orbit(5.0, 0.0)
    app.run(1)
    fw, fh = app.framebuffer_size()
    assert app.scene_view.renderer.size == (round(fw * 0.5), round(fh * 0.5))
    drawn = len(app.frame_times)
    app.run(seconds=A.STILL_AFTER + 0.4)
    assert app.scene_view.renderer.size == (fw, fh)
    assert 1 <= len(app.frame_times) - drawn <= SETTLE_FRAMES
    drawn = len(app.frame_times)
    app.run(seconds=0.3)
    assert len(app.frame_times) == drawn  # and then nothing


def test_object_gizmo_delete_and_duplicate_keys(window, tmp_path):
    """On a demo scene: the gizmo and outline draw, Ctrl+D copies the selected object, Del removes it, and
    the edits save as version 2 operations."""
    import glfw

    from particlesplat.editing.open_scene import demo_scenes

    win, ctx = window
    args = build_parser().parse_args(
        ["--scene", str(demo_scenes()[0]), "--context", "4,16", "--size", "160x120", "--output-dir", str(tmp_path)]
    )
    session = A.load_session(args)
    glfw.set_window_size(win, *args.size)
    app = A.App(win, session, A.initial_view(session, None, None), args, ctx=ctx)
    try:
        g = session.editor.decode()
        index = int(g.owner[g.owner >= 0][g.opacities[g.owner >= 0].argmax()])
        app.state.selected = index
        app.run(2)  # the gizmo and the outline draw without error
        # a plain drag that starts on the selected object slides it on the floor: one operation, no height change
        from viewer.tools.object_tools import object_centre

        app.state.panel = False
        glfw.set_window_size(win, 400, 300)
        deadline = time.monotonic() + 5.0  # the X server applies a resize when it gets to it (slow under load)
        while glfw.get_framebuffer_size(win) != (400, 300) and time.monotonic() < deadline:
            glfw.wait_events_timeout(0.05)
        assert glfw.get_framebuffer_size(win) == (400, 300), "the X server did not resize the window in 5 s"
        app.run(2)
        cam = app.view_camera(1.0)
        uv, _ = cam.project(object_centre(session.editor, index)[None].float())
        seg = render(
            session.editor.decode(), cam, owner_weights=True, num_owners=session.editor.num_particles
        ).segmentation(session.objects())
        ys, xs = np.nonzero((seg == int(session.objects()[index])).numpy())
        dist = np.hypot(xs + 0.5 - float(uv[0, 0]), ys + 0.5 - float(uv[0, 1]))
        dist[dist < 35.0] = np.inf  # grab the object clear of the gizmo's handles
        sx, sy = app.pixel_ratio()
        u, v = round(float(xs[dist.argmin()]) / sx), round(float(ys[dist.argmin()]) / sy)  # X pointers are whole
        io = imgui.get_io()
        n_ops = len(session.editor.history.undo)
        _point_at(app, u, v)
        io.add_mouse_button_event(0, True)
        app.run(1)
        for k in range(1, 6):
            _point_at(app, u + 4 * k, v + k)
        io.add_mouse_button_event(0, False)
        app.run(1)
        assert len(session.editor.history.undo) == n_ops + 1 and session.editor.history.undo[-1].kind == "translate"
        dx, dy, dz = session.editor.history.undo[-1].offset
        assert abs(dz) < 1e-9 and (dx * dx + dy * dy) ** 0.5 > 0.02
        session.editor.undo()
        app.state.panel = True
        n = session.editor.num_particles
        members = session.editor.object_members(index)
        K = imgui.Key
        chord(app, "d")
        assert session.editor.num_particles == n + len(members) and app.state.selected == n  # the copy is selected
        press(app, K.delete)
        assert [op.kind for op in session.editor.history.undo[-2:]] == ["duplicate", "remove"]
        assert app.state.selected is None and "removed" in app.fields.status
        assert not bool((session.editor.decode().owner >= n).any())
        text = session.save_edits(tmp_path / "e.yaml").read_text()
        assert "duplicate:" in text and "remove: true" in text
    finally:
        app.scene_view.renderer.release()


def test_a_signal_wakes_the_idle_loop_and_the_edits_are_autosaved(window, tmp_path):
    """SIGTERM while the loop sleeps in glfw.wait_events() ends it within a second, and the unsaved edit is
    autosaved on close (the window-close path of particlesplat-viewer)."""
    import signal
    import threading

    import glfw

    from viewer.signals import SignalStop

    win, ctx = window
    ckpt = tmp_path / "small.pt"
    save_checkpoint(ckpt, small_model(), 0)
    args = build_parser().parse_args(["--checkpoint", str(ckpt), "--size", "160x120", "--output-dir", str(tmp_path)])
    session = A.load_session(args)
    app = A.App(win, session, A.initial_view(session, None, None), args, ctx=ctx)
    try:
        app.run(2)
        session.editor.remove_object(0)  # an unsaved edit
        with SignalStop(glfw.post_empty_event) as stop:
            app.stop = stop
            app.run(seconds=0.3)  # settle: then nothing is left to draw
            timer = threading.Timer(0.5, os.kill, (os.getpid(), signal.SIGTERM))
            t0 = time.perf_counter()
            timer.start()
            app.run(seconds=20.0)
            elapsed = time.perf_counter() - t0
            timer.join()
        assert stop.signum == signal.SIGTERM
        assert elapsed < 1.5, elapsed  # 0.5 s until the signal, then within a second
        kept = app.keep_unsaved()
        assert kept is not None and kept.is_file() and "remove: true" in kept.read_text()
    finally:
        app.scene_view.renderer.release()


def _demo_app(window, tmp_path, scene, size=(160, 120)):
    import glfw

    win, ctx = window
    args = build_parser().parse_args(
        ["--scene", str(scene), "--context", "4,16", "--size", "x".join(map(str, size)), "--output-dir", str(tmp_path)]
    )
    session = A.load_session(args)
    glfw.set_window_size(win, *size)
    return A.App(win, session, A.initial_view(session, None, None), args, ctx=ctx)


def _robot_app_selecting(window, tmp_path):
    """An app on the first robot demo scene in a 400x300 window, panel hidden, its most opaque particle's object
    selected: (app, that particle)."""
    import glfw

    from particlesplat.editing.open_scene import demo_scenes

    app = _demo_app(window, tmp_path, next(p for p in demo_scenes() if "robot" in str(p)), size=(400, 300))
    deadline = time.monotonic() + 5.0
    while glfw.get_framebuffer_size(app.window) != (400, 300) and time.monotonic() < deadline:
        glfw.wait_events_timeout(0.05)
    g = app.session.editor.decode()
    index = int(g.owner[g.owner >= 0][g.opacities[g.owner >= 0].argmax()])
    app.state.selected, app.state.panel = index, False
    return app, index


def test_the_gizmo_centre_handle_slides_a_robot_object_on_its_plane(window, tmp_path):
    """On a robot demo scene at its default view, a drag that grabs the gizmo's centre handle (which covers a
    robot-sized object whole) slides the object on the horizontal plane: one translate, no height change, nothing
    below the table."""
    from viewer.tools.object_tools import object_centre

    app, index = _robot_app_selecting(window, tmp_path)
    ed, io = app.session.editor, imgui.get_io()
    try:
        app.run(2)
        uv, _ = app.view_camera(1.0).project(object_centre(ed, index)[None].float())
        sx, sy = app.pixel_ratio()
        u, v = round(float(uv[0, 0]) / sx), round(float(uv[0, 1]) / sy)
        n_ops = len(ed.history.undo)
        _point_at(app, u, v)
        io.add_mouse_button_event(0, True)
        app.run(1)
        for k in range(1, 6):
            _point_at(app, u + 5 * k, v + 2 * k)
        assert app.gizmo.using and app.gizmo.drag.mode == "floor"
        io.add_mouse_button_event(0, False)
        app.run(1)
        assert len(ed.history.undo) == n_ops + 1 and ed.history.undo[-1].kind == "translate"
        dx, dy, dz = ed.history.undo[-1].offset
        assert dz == 0.0 and (dx * dx + dy * dy) ** 0.5 > 0.01 and not ed.sunk_objects()
    finally:
        io.add_mouse_button_event(0, False)
        app.run(1)
        app.scene_view.renderer.release()


def test_the_gizmo_scale_handles_scale_the_object_on_its_support(window, tmp_path):
    """With the scale handles on (S), dragging one away from the object's centre grows the object: one scale
    operation, its bottom still on the table."""
    from viewer.tools.object_tools import object_centre

    app, index = _robot_app_selecting(window, tmp_path)
    ed, io = app.session.editor, imgui.get_io()
    try:
        press(app, imgui.Key.s)
        assert app.state.gizmo_scale
        app.run(2)
        cam = app.view_camera(1.0)
        centre = object_centre(ed, index)
        sx, sy = app.pixel_ratio()
        (cu, cv), _ = cam.project(centre[None].float())[0][0], None
        grabbed = None
        for axis in range(3):  # the handle at the end of an axis: found by hovering along it
            tip = centre.clone()
            tip[axis] += 0.05
            (tu, tv) = cam.project(tip[None].float())[0][0].tolist()
            d = np.array([tu - float(cu), tv - float(cv)])
            if np.linalg.norm(d) < 1e-3:
                continue
            d /= np.linalg.norm(d)
            for r in range(10, 160, 4):
                u, v = round((float(cu) + r * d[0]) / sx), round((float(cv) + r * d[1]) / sy)
                _point_at(app, u, v)
                app.run(1)
                if app.gizmo.hovered:
                    grabbed = (u, v, d)
                    break
            if grabbed:
                break
        assert grabbed is not None, "no scale handle found along the axes"
        u, v, d = grabbed
        n_ops = len(ed.history.undo)
        io.add_mouse_button_event(0, True)
        app.run(1)
        for k in range(1, 6):
            _point_at(app, round(u + 6 * k * d[0]), round(v + 6 * k * d[1]))
        io.add_mouse_button_event(0, False)
        app.run(1)
        assert len(ed.history.undo) == n_ops + 1 and ed.history.undo[-1].kind == "scale", app.fields.status
        assert ed.history.undo[-1].factor != pytest.approx(1.0) and not ed.sunk_objects()
    finally:
        io.add_mouse_button_event(0, False)
        app.state.gizmo_scale = False
        app.run(1)
        app.scene_view.renderer.release()


def _load_rgb(path) -> np.ndarray:
    return np.asarray(Image.open(path).convert("RGB"), np.float64) / 255.0


def test_a_screenshot_carries_its_edit_file_and_render_replays_it(window, tmp_path):
    """After a move, a delete, a duplicate and an insert, the screenshot's 'edits' chunk is the whole version 2
    edit file: `particlesplat render --camera-from shot.png --edits-from shot.png` reproduces the screenshot."""
    from particlesplat.cli.main import main as cli_main
    from particlesplat.editing.open_scene import demo_scenes

    scene = demo_scenes()[0]
    app = _demo_app(window, tmp_path, scene)
    try:
        s = app.session
        g = s.editor.decode()
        labels = s.objects()
        weight: dict[int, float] = {}
        for o, w in zip(g.owner.tolist(), g.opacities.tolist(), strict=True):
            if o >= 0 and int(labels[o]) >= 0:
                weight[int(labels[o])] = weight.get(int(labels[o]), 0.0) + w
        # the three heaviest objects, each by its first particle
        a, b, c = (int(torch.nonzero(labels == k)[0]) for k in sorted(weight, key=lambda k: -weight[k])[:3])
        s.editor.move_object(a, [0.06, -0.04, 0.0])
        s.editor.end_gesture()
        s.editor.remove_object(b)
        s.editor.duplicate_object(c, [0.0, 0.12, 0.0])
        app.fields.insert.scene = str(demo_scenes()[1])
        app.req.insert = True
        app.run(1)
        assert [op.kind for op in s.editor.history.undo] == ["translate", "remove", "duplicate", "insert"], (
            app.fields.status
        )
        app.fields.shot_size = [128, 96]
        shot = app.screenshot_numbered()
        text = Image.open(shot).text["edits"]
        for key in ("version: 2", "scene_sha256:", "translate:", "remove: true", "duplicate:", "insert:"):
            assert key in text
        out, plain = tmp_path / "replay.png", tmp_path / "plain.png"
        prune = ["--prune", str(app.state.prune)]
        replay = ["render", "--camera-from", str(shot), "--edits-from", str(shot), *prune]
        assert cli_main([*replay, "--out", str(out)]) == 0
        assert psnr(_load_rgb(shot), _load_rgb(out)) >= 40.0
        # the edits are what makes it match: the scene without them does not
        base = ["render", "--scene", str(scene), "--context", "4,16", "--camera-from", str(shot), *prune]
        assert cli_main([*base, "--out", str(plain)]) == 0
        assert psnr(_load_rgb(shot), _load_rgb(plain)) < 35.0
    finally:
        app.scene_view.renderer.release()


def test_edits_are_saved_per_scene_and_another_scenes_file_is_not_replaced(window, tmp_path):
    """Save edits writes FAMILY-NAME-HASH.edits.yaml of the scene shown (two folders of one name: two files); a file
    holding another scene's edits is replaced only by a second Save; two scene folders of one name have their own
    autosaves (in the user's state folder, not the output folder), and loading one's edits onto the other warns."""
    import shutil

    from particlesplat.editing.open_scene import demo_scenes

    a_dir, b_dir = tmp_path / "train" / "scene_00000", tmp_path / "test" / "scene_00000"
    shutil.copytree(demo_scenes()[0], a_dir)
    shutil.copytree(demo_scenes()[0], b_dir)
    with open(b_dir / "scene.json", "a") as f:  # another scene of the same name (its content differs)
        f.write("\n")
    out = tmp_path / "out"
    app = _demo_app(window, out, a_dir)
    try:
        a_file = out / f"{app.session.file_key}.edits.yaml"
        assert app.fields.edits_path == str(a_file) and a_file.name.startswith("tabletop-scene_00000-")
        app.session.editor.remove_object(int(app.session.editor.decode().owner.max()))
        app.req.save_edits = True
        app.run(1)
        saved = a_file.read_text()
        assert "remove: true" in saved and str(a_dir.resolve()) in saved, app.fields.status
        app.session.editor.move_object(0, [0.05, 0.0, 0.0])  # unsaved: autosaved when B opens
        app.req.open_path = str(b_dir)
        app.run(1)
        kept_a = next(autosave_dir().iterdir())
        assert "kept in" in app.fields.status and "autosaved edits of this scene found" not in app.fields.status
        assert app.session.autosave_path(autosave_dir()) != kept_a  # B does not see A's autosave
        assert app.fields.edits_path != str(a_file)  # nor shares A's edit file: its path differs
        assert not (out / ".particlesplat-autosave").exists()
        # B's own edits: Save to A's file is refused once, then done
        app.session.editor.move_object(0, [0.0, 0.05, 0.0])
        app.fields.edits_path = str(a_file)
        app.req.save_edits = True
        app.run(1)
        assert app.fields.status.startswith("error: not saved") and "another scene" in app.fields.status
        assert a_file.read_text() == saved
        app.req.save_edits = True
        app.run(1)
        assert str(b_dir.resolve()) in a_file.read_text(), app.fields.status
        # A's autosave loaded onto B: a warning, by content (the names are the same)
        app.fields.edits_path = str(kept_a)
        app.req.load_edits = True
        app.run(1)
        assert "warning: they were made on scene" in app.fields.status
        assert "another scene's content" in app.fields.status
        # a demo scene of another name gets its own default file
        app.req.open_path = str(demo_scenes()[1])
        app.run(1)
        assert app.fields.edits_path == str(out / f"{app.session.file_key}.edits.yaml")
        assert app.session.file_key.startswith("tabletop-scene_00001-")
    finally:
        app.scene_view.renderer.release()


def test_fast_undo_taps_are_all_done_at_once(app):
    """Three Ctrl+Z taps arriving in one burst of window events (a busy machine) are three undos, done before the
    loop goes idle again (imgui takes one change of a key a frame: the loop draws until its queue is empty)."""
    s = app.session
    n0 = len(s.editor.history.undo)
    for _ in range(3):
        s.editor.set_attribute(0, "z_d", [s.editor.value(0, "z_d")[0] + 0.1])
        s.editor.end_gesture()
    app.run(2)
    app.run(seconds=0.3)  # idle
    import glfw

    for _ in range(3):  # the key callbacks of that burst: each Z press carries Ctrl
        app.chords.on_key(app.window, glfw.KEY_Z, 0, glfw.PRESS, glfw.MOD_CONTROL)
        app.chords.on_key(app.window, glfw.KEY_Z, 0, glfw.RELEASE, glfw.MOD_CONTROL)
    app.redraw.notify()
    app.run(seconds=1.0)
    assert len(s.editor.history.undo) == n0
    while len(s.editor.history.redo):
        s.editor.redo()
    while len(s.editor.history.undo) > n0:
        s.editor.undo()


def _wait_for_cursor(window, x: float, y: float, timeout: float = 2.0) -> None:
    """Wait until the X server reports the pointer at (x, y) after a warp."""
    import glfw

    deadline = time.perf_counter() + timeout
    while time.perf_counter() < deadline and glfw.get_cursor_pos(window) != (x, y):
        glfw.wait_events_timeout(0.01)


def _point_at(app, x: int, y: int, timeout: float = 2.0) -> None:
    """Put the pointer on window point (x, y) and draw frames until imgui sees it there with no motion left
    over: the X server applies a warp asynchronously, and the glfw backend reads the pointer itself."""
    import glfw

    glfw.set_cursor_pos(app.window, x, y)
    _wait_for_cursor(app.window, x, y)
    io = imgui.get_io()
    deadline = time.perf_counter() + timeout
    while time.perf_counter() < deadline and (
        (io.mouse_pos.x, io.mouse_pos.y) != (x, y) or (io.mouse_delta.x, io.mouse_delta.y) != (0.0, 0.0)
    ):
        io.add_mouse_pos_event(x, y)
        app.redraw.notify()
        app.run(1)
    assert (io.mouse_pos.x, io.mouse_pos.y) == (x, y), f"imgui does not see the pointer at {(x, y)} after {timeout} s"


def test_a_drag_released_in_one_burst_ends_where_the_mouse_did(app):
    """Moves and the release arriving between two frames: the frame after them shows the camera where the mouse
    ended, and nothing moves after it (no stale motion after the release)."""
    import glfw

    app.state.panel, app.state.selected = False, None
    app.run(2)
    io = imgui.get_io()
    sx, _ = app.pixel_ratio()
    x, y = 40, 60
    start = glfw.get_cursor_pos(app.window)
    _point_at(app, x, y)
    try:
        io.add_mouse_button_event(0, True)
        app.run(1)
        view0 = app.orbit.view
        for k in range(1, 11):
            io.add_mouse_pos_event(x + 3.0 * k, y)
        glfw.set_cursor_pos(app.window, x + 30.0, y)
        _wait_for_cursor(app.window, x + 30.0, y)
        io.add_mouse_button_event(0, False)
        app.redraw.notify()
        app.run(1)
        after = app.orbit.view
        assert after.look.azimuth == pytest.approx(view0.look.azimuth - 30.0 * sx * 0.3)  # orbit: 0.3 degrees a pixel
        app.run(seconds=0.5)
        assert app.orbit.view == after
    finally:  # a failure here must not leave a button down or a turned view for the tests after it
        io.add_mouse_button_event(0, False)
        app.run(1)
        app.orbit.reset()
        app.state.panel = True
        glfw.set_cursor_pos(app.window, *start)  # where the pointer was (the next tests drive it)
        app.run(2)


def test_the_particle_list_names_deleted_particles_and_colours_copies(app):
    """After a duplicate the copies have the swatches of what they copy; a removed object's particles read
    "deleted", the encoder's inactive ones "inactive"."""
    from particlesplat.editing.open_scene import demo_scenes
    from viewer.ui.particles import particle_status

    if app.session.editor is None:  # an earlier test opened a .ply
        app.open(str(demo_scenes()[0]))
    s = app.session
    app.state.selected = None
    app.run(1)
    n = s.editor.num_particles
    first = next(i for i in range(n) if s.editor.is_active(i) and i in app.swatches)
    members = s.editor.object_members(first)
    s.editor.duplicate_object(first, [0.0, 0.0, 0.0])
    app.run(1)
    for k, i in enumerate(range(n, s.editor.num_particles)):
        if members[k] in app.swatches:
            assert app.swatches[i] == pytest.approx(app.swatches[members[k]], abs=1e-5)
    s.editor.undo()
    inactive = [i for i in range(n) if not s.editor.is_active(i)]
    s.editor.remove_object(first)
    assert all(particle_status(s.editor, i) == "deleted" for i in members)
    assert all(particle_status(s.editor, i) == "inactive" for i in inactive)
    s.editor.undo()
    assert particle_status(s.editor, first) == "active"
    app.run(1)


def test_status_line_at_the_bottom_mirrored_on_the_terminal(app, capsys):
    """A message shows on one line at the bottom of the window, below the panel, and once on the terminal; the
    panel's layout is the same with or without it (no shift under the mouse)."""
    find = imgui.internal.find_window_by_name
    app.state.panel = True
    app.fields.status = ""
    app.run(2)
    content = (find("ParticleSplat").content_size.x, find("ParticleSplat").content_size.y)
    capsys.readouterr()
    app.fields.status = "saved 3 edit operation(s) to /somewhere/e.yaml\nand a second line"
    app.run(2)
    status, panel, vp = find("##status"), find("ParticleSplat"), imgui.get_main_viewport()
    assert status.active and status.pos.y + status.size.y == pytest.approx(vp.work_pos.y + vp.work_size.y)
    assert status.size.x == pytest.approx(vp.work_size.x)
    assert panel.pos.y + panel.size.y <= status.pos.y + 0.5  # the panel ends above it
    assert (panel.content_size.x, panel.content_size.y) == content  # the panel's layout did not change
    out = capsys.readouterr().out
    assert out.count("particlesplat-viewer: saved 3 edit operation(s) to /somewhere/e.yaml and a second line\n") == 1
    app.fields.status = ""
    app.run(2)
    assert not find("##status").active


def test_panel_width_follows_a_drag_of_its_edge_and_is_remembered(app):
    """Dragging the panel's left edge 80 points to the left widens it by 80; the width is written to the settings
    file once the mouse is released, and the next viewer starts with it."""
    import glfw

    from viewer.settings import load_settings, settings_path

    app.state.panel = True
    glfw.set_window_size(app.window, 900, 400)
    app.run(3)
    panel = imgui.internal.find_window_by_name("ParticleSplat")
    x0, y, w0 = panel.pos.x, panel.pos.y + 0.5 * panel.size.y, panel.size.x
    assert w0 == pytest.approx(app.fields.panel_width)
    io = imgui.get_io()
    start = glfw.get_cursor_pos(app.window)
    x, y = int(round(x0)), int(round(y))
    _point_at(app, x, y)
    app.run(2)  # hovered: the edge's resize cursor
    io.add_mouse_button_event(0, True)
    app.run(1)
    for step in range(1, 9):
        io.add_mouse_pos_event(x - 10.0 * step, y)
        app.run(1)
    glfw.set_cursor_pos(app.window, x - 80.0, y)
    _wait_for_cursor(app.window, x - 80.0, y)
    io.add_mouse_button_event(0, False)
    app.run(2)
    try:
        assert app.fields.panel_width == pytest.approx(w0 + 80.0, abs=1.0)
        assert load_settings(settings_path()).panel_width == pytest.approx(w0 + 80.0, abs=1.0)
        assert str(settings_path()).startswith(os.environ["XDG_CONFIG_HOME"])
        cam = app.view_camera(1.0)
        assert cam.K[0, 2] < cam.width / 2 - 0.5 * (w0 + 80.0)  # the scene is framed in the narrower free part
    finally:
        io.add_mouse_button_event(0, False)
        glfw.set_window_size(app.window, 160, 120)
        app.fields.panel_width = app.settings.panel_width = w0
        glfw.set_cursor_pos(app.window, *start)
        app.run(2)


def test_a_drag_inside_the_panel_does_not_move_it(app):
    """A left drag that starts on the panel's empty space (not on a widget, not on its edge) leaves the panel where
    it is docked, and does not turn the view."""
    import glfw

    app.state.panel = True
    glfw.set_window_size(app.window, 900, 400)
    app.run(3)
    panel = imgui.internal.find_window_by_name("ParticleSplat")
    pos = (panel.pos.x, panel.pos.y)
    view = app.orbit.view
    io = imgui.get_io()
    start = glfw.get_cursor_pos(app.window)
    x, y = int(round(panel.pos.x + 0.5 * panel.size.x)), int(round(panel.pos.y + panel.size.y - 30.0))
    _point_at(app, x, y)  # near its bottom, away from its edges: no widget there
    try:
        io.add_mouse_button_event(0, True)
        app.run(1)
        for step in range(1, 9):
            io.add_mouse_pos_event(x - 20.0 * step, y - 10.0 * step)
            app.run(1)
        io.add_mouse_button_event(0, False)
        app.run(2)
        panel = imgui.internal.find_window_by_name("ParticleSplat")
        assert (panel.pos.x, panel.pos.y) == pos and app.orbit.view == view
    finally:
        io.add_mouse_button_event(0, False)
        glfw.set_window_size(app.window, 160, 120)
        glfw.set_cursor_pos(app.window, *start)
        app.run(2)


def test_switching_scenes_shows_its_progress_while_the_window_draws(app):
    """A scene picked in the panel opens on a thread: the loop goes on drawing, the status line says what is being
    done ("opening scene_00019: encoding ..."), then the scene is in place and the line says how long it took."""
    from particlesplat.editing.open_scene import demo_scenes

    scene = next(p for p in demo_scenes() if "robot" in str(p))
    app.req.open_path = str(scene)
    app.redraw.notify()
    lines, frames = set(), 0
    deadline = time.perf_counter() + 180.0
    while (app.opening is not None or not frames) and time.perf_counter() < deadline:
        n = len(app.frame_times)
        app.run(seconds=0.02)  # the interactive loop (the first frame's request starts the thread)
        frames += len(app.frame_times) - n
        lines.add(app.fields.status)
    assert app.opening is None and Path(app.session.source) == scene, app.fields.status
    progress = [line for line in lines if line.startswith(f"opening {scene.name}: ")]
    assert progress and all(line.endswith(" s)") for line in progress), lines
    assert frames > 1  # the window kept drawing while it loaded
    assert app.fields.status.startswith(f"opened {scene}") and app.fields.status.endswith(" s)")


def test_a_robot_scene_outlines_its_workspace_and_c_crops_to_it(window, tmp_path):
    """A robot demo scene opens with every Gaussian drawn and its workspace box outlined, not an edit, and exports
    only what is inside it (as ``particlesplat export``); C makes the box an edit: the view uploads only the
    Gaussians inside it (the panel's Crop box section drawn each frame), a screenshot's edit file carries it, Ctrl+Z
    draws everything again, and the box switched off exports everything."""
    from particlesplat.editing.open_scene import demo_scenes
    from viewer.tools.crop_box import shown_box

    app = _demo_app(window, tmp_path, next(p for p in demo_scenes() if "robot" in str(p)), size=(400, 300))
    try:
        s = app.session
        app.run(2)
        total = s.editor.decode().num
        assert app.scene_view.renderer.num == total and not s.editor.history.undo and not s.unsaved
        assert s.workspace is not None and shown_box(s) == (s.workspace, False)
        inside = int(s.workspace.inside(s.editor.decode().means).sum())
        # the export of a scene whose edits set no box: its workspace, as particlesplat export writes it
        app.fields.output_dir, app.fields.export_format = str(tmp_path), ".ply"
        drawn = app.scene_view.visible_gaussians(s, app.state)
        app.req.export_ply = True
        app.run(1)
        (ply,) = tmp_path.glob("particlesplat_*.ply")
        want = int(s.workspace.inside(drawn.means).sum())
        assert Gaussians.load_ply(ply).num == want < drawn.num and "the workspace box" in app.fields.status
        press(app, imgui.Key.c)
        assert shown_box(s) == (s.workspace, True) and app.fields.status.startswith("cropped to")
        assert 0 < inside < total and app.scene_view.renderer.num == inside
        app.fields.shot_size = [128, 96]
        assert "crop:" in Image.open(app.screenshot_numbered()).text["edits"]
        chord(app, "z")
        assert app.scene_view.renderer.num == total and app.fields.status.startswith("undid: crop to")
        chord(app, "z", shift=True)
        press(app, imgui.Key.c)  # switched off (crop: false): the export writes every Gaussian drawn
        app.req.export_ply = True
        app.run(1)
        last = sorted(tmp_path.glob("particlesplat_*.ply"))[-1]
        assert last != ply and Gaussians.load_ply(last).num == drawn.num, app.fields.status
    finally:
        app.scene_view.renderer.release()


def test_dragging_a_crop_box_handle_moves_its_face_in_one_step(window, tmp_path):
    """With the box on, a press on the handle of the box's +x face and a drag along x move that face only (no orbit,
    no pick), as one undo step; the view draws what lies inside the new box."""
    import glfw

    from particlesplat.editing.open_scene import demo_scenes
    from viewer.tools.crop_box import applied_box
    from viewer.tools.crop_handles import face_centres

    app = _demo_app(window, tmp_path, next(p for p in demo_scenes() if "robot" in str(p)), size=(400, 300))
    io = imgui.get_io()
    start = glfw.get_cursor_pos(app.window)
    try:
        s = app.session
        app.state.panel = False
        app.run(2)
        press(app, imgui.Key.c)
        box = applied_box(s)
        assert box is not None
        sx, sy = app.pixel_ratio()
        cam = app.view_camera(1.0).to("cpu", torch.float64)
        face = face_centres(box)[1]
        further = face + np.array([0.2, 0.0, 0.0])
        (u0, v0), (u1, v1) = cam.project(torch.tensor(np.stack([face, further]), dtype=torch.float64))[0]
        x0, y0 = float(u0) / sx, float(v0) / sy
        step = np.array([float(u1 - u0) / sx, float(v1 - v0) / sy])
        step *= 25.0 / np.linalg.norm(step)  # 25 window points along the x axis as seen
        view, undo = app.orbit.view, len(s.editor.history.undo)
        _point_at(app, round(x0), round(y0))
        io.add_mouse_button_event(0, True)
        app.run(1)
        for k in range(1, 6):
            x, y = round(x0 + step[0] * k / 5), round(y0 + step[1] * k / 5)
            glfw.set_cursor_pos(app.window, x, y)
            _wait_for_cursor(app.window, x, y)
            io.add_mouse_pos_event(x, y)
            app.redraw.notify()
            app.run(1)
        io.add_mouse_button_event(0, False)
        app.run(2)
        moved = applied_box(s)
        assert moved is not None and moved.hi[0] > box.hi[0] + 0.02, app.fields.status
        assert moved.lo == box.lo and moved.hi[1:] == box.hi[1:]
        assert len(s.editor.history.undo) == undo + 1 and app.orbit.view == view and app.state.selected is None
        assert app.scene_view.renderer.num == int(moved.inside(s.editor.decode().means).sum())
        assert app.fields.status.startswith("crop to")
    finally:
        io.add_mouse_button_event(0, False)
        app.run(1)
        glfw.set_cursor_pos(app.window, *start)
        app.scene_view.renderer.release()
