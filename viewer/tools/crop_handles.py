"""The crop box's handles: a dot at the centre of each of its six faces; dragging one moves that face along its
axis (the point of the axis through the face's centre nearest the mouse's ray), one undo step per drag.

Shown only while the box is applied (:func:`viewer.tools.crop_box.applied_box`); a press on a handle is theirs, not
the viewport's (no orbit, no pick), as a press on the object gizmo is.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import torch

from particlesplat.core.camera import Camera
from particlesplat.editing.crop_box import CropBox

from .crop_box import APPLIED_COLOUR, NEAR, applied_box, set_bound

if TYPE_CHECKING:
    from ..session import Scene

HANDLE_RADIUS = 6.0  # window points: a handle's dot; a press this close (plus 3) grabs it
PARALLEL = 1e-6  # a face's axis this close to parallel with the mouse's ray: no step (looking along it)


def face_centres(box: CropBox) -> np.ndarray:
    """(6, 3) float64 world metres: the centre of face 2 * axis + side (side 0: the ``lo`` face, 1: ``hi``)."""
    lo, hi = np.array(box.lo, np.float64), np.array(box.hi, np.float64)
    mid = 0.5 * (lo + hi)
    out = np.repeat(mid[None], 6, axis=0)
    for axis in range(3):
        out[2 * axis, axis], out[2 * axis + 1, axis] = lo[axis], hi[axis]
    return out


def projected_faces(box: CropBox, camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """((6, 2) framebuffer pixels of the face centres, (6,) bool: in front of the camera)."""
    cam = camera.to("cpu", torch.float64)
    uv, z = cam.project(torch.tensor(face_centres(box), dtype=torch.float64))
    return uv.numpy(), z.numpy() > NEAR


def handle_at(box: CropBox, camera: Camera, x: float, y: float, radius: float) -> int | None:
    """The face (2 * axis + side) whose handle is nearest framebuffer pixel (x, y) within ``radius`` pixels, or
    None."""
    uv, front = projected_faces(box, camera)
    d = np.hypot(uv[:, 0] - x, uv[:, 1] - y)
    d[~front] = np.inf
    face = int(np.argmin(d))
    return face if d[face] <= radius else None


def axis_value(camera: Camera, point: np.ndarray, axis: int, x: float, y: float) -> float | None:
    """World coordinate (metres) along ``axis`` of the point of the line through ``point`` (3,) along that axis
    nearest the ray of framebuffer pixel (x, y); None when the ray runs along the axis."""
    cam = camera.to("cpu", torch.float64)
    origin = cam.c2w[:3, 3].numpy()
    ray = cam.unproject(torch.tensor([x, y], dtype=torch.float64), torch.ones((), dtype=torch.float64)).numpy()
    d = ray - origin
    e = np.zeros(3)
    e[axis] = 1.0
    w0 = np.asarray(point, np.float64) - origin
    b, c = float(e @ d), float(d @ d)
    denom = c - b * b  # |e| = 1
    if denom <= PARALLEL * c:
        return None
    t = (b * float(d @ w0) - c * float(e @ w0)) / denom
    return float(point[axis] + t)


class CropHandles:
    """The handles' drag state. Call :meth:`draw` once a frame after ``imgui.new_frame`` and before the viewport's
    controls, which leave the mouse alone while :attr:`capturing`."""

    def __init__(self) -> None:
        self.face: int | None = None  # the face being dragged
        self.hovered = False

    @property
    def capturing(self) -> bool:
        return self.face is not None or self.hovered

    def draw(self, scene: Scene, camera: Camera, pixel_ratio: tuple[float, float], blocked: bool = False) -> str | None:
        """Draw the handles of the applied crop box seen by ``camera`` (framebuffer pixels; ``pixel_ratio``:
        framebuffer pixels per window point) and apply a drag of one; ``blocked``: the object gizmo has the mouse.
        Returns the drag's edit label when it ends (for the status line), else None."""
        from imgui_bundle import imgui

        from ..controls import ui_takes_mouse

        editor, box = scene.editor, applied_box(scene)
        self.hovered = False
        if editor is None or box is None:
            if self.face is not None and editor is not None:
                editor.end_gesture()
            self.face = None
            return None
        io = imgui.get_io()
        sx, sy = pixel_ratio
        x, y = io.mouse_pos.x * sx, io.mouse_pos.y * sy
        free = not blocked and not ui_takes_mouse(io)
        near = handle_at(box, camera, x, y, (HANDLE_RADIUS + 3.0) * sx) if free and self.face is None else None
        self.hovered = near is not None
        if near is not None and imgui.is_mouse_clicked(imgui.MouseButton_.left):
            self.face = near
        message = None
        if self.face is not None:
            axis, side = divmod(self.face, 2)
            if imgui.is_mouse_down(imgui.MouseButton_.left):
                value = axis_value(camera, face_centres(box)[self.face], axis, x, y)
                if value is not None and np.isfinite(value):
                    corner = list(box.hi if side else box.lo)
                    corner[axis] = value
                    set_bound(scene, "max" if side else "min", corner, gesture="crop handle")
            else:
                editor.end_gesture()
                self.face = None
                message = editor.history.undo[-1].label if editor.history.undo else None
        uv, front = projected_faces(applied_box(scene) or box, camera)
        draw = imgui.get_background_draw_list()
        for face in range(6):
            if front[face]:
                lit = face in (self.face, near)
                colour = imgui.IM_COL32(255, 255, 255, 255) if lit else imgui.IM_COL32(*APPLIED_COLOUR)
                draw.add_circle_filled(imgui.ImVec2(uv[face, 0] / sx, uv[face, 1] / sy), HANDLE_RADIUS, colour)
        return message
