"""Driving the app in-process in its real window: keys and Ctrl chords as glfw reports them, the pointer put
where imgui sees it, apps on the bundled demo scenes, and screenshots read back."""

from __future__ import annotations

import time

import numpy as np
from imgui_bundle import imgui
from PIL import Image

from viewer import app as A
from viewer.launch import build_parser


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


def demo_app(window, tmp_path, scene, size=(160, 120)):
    import glfw

    win, ctx = window
    args = build_parser().parse_args(
        ["--scene", str(scene), "--context", "4,16", "--size", "x".join(map(str, size)), "--output-dir", str(tmp_path)]
    )
    session = A.load_session(args)
    glfw.set_window_size(win, *size)
    return A.App(win, session, A.initial_view(session, None, None), args, ctx=ctx)


def robot_app_selecting(window, tmp_path):
    """An app on the first robot demo scene in a 400x300 window, panel hidden, its most opaque particle's object
    selected: (app, that particle)."""
    import glfw

    from particlesplat.editing.open_scene import demo_scenes

    app = demo_app(window, tmp_path, next(p for p in demo_scenes() if "robot" in str(p)), size=(400, 300))
    deadline = time.monotonic() + 5.0
    while glfw.get_framebuffer_size(app.window) != (400, 300) and time.monotonic() < deadline:
        glfw.wait_events_timeout(0.05)
    g = app.session.editor.decode()
    index = int(g.owner[g.owner >= 0][g.opacities[g.owner >= 0].argmax()])
    app.state.selected, app.state.panel = index, False
    return app, index


def load_rgb(path) -> np.ndarray:
    return np.asarray(Image.open(path).convert("RGB"), np.float64) / 255.0


def wait_for_cursor(window, x: float, y: float, timeout: float = 2.0) -> None:
    """Wait until the X server reports the pointer at (x, y) after a warp."""
    import glfw

    deadline = time.perf_counter() + timeout
    while time.perf_counter() < deadline and glfw.get_cursor_pos(window) != (x, y):
        glfw.wait_events_timeout(0.01)


def point_at(app, x: int, y: int, timeout: float = 2.0) -> None:
    """Put the pointer on window point (x, y) and draw frames until imgui sees it there with no motion left
    over: the X server applies a warp asynchronously, and the glfw backend reads the pointer itself."""
    import glfw

    glfw.set_cursor_pos(app.window, x, y)
    wait_for_cursor(app.window, x, y)
    io = imgui.get_io()
    deadline = time.perf_counter() + timeout
    while time.perf_counter() < deadline and (
        (io.mouse_pos.x, io.mouse_pos.y) != (x, y) or (io.mouse_delta.x, io.mouse_delta.y) != (0.0, 0.0)
    ):
        io.add_mouse_pos_event(x, y)
        app.redraw.notify()
        app.run(1)
    assert (io.mouse_pos.x, io.mouse_pos.y) == (x, y), f"imgui does not see the pointer at {(x, y)} after {timeout} s"
