"""Mouse and keyboard in the viewport: orbit, pan, zoom, picking, particle drags, shortcuts.

The controls change only the orbit camera, the session (as do/undo operations), the view state
and the UI requests of the app; they never draw.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Protocol

from imgui_bundle import imgui

from particlesplat.editing.move import MoveError

from .panels.objects import duplicate_selected, remove_selected
from .state import SEG_MODES
from .tools.object_tools import FloorDrag

if TYPE_CHECKING:
    from particlesplat.core.camera import Camera

    from .orbit import OrbitCamera
    from .panel import UiFields, UiRequests
    from .scene_view import SceneView
    from .session import SceneSession
    from .state import ViewState
    from .tools.object_tools import ObjectGizmo


class ViewportHost(Protocol):
    """What the controls use of the app (the app is one; the controls never import it)."""

    orbit: OrbitCamera
    state: ViewState
    session: SceneSession
    scene_view: SceneView
    fields: UiFields
    req: UiRequests
    gizmo: ObjectGizmo

    def pixel_ratio(self) -> tuple[float, float]: ...

    def framebuffer_size(self) -> tuple[int, int]: ...

    def view_camera(self, scale: float = 1.0, clear_panel: bool = True) -> Camera: ...


CLICK_SLOP = 3.0  # window pixels a press may move and still count as a click


def inside_hull(hull, x: float, y: float) -> bool:
    """Whether (x, y) lies inside the convex polygon ``hull`` ((M, 2), counter-clockwise; M < 3: never)."""
    if len(hull) < 3:
        return False
    for (ax, ay), (bx, by) in zip(hull, list(hull[1:]) + [hull[0]], strict=True):
        if (bx - ax) * (y - ay) - (by - ay) * (x - ax) < 0:
            return False
    return True


class ViewportControls:
    """Gesture state of the viewport (press position, drag, the dragged particle's centre)."""

    def __init__(self) -> None:
        self.last_move = 0.0  # perf_counter time of the last camera or particle motion
        self.press_pos: tuple[float, float] | None = None
        self.dragged = False
        self.floor = FloorDrag()  # a plain drag that began on the selected object, or a Shift-drag

    def handle(self, app: ViewportHost) -> None:
        """Read this frame's input from imgui (unless a panel wants it) and apply it."""
        io = imgui.get_io()
        sx, sy = app.pixel_ratio()
        if app.state.selected is not None and app.state.selected >= app.session.num_owners():
            app.state.selected = None  # an undone copy
        if not io.want_capture_mouse and not app.gizmo.capturing:
            self._mouse(app, io, sx, sy)
        if not io.want_capture_keyboard:
            self._keys(app, io)

    def _mouse(self, app: ViewportHost, io, sx: float, sy: float) -> None:
        now = time.perf_counter()
        dx, dy = io.mouse_delta.x * sx, io.mouse_delta.y * sy
        if io.mouse_wheel:
            app.orbit.zoom(io.mouse_wheel)
            self.last_move = now
        if imgui.is_mouse_clicked(imgui.MouseButton_.left):
            self.press_pos = (io.mouse_pos.x, io.mouse_pos.y)
            self.dragged = False
        left_held = imgui.is_mouse_down(imgui.MouseButton_.left) or imgui.is_mouse_released(imgui.MouseButton_.left)
        if left_held and self.press_pos is not None and (dx or dy):  # the motion that came with a release counts
            px, py = self.press_pos
            if abs(io.mouse_pos.x - px) + abs(io.mouse_pos.y - py) > CLICK_SLOP and not self.dragged:
                self.dragged = True
                self._begin_drag(app, io, px * sx, py * sy)
            if self.dragged:
                sel = app.state.selected
                if self.floor.active:
                    message = self.floor.update(
                        app.session, app.view_camera(1.0), io.mouse_pos.x * sx, io.mouse_pos.y * sy
                    )
                    if message:
                        app.fields.status = message
                elif io.key_ctrl and sel is not None and app.session.editable:
                    self.lift_object(app, sel, dy)
                else:
                    app.orbit.orbit(dx, dy)
                self.last_move = now
        if imgui.is_mouse_released(imgui.MouseButton_.left) and self.press_pos is not None:
            if not self.dragged:
                self.pick(app, io.mouse_pos.x * sx, io.mouse_pos.y * sy)
            self.floor.stop()
            app.session.end_gesture()
            self.press_pos = None
        for button in (imgui.MouseButton_.right, imgui.MouseButton_.middle):
            if imgui.is_mouse_dragging(button) and (dx or dy):
                app.orbit.pan(dx, dy, app.framebuffer_size()[1])
                self.last_move = now

    def _begin_drag(self, app: ViewportHost, io, x: float, y: float) -> None:
        """A left drag starts at framebuffer pixel (x, y): it slides the selected object on the floor when it
        began on that object (or with Shift held), else it orbits (Ctrl: lifts the object)."""
        sel = app.state.selected
        if sel is None or not app.session.editable or io.key_ctrl:
            return
        on_object = False
        if not io.key_shift:  # on the selected object: inside its outline, even where another object is in front
            from .tools.object_tools import outline

            owner = app.scene_view.pick(app.session, app.view_camera(1.0), int(x), int(y))
            labels = app.session.objects()
            on_object = (owner >= 0 and int(labels[owner]) == int(labels[sel])) or inside_hull(
                outline(app.session, sel, app.view_camera(1.0)), x, y
            )
        if (io.key_shift or on_object) and not self.floor.start(app.session, sel, app.view_camera(1.0), x, y):
            app.fields.status = "this object cannot slide from here (it draws nothing, or the floor is out of view)"

    def lift_object(self, app: ViewportHost, index: int, dy: float) -> None:
        """Move the object of particle ``index`` up or down (world Z) with a vertical drag of ``dy``
        framebuffer pixels (up = up), by the metres a pixel spans at the object's depth."""
        from .tools.object_tools import object_centre

        centre = object_centre(app.session, index)
        if centre is None:
            return
        cam = app.view_camera(1.0)
        depth = float(cam.world_to_camera(centre[None].to(cam.K.dtype))[0, 2].clamp_min(1e-3))
        try:
            app.session.move_object(index, [0.0, 0.0, -dy * depth / float(cam.fy)], gesture="lift-drag")
        except MoveError as e:
            app.fields.status = f"error: {e}"

    @staticmethod
    def pick(app: ViewportHost, x: float, y: float) -> None:
        """Select the particle owning framebuffer pixel (x, y) (nothing on background)."""
        owner = app.scene_view.pick(app.session, app.view_camera(1.0), int(x), int(y))
        app.state.selected = owner if owner >= 0 and app.session.editable else None

    @staticmethod
    def _keys(app: ViewportHost, io) -> None:
        K = imgui.Key
        if io.key_ctrl:
            if imgui.is_key_pressed(K.z):
                (app.session.redo if io.key_shift else app.session.undo)()
            elif imgui.is_key_pressed(K.y):
                app.session.redo()
            elif imgui.is_key_pressed(K.s, False) and app.session.editable:
                app.req.save_edits = True
            elif imgui.is_key_pressed(K.d, False) and app.session.editable:
                app.state.selected, app.fields.status = duplicate_selected(
                    app.session, app.state.selected, app.fields.objects.copy_offset
                )
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
        if pressed(K.delete) and app.session.editable:
            app.state.selected, app.fields.status = remove_selected(app.session, app.state.selected)
        for i, key in enumerate((K._0, K._1, K._2, K._3, K._4, K._5, K._6, K._7, K._8, K._9)):
            if pressed(key):
                app.req.snap_camera = i  # 0-based, as --context, render --view and an edit file's pick.frame
