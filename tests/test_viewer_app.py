"""The app in-process in a real window (CI runs pytest under xvfb-run): picking, dragging a particle, undo,
screenshot and .ply export requests, opening another scene, the idle loop, the panel and the status line; once
per compositing path (``--compositing``, see conftest.py). The window is conftest.py's, one for the session."""

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
from window_driver import chord, point_at, press, wait_for_cursor

from particlesplat import render
from particlesplat.core.gaussians import Gaussians
from particlesplat.core.userdirs import autosave_dir
from particlesplat.model import save_checkpoint
from viewer import app as A
from viewer.bench.random_gaussians import random_gaussians
from viewer.launch import build_parser

pytestmark = pytest.mark.window


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
    point_at(app, x, y)
    try:
        io.add_mouse_button_event(0, True)
        app.run(1)
        view0 = app.orbit.view
        for k in range(1, 11):
            io.add_mouse_pos_event(x + 3.0 * k, y)
        glfw.set_cursor_pos(app.window, x + 30.0, y)
        wait_for_cursor(app.window, x + 30.0, y)
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
    point_at(app, x, y)
    app.run(2)  # hovered: the edge's resize cursor
    io.add_mouse_button_event(0, True)
    app.run(1)
    for step in range(1, 9):
        io.add_mouse_pos_event(x - 10.0 * step, y)
        app.run(1)
    glfw.set_cursor_pos(app.window, x - 80.0, y)
    wait_for_cursor(app.window, x - 80.0, y)
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
    point_at(app, x, y)  # near its bottom, away from its edges: no widget there
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
