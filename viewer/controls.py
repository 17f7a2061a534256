"""Mouse and keyboard in the viewport: orbit, pan, zoom, picking, particle drags, shortcuts.

The controls change only what a :class:`Viewport` gives them: the orbit camera, the session (as do/undo
operations), the view state, the UI requests and the status line; they never draw and never see the app.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

from imgui_bundle import imgui

from particlesplat.editing.move import MoveError, stop_at_support

from .actions import ACTIONS
from .tools.object_tools import FloorDrag
from .tools.ruler import ruler_click

if TYPE_CHECKING:
    from torch import Tensor

    from particlesplat.core.camera import Camera
    from particlesplat.editing.editor import SceneEditor

    from .orbit import OrbitCamera
    from .session import Scene
    from .state import ViewState
    from .ui.panel import UiRequests


@dataclass
class Viewport:
    """What the controls work on in one frame (the app builds it; the controls never see the app).

    Attributes:
        orbit: the orbit camera; state: the view state; session: the scene (edits go through it).
        requests: the UI requests the app carries out after the frame (reset view, screenshot, save, snap).
        camera: the viewing camera at full scale (framebuffer pixels).
        pick: the owner (particle) under framebuffer pixel (x, y), -1 on background.
        status: shows a line in the panel's status line.
        pixel_ratio: framebuffer pixels per window coordinate (x, y).
        height: the framebuffer's height in pixels.
        copy_offset: (3,) metres between an object and its copy (Ctrl+D).
        gizmo_capturing: the object gizmo holds the mouse this frame.
        chords: the Ctrl chords pressed since the last frame, with their modifiers as the key events carried them
            (:class:`viewer.chords.ChordQueue`): ("z", shift held), ...
    """

    orbit: OrbitCamera
    state: ViewState
    session: Scene
    requests: UiRequests
    camera: Callable[[], Camera]
    pick: Callable[[int, int], int]
    status: Callable[[str], None]
    pixel_ratio: tuple[float, float] = (1.0, 1.0)
    height: int = 1
    copy_offset: Sequence[float] = (0.0, 0.0, 0.0)
    gizmo_capturing: bool = False
    chords: Sequence[tuple[str, bool]] = ()


CLICK_SLOP = 3.0  # window pixels a press may move and still count as a click


def inside_hull(hull, x: float, y: float) -> bool:
    """Whether (x, y) lies inside the convex polygon ``hull`` ((M, 2), counter-clockwise; M < 3: never)."""
    if len(hull) < 3:
        return False
    for (ax, ay), (bx, by) in zip(hull, list(hull[1:]) + [hull[0]], strict=True):
        if (bx - ax) * (y - ay) - (by - ay) * (x - ax) < 0:
            return False
    return True


ROBOT_CLICK = "that is the robot arm: part of the scene, not an object (it cannot be selected, moved or removed)"


def click_selection(session: Scene, owner: int, surface: Callable[[], Tensor | None]) -> tuple[int | None, str]:
    """What a click selects: the particle ``owner`` under it (-1: none) when it is in an object of an editable
    scene, else nothing. Returns (the selection, a status message: on the robot arm, that the arm is no object;
    else ""). ``surface``: the world point (3,) under the click, or None (asked only where nothing is selected)."""
    editor = session.editor
    if editor is None:
        return None, ""
    if owner >= 0 and int(session.objects()[owner]) >= 0:
        return owner, ""
    point = surface()
    return None, ROBOT_CLICK if point is not None and editor.on_robot(point) else ""


def _surface_at(vp: Viewport, x: float, y: float) -> Tensor | None:
    """The surface point under framebuffer pixel (x, y) of the viewing camera
    (:func:`viewer.tools.ruler.surface_point`)."""
    from .tools.ruler import surface_point

    g = vp.session.gaussians()
    return surface_point(g.subset(g.opacities >= vp.state.prune), vp.camera(), x, y)


def ui_takes_mouse(io) -> bool:
    """Whether the mouse is the panel's this frame: imgui wants it and a window is under it or a widget is held
    (not only because the gizmo, hovered the frame before, asked imgui for it: a Ctrl that came with the press
    greyed the gizmo out, and the press is the viewport's Ctrl + drag)."""
    ctx = imgui.get_current_context()
    return bool(io.want_capture_mouse) and (ctx.hovered_window is not None or ctx.active_id != 0)


class ViewportControls:
    """Gesture state of the viewport (press position, drag, the dragged particle's centre)."""

    def __init__(self) -> None:
        self.last_move = 0.0  # perf_counter time of the last camera or particle motion
        self.press_pos: tuple[float, float] | None = None
        self.dragged = False
        self.floor = FloorDrag()  # a plain drag that began on the selected object, or a Shift-drag

    def handle(self, vp: Viewport) -> None:
        """Read this frame's input from imgui (unless a panel wants it) and apply it."""
        io = imgui.get_io()
        sx, sy = vp.pixel_ratio
        if vp.state.selected is not None and vp.state.selected >= vp.session.num_owners():
            vp.state.selected = None  # an undone copy
        if not ui_takes_mouse(io) and not vp.gizmo_capturing:
            self._mouse(vp, io, sx, sy)
        if not io.want_capture_keyboard:
            self._keys(vp, io)

    def _mouse(self, vp: Viewport, io, sx: float, sy: float) -> None:
        now = time.perf_counter()
        dx, dy = io.mouse_delta.x * sx, io.mouse_delta.y * sy
        if io.mouse_wheel:
            vp.orbit.zoom(io.mouse_wheel)
            self.last_move = now
        if imgui.is_mouse_clicked(imgui.MouseButton_.left):
            self.press_pos = (io.mouse_pos.x, io.mouse_pos.y)
            self.dragged = False
        left_held = imgui.is_mouse_down(imgui.MouseButton_.left) or imgui.is_mouse_released(imgui.MouseButton_.left)
        if left_held and self.press_pos is not None and (dx or dy):  # the motion that came with a release counts
            px, py = self.press_pos
            if abs(io.mouse_pos.x - px) + abs(io.mouse_pos.y - py) > CLICK_SLOP and not self.dragged:
                self.dragged = True
                self._begin_drag(vp, io, px * sx, py * sy)
            if self.dragged:
                sel, editor = vp.state.selected, vp.session.editor
                if self.floor.active and editor is not None:
                    message = self.floor.update(editor, vp.camera(), io.mouse_pos.x * sx, io.mouse_pos.y * sy)
                    if message:
                        vp.status(message)
                elif io.key_ctrl and sel is not None and editor is not None:
                    self.lift_object(vp, editor, sel, dy)
                else:
                    vp.orbit.orbit(dx, dy)
                self.last_move = now
        if imgui.is_mouse_released(imgui.MouseButton_.left) and self.press_pos is not None:
            if not self.dragged:
                self.pick(vp, io.mouse_pos.x * sx, io.mouse_pos.y * sy)
            landed = self.floor.stop(vp.session.editor)
            if landed:
                vp.status(landed)
            if vp.session.editor is not None:
                vp.session.editor.end_gesture()
            self.press_pos = None
        for button in (imgui.MouseButton_.right, imgui.MouseButton_.middle):
            if imgui.is_mouse_dragging(button) and (dx or dy):
                vp.orbit.pan(dx, dy, vp.height)
                self.last_move = now

    def _begin_drag(self, vp: Viewport, io, x: float, y: float) -> None:
        """A left drag starts at framebuffer pixel (x, y): it slides the selected object on the floor when it
        began on that object (or with Shift held), else it orbits (Ctrl: lifts the object)."""
        sel, editor = vp.state.selected, vp.session.editor
        if sel is None or editor is None or io.key_ctrl:
            return
        on_object = False
        if not io.key_shift:  # on the selected object: inside its outline, even where another object is in front
            from .tools.object_tools import outline

            owner = vp.pick(int(x), int(y))
            labels = vp.session.objects()
            on_object = (owner >= 0 and int(labels[owner]) == int(labels[sel])) or inside_hull(
                outline(editor, sel, vp.camera()), x, y
            )
        if (io.key_shift or on_object) and not self.floor.start(editor, sel, vp.camera(), x, y):
            vp.status("this object cannot slide from here (it draws nothing, or the floor is out of view)")

    def lift_object(self, vp: Viewport, editor: SceneEditor, index: int, dy: float) -> None:
        """Move the object of particle ``index`` up or down (world Z) with a vertical drag of ``dy``
        framebuffer pixels (up = up), by the metres a pixel spans at the object's depth; it stops at the
        surface it rests on (:func:`particlesplat.editing.move.stop_at_support`)."""
        from .tools.object_tools import object_centre

        centre = object_centre(editor, index)
        if centre is None:
            return
        cam = vp.camera()
        depth = float(cam.world_to_camera(centre[None].to(cam.K.dtype))[0, 2].clamp_min(1e-3))
        dz = -dy * depth / float(cam.fy)
        bottom = editor.object_bottom(index)
        if bottom is not None:
            dz = stop_at_support(dz, bottom, editor.support_height(index))
        if dz == 0.0:
            if dy > 0:
                vp.status("the object rests on the surface: it goes no lower")
            return
        try:
            editor.move_object(index, [0.0, 0.0, dz], gesture="lift-drag")
        except MoveError as e:
            vp.status(f"error: {e}")

    @staticmethod
    def pick(vp: Viewport, x: float, y: float) -> None:
        """Select the particle owning framebuffer pixel (x, y) (nothing on background); with the ruler on, pick a
        ruler point there instead."""
        if vp.state.ruler:
            g = vp.session.gaussians()
            vp.status(ruler_click(vp.state, g.subset(g.opacities >= vp.state.prune), vp.camera(), x, y))
            return
        owner = vp.pick(int(x), int(y))
        selected, message = click_selection(vp.session, owner, lambda: _surface_at(vp, x, y))
        vp.state.selected = selected
        if message:
            vp.status(message)

    @staticmethod
    def _keys(vp: Viewport, io) -> None:
        """Run the actions whose keys were pressed (:data:`viewer.actions.ACTIONS`): a Ctrl chord as its key event
        carried it (``vp.chords``: Ctrl and Shift as they were when the key went down, :mod:`viewer.chords`), a
        plain key without Ctrl."""
        for key, shift in vp.chords:
            for action in ACTIONS:
                if any(c.ctrl and c.key == key and c.shift == shift for c in action.keys):
                    if action.enabled(vp):
                        action.run(vp)
                    break
        if io.key_ctrl or vp.chords:
            return
        for action in ACTIONS:
            for chord in action.keys:
                if chord.ctrl:
                    continue
                if imgui.is_key_pressed(getattr(imgui.Key, chord.key), action.repeat):
                    if action.enabled(vp):
                        action.run(vp)
                    break
