"""Edits in the app in its real window (CI runs pytest under xvfb-run): the object gizmo's keys and handles, the
autosave a signal triggers, a screenshot's edit file replayed by ``render``, edits saved per scene, the robot
workspace's crop box. The window is conftest.py's, one for the session."""

from __future__ import annotations

import os
import time

import numpy as np
import pytest
import torch
from imgui_bundle import imgui
from PIL import Image
from viewer_helpers import psnr, small_model
from window_driver import chord, demo_app, load_rgb, point_at, press, robot_app_selecting, wait_for_cursor

from particlesplat import render
from particlesplat.core.gaussians import Gaussians
from particlesplat.core.userdirs import autosave_dir
from particlesplat.model import save_checkpoint
from viewer import app as A
from viewer.launch import build_parser

pytestmark = pytest.mark.window


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
        point_at(app, u, v)
        io.add_mouse_button_event(0, True)
        app.run(1)
        for k in range(1, 6):
            point_at(app, u + 4 * k, v + k)
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


def test_the_gizmo_centre_handle_slides_a_robot_object_on_its_plane(window, tmp_path):
    """On a robot demo scene at its default view, a drag that grabs the gizmo's centre handle (which covers a
    robot-sized object whole) slides the object on the horizontal plane: one translate, no height change, nothing
    below the table."""
    from viewer.tools.object_tools import object_centre

    app, index = robot_app_selecting(window, tmp_path)
    ed, io = app.session.editor, imgui.get_io()
    try:
        app.run(2)
        uv, _ = app.view_camera(1.0).project(object_centre(ed, index)[None].float())
        sx, sy = app.pixel_ratio()
        u, v = round(float(uv[0, 0]) / sx), round(float(uv[0, 1]) / sy)
        n_ops = len(ed.history.undo)
        point_at(app, u, v)
        io.add_mouse_button_event(0, True)
        app.run(1)
        for k in range(1, 6):
            point_at(app, u + 5 * k, v + 2 * k)
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

    app, index = robot_app_selecting(window, tmp_path)
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
                point_at(app, u, v)
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
            point_at(app, round(u + 6 * k * d[0]), round(v + 6 * k * d[1]))
        io.add_mouse_button_event(0, False)
        app.run(1)
        assert len(ed.history.undo) == n_ops + 1 and ed.history.undo[-1].kind == "scale", app.fields.status
        assert ed.history.undo[-1].factor != pytest.approx(1.0) and not ed.sunk_objects()
    finally:
        io.add_mouse_button_event(0, False)
        app.state.gizmo_scale = False
        app.run(1)
        app.scene_view.renderer.release()


def test_a_screenshot_carries_its_edit_file_and_render_replays_it(window, tmp_path):
    """After a move, a delete, a duplicate and an insert, the screenshot's 'edits' chunk is the whole version 2
    edit file: `particlesplat render --camera-from shot.png --edits-from shot.png` reproduces the screenshot."""
    from particlesplat.cli.main import main as cli_main
    from particlesplat.editing.open_scene import demo_scenes

    scene = demo_scenes()[0]
    app = demo_app(window, tmp_path, scene)
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
        assert psnr(load_rgb(shot), load_rgb(out)) >= 40.0
        # the edits are what makes it match: the scene without them does not
        base = ["render", "--scene", str(scene), "--context", "4,16", "--camera-from", str(shot), *prune]
        assert cli_main([*base, "--out", str(plain)]) == 0
        assert psnr(load_rgb(shot), load_rgb(plain)) < 35.0
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
    app = demo_app(window, out, a_dir)
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


def test_a_robot_scene_outlines_its_workspace_and_c_crops_to_it(window, tmp_path):
    """A robot demo scene opens with every Gaussian drawn and its workspace box outlined, not an edit, and exports
    only what is inside it (as ``particlesplat export``); C makes the box an edit: the view uploads only the
    Gaussians inside it (the panel's Crop box section drawn each frame), a screenshot's edit file carries it, Ctrl+Z
    draws everything again, and the box switched off exports everything."""
    from particlesplat.editing.open_scene import demo_scenes
    from viewer.tools.crop_box import shown_box

    app = demo_app(window, tmp_path, next(p for p in demo_scenes() if "robot" in str(p)), size=(400, 300))
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

    app = demo_app(window, tmp_path, next(p for p in demo_scenes() if "robot" in str(p)), size=(400, 300))
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
        point_at(app, round(x0), round(y0))
        io.add_mouse_button_event(0, True)
        app.run(1)
        for k in range(1, 6):
            x, y = round(x0 + step[0] * k / 5), round(y0 + step[1] * k / 5)
            glfw.set_cursor_pos(app.window, x, y)
            wait_for_cursor(app.window, x, y)
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
