"""Moving a selected object in the world: slide it on the floor with the mouse, a world-space gizmo
(ImGuizmo) with X / Y / Z handles at its centre, and an outline of it in the viewport.

Tools get narrow dependencies: the scene's editor (a :class:`particlesplat.editing.editor.SceneEditor`), the
selected particle and the viewing camera; they never see the App. Every move is a do/undo operation of the editor
(one per drag, by its gesture id).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import torch
from torch import Tensor

from particlesplat.core.camera import Camera
from particlesplat.editing.move import MoveError, stop_at_support

if TYPE_CHECKING:
    from particlesplat.editing.editor import SceneEditor

    from ..session import Scene

FLOOR_GESTURE = "floor-drag"
GIZMO_GESTURE = "gizmo"
SCALE_GESTURE = "gizmo-scale"
MAX_STEP = 0.5  # metres one mouse event may slide an object (a ray grazing the plane goes far)
OUTLINE_OPACITY = 0.1  # Gaussians at least this opaque outline the selected object
GL_FLIP = np.diag([1.0, -1.0, -1.0, 1.0])  # OpenCV camera axes -> OpenGL (y up, looking down -z)


def object_centre(editor: SceneEditor, index: int) -> Tensor | None:
    """(3,) float64 world metres: the centre of particle ``index``'s object as drawn now (the resting centre,
    :meth:`particlesplat.editing.editor.SceneEditor.object_centre`), or None if it draws nothing."""
    return editor.object_centre(index)


def floor_point(camera: Camera, x: float, y: float, height: float) -> Tensor | None:
    """(3,) float64: where the ray through framebuffer pixel (x, y) (pixel centres at +0.5) meets the
    horizontal plane z = ``height`` in front of the camera, or None (parallel, or behind)."""
    K = camera.K.detach().double().cpu()
    c2w = camera.c2w.detach().double().cpu()
    d_cam = torch.linalg.solve(K, torch.tensor([x, y, 1.0], dtype=torch.float64))
    d = c2w[:3, :3] @ d_cam
    o = c2w[:3, 3]
    if abs(float(d[2])) < 1e-9:
        return None
    t = (height - float(o[2])) / float(d[2])
    return o + t * d if t > 0 else None


class FloorDrag:
    """Slides the selected object on the horizontal plane through its centre, following the mouse; where it is let
    go, it lands on the surface under it (the table, or the floor past its edge) at the free spot nearest, clear of
    the other objects (:meth:`SceneEditor.place_object`).

    :meth:`start` at the press, :meth:`update` per mouse event, :meth:`stop` and the editor's ``end_gesture`` at
    release (one undo step per drag, its landing included)."""

    def __init__(self) -> None:
        self.index: int | None = None
        self.height = 0.0
        self.last: Tensor | None = None
        self.resting = True  # the object rested on its surface when the drag began
        self.moved = False

    @property
    def active(self) -> bool:
        return self.index is not None

    def start(self, editor: SceneEditor, index: int, camera: Camera, x: float, y: float) -> bool:
        """Begin sliding particle ``index``'s object from framebuffer pixel (x, y); False if it draws nothing
        or the pixel's ray misses its plane."""
        centre = object_centre(editor, index)
        if centre is None:
            return False
        self.height = float(centre[2])
        self.last = floor_point(camera, x, y, self.height)
        self.index = index if self.last is not None else None
        self.resting = editor.scene.resting(editor.object_members(index))
        self.moved = False
        return self.active

    def update(self, editor: SceneEditor, camera: Camera, x: float, y: float) -> str | None:
        """Move the object so the plane point under the mouse stays under it; an error message if the
        move was refused (nothing moved), else None."""
        if self.index is None or self.last is None:
            return None
        p = floor_point(camera, x, y, self.height)
        if p is None:
            return None
        delta = p - self.last
        delta[2] = 0.0
        step = float(delta.norm())
        if step > MAX_STEP:
            delta = delta * (MAX_STEP / step)
        try:
            editor.move_object(self.index, delta.tolist(), gesture=FLOOR_GESTURE)
        except MoveError as e:
            return f"error: {e}"
        self.last = self.last + delta
        self.moved = self.moved or step > 0.0
        return None

    def stop(self, editor: SceneEditor | None = None) -> str | None:
        """The drag ends: with ``editor``, a moved object lands where it was let go (a step of the drag's gesture,
        :meth:`SceneEditor.place_object`). Returns what the landing says ("" or None: nothing to say)."""
        index, moved, self.index, self.last, self.moved = self.index, self.moved, None, None, False
        if editor is None or index is None or not moved:
            return None
        try:
            return editor.place_object(index, self.resting, gesture=FLOOR_GESTURE) or None
        except MoveError as e:
            return f"error: {e}"


class GizmoDrag:
    """One drag of the gizmo's handles, as moves that respect the surface the object rests on.

    An arrow or plane handle moves the object along its axes, but never lower than its support
    (:func:`particlesplat.editing.move.stop_at_support`). The centre handle (which ImGuizmo moves in the screen
    plane, and which covers a small object whole) slides the object on the horizontal plane through its centre,
    following the mouse as a plain drag does (:class:`FloorDrag`). Which handle it is, is read from the first step:
    the centre handle's moves all three coordinates at once, an arrow one, a plane two.
    """

    def __init__(self) -> None:
        self.mode: str | None = None  # None before the first step, then "axes" or "floor"
        self.floor = FloorDrag()
        self.scaled = 1.0  # the scale handles' factor so far in this drag
        self.index: int | None = None  # the object an axes drag moved
        self.resting = True  # it rested on its surface when the drag began
        self.slid = False  # an axes drag moved it along x or y

    def scale(self, editor: SceneEditor, index: int, total: float) -> str | None:
        """The scale handles show ``total`` (the factor since the drag began): scale the object by what it adds
        (about its resting centre, on its support; one operation per drag). An error message if refused."""
        step = total / self.scaled
        if not (np.isfinite(step) and step > 0.0) or abs(step - 1.0) < 1e-6:
            return None
        try:
            editor.scale_object(index, step, gesture=SCALE_GESTURE)
        except MoveError as e:
            return f"error: {e}"
        self.scaled = total
        return None

    def step(
        self,
        editor: SceneEditor,
        index: int,
        step: np.ndarray,
        camera: Camera,
        mouse: tuple[float, float],
        previous: tuple[float, float],
    ) -> str | None:
        """Apply one gizmo step (3,) world metres, with the mouse at framebuffer pixel ``mouse`` (at ``previous``
        the frame before). Returns an error message when a move was refused, else None."""
        if self.mode is None:
            self.mode = "floor" if int(np.count_nonzero(np.abs(step) > 1e-9)) == 3 else "axes"
            if self.mode == "floor" and not self.floor.start(editor, index, camera, *previous):
                self.mode = "axes"
            self.index, self.slid = index, False
            self.resting = editor.scene.resting(editor.object_members(index))
        if self.mode == "floor":
            return self.floor.update(editor, camera, *mouse)
        step = np.asarray(step, dtype=np.float64).copy()
        self.slid = self.slid or bool(np.any(np.abs(step[:2]) > 1e-9))
        if step[2] < 0.0:
            bottom = editor.object_bottom(index)
            if bottom is not None:
                step[2] = stop_at_support(float(step[2]), bottom, editor.support_height(index))
        if not np.any(step):
            return None
        try:
            editor.move_object(index, step.tolist(), gesture=GIZMO_GESTURE)
        except MoveError as e:
            return f"error: {e}"
        return None

    def stop(self, editor: SceneEditor) -> str | None:
        """The drag ends: an object slid (the centre handle, or an arrow or plane along x or y) lands on the surface
        under it, clear of the others (:meth:`SceneEditor.place_object`; a lift along z alone stays where it was
        lifted); one operation in the history. Returns what the landing says, or None."""
        note = self.floor.stop(editor) if self.mode == "floor" else None
        if self.mode == "axes" and self.slid and self.index is not None:
            try:
                note = editor.place_object(self.index, self.resting, gesture=GIZMO_GESTURE) or None
            except MoveError as e:
                note = f"error: {e}"
        editor.end_gesture()
        self.mode, self.scaled, self.index, self.slid = None, 1.0, None, False
        return note


def gl_view(camera: Camera) -> np.ndarray:
    """(4, 4) float64 OpenGL view matrix (world -> eye, y up, looking down -z) of an OpenCV camera."""
    return GL_FLIP @ camera.w2c.detach().double().cpu().numpy()


def gl_projection(camera: Camera, near: float = 0.01, far: float = 100.0) -> np.ndarray:
    """(4, 4) float64 OpenGL projection of the camera's intrinsics (pixel (0, 0) at the top left)."""
    K = camera.K.detach().double().cpu().numpy()
    W, H = camera.width, camera.height
    P = np.zeros((4, 4))
    P[0, 0], P[0, 2] = 2.0 * K[0, 0] / W, 1.0 - 2.0 * K[0, 2] / W
    P[1, 1], P[1, 2] = 2.0 * K[1, 1] / H, 2.0 * K[1, 2] / H - 1.0
    P[2, 2], P[2, 3] = -(far + near) / (far - near), -2.0 * far * near / (far - near)
    P[3, 2] = -1.0
    return P


def outline(editor: SceneEditor, index: int, camera: Camera) -> np.ndarray:
    """(M, 2) framebuffer pixels: the convex hull of the projected centres of the selected object's
    Gaussians (opacity >= OUTLINE_OPACITY), counter-clockwise; empty if fewer than 3."""
    members = editor.object_members(index)
    g = editor.model.decode(editor.particles, torch.tensor(members), background=False)
    g = g.subset(g.opacities >= OUTLINE_OPACITY)
    if g.num < 3:
        return np.zeros((0, 2))
    uv, z = camera.project(g.means.detach().to(camera.K.dtype).cpu())
    pts = uv[z > 0].double().numpy()
    return convex_hull(pts) if len(pts) >= 3 else np.zeros((0, 2))


def convex_hull(points: np.ndarray) -> np.ndarray:
    """(M, 2) hull vertices of (N, 2) points, counter-clockwise (Andrew's monotone chain)."""
    pts = np.unique(points, axis=0)
    if len(pts) < 3:
        return pts

    def cross(o, a, b) -> float:
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    lower: list = []
    for p in pts:
        while len(lower) >= 2 and cross(lower[-2], lower[-1], p) <= 0:
            lower.pop()
        lower.append(p)
    upper: list = []
    for p in pts[::-1]:
        while len(upper) >= 2 and cross(upper[-2], upper[-1], p) <= 0:
            upper.pop()
        upper.append(p)
    return np.array(lower[:-1] + upper[:-1])


class ObjectGizmo:
    """ImGuizmo translate handles (world X / Y / Z, and the planes between them) at the selected object's
    centre, plus its outline. Call :meth:`draw` once a frame after ``imgui.new_frame``."""

    def __init__(self) -> None:
        self._key: tuple | None = None
        self._centre: Tensor | None = None
        self._hull = np.zeros((0, 2))
        self.using = False  # a handle is being dragged
        self.hovered = False  # the mouse is over a handle: the viewport should not orbit
        self.drag = GizmoDrag()

    @property
    def capturing(self) -> bool:
        return self.using or self.hovered

    def _refresh(self, editor: SceneEditor, index: int, camera: Camera) -> None:
        key = (id(editor), editor.version, index, camera.c2w.detach().cpu().numpy().tobytes(), camera.width)
        if key != self._key:
            self._key = key
            self._centre = object_centre(editor, index)
            self._hull = outline(editor, index, camera)

    def draw(
        self,
        session: Scene,
        index: int | None,
        camera: Camera,
        pixel_ratio: tuple[float, float],
        scale_handles: bool = False,
    ) -> str | None:
        """Draw the outline and the handles of particle ``index``'s object (nothing when None) seen by
        ``camera`` (framebuffer pixels; ``pixel_ratio`` = framebuffer pixels per window point) and apply a
        handle drag as a move, or with ``scale_handles`` the uniform scale handles' drag as a scale; with Ctrl held
        (and no handle dragged) the handles are greyed and take no press, so Ctrl + drag lifts the object. Returns
        a message: an edit refused, or where a slid object landed."""
        from imgui_bundle import imgui, imguizmo

        gz = imguizmo.im_guizmo
        self.hovered = False
        editor = session.editor
        if editor is None or index is None or not 0 <= index < editor.num_particles:
            if self.using and editor is not None:
                self.drag.stop(editor)  # (deselected mid-drag: nothing to show it on)
            self.using = False
            return None
        self._refresh(editor, index, camera)
        sx, sy = pixel_ratio
        draw = imgui.get_background_draw_list()
        if len(self._hull) >= 3:
            pts: list = [imgui.ImVec2(float(u) / sx, float(v) / sy) for u, v in self._hull]
            draw.add_polyline(pts, imgui.IM_COL32(255, 220, 40, 255), 2.0, imgui.ImDrawFlags_.closed.value)
        if self._centre is None:
            return None
        io = imgui.get_io()
        gz.begin_frame()
        gz.set_drawlist(draw)
        gz.set_rect(0.0, 0.0, io.display_size.x, io.display_size.y)
        gz.set_orthographic(False)
        # Ctrl held: a drag lifts the object (the viewport's Ctrl + drag), so the handles grey out and take no press
        enabled = self.using or not io.key_ctrl
        gz.enable(enabled)
        model = np.eye(4)
        model[:3, 3] = self._centre.numpy()
        obj = gz.Matrix16(model.T.flatten().tolist())
        delta = gz.Matrix16(np.eye(4).flatten().tolist())
        changed = gz.manipulate(
            gz.Matrix16(gl_view(camera).T.flatten().tolist()),
            gz.Matrix16(gl_projection(camera).T.flatten().tolist()),
            gz.OPERATION.scaleu if scale_handles else gz.OPERATION.translate,
            gz.MODE.world,
            obj,
            delta,
        )
        using = gz.is_using()
        self.hovered = enabled and bool(gz.is_over())
        message = None
        matrix = np.array(obj.values, dtype=np.float64).reshape(4, 4).T
        scales = np.linalg.norm(matrix[:3, :3], axis=0)  # ImGuizmo returns the drag's whole scale on a unit matrix
        if changed and scale_handles:
            if np.isfinite(scales).all():
                message = self.drag.scale(editor, index, float(scales.mean()))
        elif changed:
            step = matrix[:3, 3] - self._centre.numpy()
            if np.isfinite(step).all() and np.linalg.norm(step) > 0:
                mouse = (io.mouse_pos.x * sx, io.mouse_pos.y * sy)
                previous = (mouse[0] - io.mouse_delta.x * sx, mouse[1] - io.mouse_delta.y * sy)
                message = self.drag.step(editor, index, step, camera, mouse, previous)
        if self.using and not using:
            message = self.drag.stop(editor) or message
        self.using = bool(using)
        return message
