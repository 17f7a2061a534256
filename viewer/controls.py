"""Mouse and keyboard in the viewport: orbit, pan, zoom, picking, particle drags, shortcuts.

The controls change only the orbit camera, the session (as do/undo operations), the view state
and the UI requests of the app; they never draw.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

import torch
from imgui_bundle import imgui

from particlesplat.move import MoveError

from .state import SEG_MODES

if TYPE_CHECKING:
    from .app import App

CLICK_SLOP = 3.0  # window pixels a press may move and still count as a click
DEPTH_PER_PX = 0.01  # z_d logit change per framebuffer pixel of vertical Ctrl-drag


class ViewportControls:
    """Gesture state of the viewport (press position, drag, the dragged particle's centre)."""

    def __init__(self) -> None:
        self.last_move = 0.0  # perf_counter time of the last camera or particle motion
        self.press_pos: tuple[float, float] | None = None
        self.dragged = False
        self.particle_center: torch.Tensor | None = None

    def handle(self, app: App) -> None:
        """Read this frame's input from imgui (unless a panel wants it) and apply it."""
        io = imgui.get_io()
        sx, sy = app.pixel_ratio()
        if not io.want_capture_mouse:
            self._mouse(app, io, sx, sy)
        if not io.want_capture_keyboard:
            self._keys(app, io)

    def _mouse(self, app: App, io, sx: float, sy: float) -> None:
        now = time.perf_counter()
        dx, dy = io.mouse_delta.x * sx, io.mouse_delta.y * sy
        if io.mouse_wheel:
            app.orbit.zoom(io.mouse_wheel)
            self.last_move = now
        if imgui.is_mouse_clicked(imgui.MouseButton_.left):
            self.press_pos = (io.mouse_pos.x, io.mouse_pos.y)
            self.dragged = False
            self.particle_center = None
        if imgui.is_mouse_down(imgui.MouseButton_.left) and self.press_pos is not None and (dx or dy):
            px, py = self.press_pos
            if abs(io.mouse_pos.x - px) + abs(io.mouse_pos.y - py) > CLICK_SLOP:
                self.dragged = True
            if self.dragged:
                sel = app.state.selected
                if io.key_shift and sel is not None and app.session.editable:
                    self.drag_object(app, sel, dx, dy)
                elif io.key_ctrl and sel is not None and app.session.editable:
                    z_d = app.session.value(sel, "z_d")[0] - dy * DEPTH_PER_PX
                    app.session.set_attribute(sel, "z_d", [z_d], gesture="depth-drag")
                else:
                    app.orbit.orbit(dx, dy)
                self.last_move = now
        if imgui.is_mouse_released(imgui.MouseButton_.left) and self.press_pos is not None:
            if not self.dragged:
                self.pick(app, io.mouse_pos.x * sx, io.mouse_pos.y * sy)
            app.session.end_gesture()
            self.press_pos = None
        for button in (imgui.MouseButton_.right, imgui.MouseButton_.middle):
            if imgui.is_mouse_dragging(button) and (dx or dy):
                app.orbit.pan(dx, dy, app.framebuffer_size()[1])
                self.last_move = now

    @staticmethod
    def pick(app: App, x: float, y: float) -> None:
        """Select the particle owning framebuffer pixel (x, y) (nothing on background)."""
        owner = app.scene_view.pick(app.session, app.view_camera(1.0), int(x), int(y))
        app.state.selected = owner if owner >= 0 and app.session.editable else None

    def drag_object(self, app: App, index: int, dx: float, dy: float) -> None:
        """Move the object of particle ``index`` (every particle of it, :meth:`SceneSession.move_object`)
        so it follows a screen drag of (dx, dy) framebuffer pixels: the world motion parallel to the
        viewing camera's image plane at the particle's depth. A move out of the model's depth range is
        refused (the status line says why)."""
        session = app.session
        if self.particle_center is None:
            g = session.particle_gaussians(index)
            w = g.opacities.clamp_min(1e-6)
            self.particle_center = (g.means * w[:, None]).sum(0) / w.sum()
        view_cam = app.orbit.camera(*app.framebuffer_size())
        R = view_cam.c2w[:3, :3]
        depth = float(view_cam.world_to_camera(self.particle_center[None].float())[0, 2].clamp_min(1e-3))
        delta = (R[:, 0] * dx + R[:, 1] * dy) * depth / float(view_cam.fy)
        try:
            session.move_object(index, delta.tolist(), gesture="object-drag")
        except MoveError as e:
            app.fields.status = f"error: {e}"
            return
        self.particle_center = self.particle_center + delta

    @staticmethod
    def _keys(app: App, io) -> None:
        K = imgui.Key
        if io.key_ctrl:
            if imgui.is_key_pressed(K.z):
                (app.session.redo if io.key_shift else app.session.undo)()
            elif imgui.is_key_pressed(K.y):
                app.session.redo()
            elif imgui.is_key_pressed(K.s, False) and app.session.editable:
                app.req.save_edits = True
            return
        pressed = lambda key: imgui.is_key_pressed(key, False)  # noqa: E731
        if pressed(K.r):
            app.req.reset_view = True
        if pressed(K.p) or pressed(K.f12):
            app.req.screenshot = True
        if pressed(K.e):
            app.req.export_ply = True
        if pressed(K.h):
            app.state.panel = not app.state.panel
        if pressed(K.o):
            app.state.overlay = not app.state.overlay
        if pressed(K.m):
            app.state.seg_mode = SEG_MODES[(SEG_MODES.index(app.state.seg_mode) + 1) % len(SEG_MODES)]
        if pressed(K.escape):
            app.state.selected = None
        for i, key in enumerate((K._1, K._2, K._3, K._4, K._5, K._6, K._7, K._8, K._9)):
            if pressed(key):
                app.req.snap_camera = i
