"""The crop box in the viewer: which box it shows, switching it on and off, setting one bound, and its wireframe.

The box the edits set (:meth:`particlesplat.editing.editor.SceneEditor.crop_box`) hides the Gaussians outside it
(:meth:`viewer.session.EditableScene.gaussians`). A robot scene whose edits set none still shows its workspace box
(:attr:`viewer.session.EditableScene.workspace`, what ``particlesplat export`` crops to) as a dimmer wireframe that
hides nothing: switching the box on (C, the panel's switch) makes it an edit. Every change goes through the editor
(:meth:`SceneEditor.set_crop`), so it is undone, saved and replayed as any edit.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
import torch

from particlesplat.core.camera import Camera
from particlesplat.core.gaussians import Gaussians
from particlesplat.editing.crop_box import CropBox
from particlesplat.editing.operations import Crop

if TYPE_CHECKING:
    from ..session import Scene

NEAR = 1e-3  # metres in front of the camera: a wireframe edge is cut where it passes behind this plane
MIN_SIZE = 0.01  # metres: a bound typed or dragged past the other one stops this far from it
APPLIED_COLOUR = (255, 170, 40, 255)  # the box the edits set (it hides what lies outside)
PROPOSED_COLOUR = (170, 170, 190, 150)  # the workspace box shown before it is switched on (it hides nothing)
# the box's 12 edges as pairs of corners; corner k takes min or max on axis a by bit a of k
EDGES = tuple((a, a | 1 << axis) for axis in range(3) for a in range(8) if not a & 1 << axis)


def applied_box(scene: Scene) -> CropBox | None:
    """The box the edits set when it hides anything (None: none, or ``crop: false``)."""
    editor = scene.editor
    box = None if editor is None else editor.crop_box
    return box if box is not None and box.bounded else None


def default_box(scene: Scene) -> CropBox | None:
    """The box switching the crop on sets when the edits never set one: the scene's workspace (a robot scene's table
    and arm), else the box about every Gaussian's mean, a centimetre beyond it (hides nothing until a bound is
    moved). None for a scene with nothing to edit or no Gaussian."""
    if scene.editor is None:
        return None
    workspace = getattr(scene, "workspace", None)
    if workspace is not None:
        return workspace
    means = scene.editor.decode().means.detach().double()
    if means.shape[0] == 0:
        return None
    lo, hi = means.min(0).values - MIN_SIZE, means.max(0).values + MIN_SIZE
    lo_c = tuple(math.floor(float(v) * 100.0) / 100.0 for v in lo)
    hi_c = tuple(math.ceil(float(v) * 100.0) / 100.0 for v in hi)
    return CropBox((lo_c[0], lo_c[1], lo_c[2]), (hi_c[0], hi_c[1], hi_c[2]))


def last_box(scene: Scene) -> CropBox | None:
    """The box to switch back on: the last bounded box an edit still done set (the one before the crop went off),
    else :func:`default_box`."""
    editor = scene.editor
    if editor is None:
        return None
    for op in reversed(editor.history.undo):
        if isinstance(op, Crop) and op.box is not None and op.box.bounded:
            return op.box
    return default_box(scene)


def shown_box(scene: Scene) -> tuple[CropBox, bool] | None:
    """(the box the viewport outlines, whether it is applied): the edits' box, else a robot scene's workspace box
    (not applied); None for a tabletop scene whose edits set none, or a .ply."""
    box = applied_box(scene)
    if box is not None:
        return box, True
    workspace = getattr(scene, "workspace", None)
    return (workspace, False) if workspace is not None else None


def toggle_crop(scene: Scene) -> str:
    """Switch the crop box off (``crop: false``: everything shows) or on again (:func:`last_box`), one edit.
    Returns the status line."""
    editor = scene.editor
    if editor is None:
        return "nothing to crop: a .ply opens as it is"
    if applied_box(scene) is not None:
        editor.set_crop(CropBox.everything())
        return "crop box off: every Gaussian shows (Ctrl+Z brings the box back)"
    box = last_box(scene)
    if box is None:
        return "nothing to crop: the scene draws no Gaussian"
    editor.set_crop(box)
    return f"cropped to {box.text()}"


def with_bound(box: CropBox, which: str, values: list[float]) -> CropBox:
    """``box`` with its ``which`` ("min" or "max") corner set to ``values`` (3,) metres; an axis pushed past the
    other corner stops :data:`MIN_SIZE` short of it."""
    lo, hi = list(box.lo), list(box.hi)
    for axis in range(3):
        v = float(values[axis])
        if which == "min":
            lo[axis] = min(v, hi[axis] - MIN_SIZE)
        else:
            hi[axis] = max(v, lo[axis] + MIN_SIZE)
    return CropBox((lo[0], lo[1], lo[2]), (hi[0], hi[1], hi[2]))


def corners(box: CropBox) -> np.ndarray:
    """(8, 3) float64 world metres: corner k takes ``hi`` on axis a where bit a of k is set, else ``lo``."""
    lo, hi = np.array(box.lo, np.float64), np.array(box.hi, np.float64)
    return np.array([[hi[a] if k >> a & 1 else lo[a] for a in range(3)] for k in range(8)])


def edge_segments(box: CropBox, camera: Camera) -> np.ndarray:
    """(M, 2, 2) framebuffer pixels of ``camera``: the box's edges as seen, each cut where it passes behind
    :data:`NEAR` (an edge wholly behind the camera is left out)."""
    c = torch.tensor(corners(box), dtype=torch.float64)
    cam = camera.to("cpu", torch.float64)
    p = cam.world_to_camera(c).numpy()  # (8, 3) camera metres, z forward
    K = cam.K.numpy()
    out = []
    for i, j in EDGES:
        a, b = p[i], p[j]
        if a[2] < NEAR and b[2] < NEAR:
            continue
        if a[2] < NEAR or b[2] < NEAR:  # cut at the near plane
            t = (NEAR - a[2]) / (b[2] - a[2])
            cut = a + t * (b - a)
            a, b = (cut, b) if a[2] < NEAR else (a, cut)
        ends = [(K[0, 0] * q[0] / q[2] + K[0, 2], K[1, 1] * q[1] / q[2] + K[1, 2]) for q in (a, b)]
        out.append(ends)
    return np.array(out, np.float64).reshape(-1, 2, 2)


def draw_crop_box(scene: Scene, camera: Camera, pixel_ratio: tuple[float, float]) -> None:
    """The box's wireframe over the scene (:func:`shown_box`; applied: orange, proposed: grey), drawn on imgui's
    background list as the selection outline is (``camera``: framebuffer pixels; ``pixel_ratio``: framebuffer
    pixels per window point)."""
    from imgui_bundle import imgui

    shown = shown_box(scene)
    if shown is None:
        return
    box, applied = shown
    colour = imgui.IM_COL32(*(APPLIED_COLOUR if applied else PROPOSED_COLOUR))
    sx, sy = pixel_ratio
    draw = imgui.get_background_draw_list()
    for (u0, v0), (u1, v1) in edge_segments(box, camera):
        draw.add_line(imgui.ImVec2(u0 / sx, v0 / sy), imgui.ImVec2(u1 / sx, v1 / sy), colour, 1.5)


def set_bound(scene: Scene, which: str, values: list[float], gesture: str | None = None) -> CropBox | None:
    """Set the ``which`` ("min" or "max") corner of the crop box to ``values`` (3,) metres (:func:`with_bound`)
    through the editor, starting from the box in effect, else :func:`last_box` (a bound set switches the box on);
    the steps of one ``gesture`` (a field's drag) are one edit. Returns the box set, or None (nothing to crop)."""
    editor = scene.editor
    box = applied_box(scene) or last_box(scene)
    if editor is None or box is None:
        return None
    new = with_bound(box, which, values)
    editor.set_crop(new, gesture)
    return new


def export_crop(scene: Scene, drawn: Gaussians) -> tuple[Gaussians, str]:
    """(what the viewer's export writes of the ``drawn`` Gaussians, a note for the status line or ""), as
    ``particlesplat export`` writes the scene: a robot scene whose edits never set a box is cropped to its
    workspace (:attr:`viewer.session.EditableScene.workspace`), so another viewer frames the table and the arm
    rather than the room; a box the edits set (the drawn Gaussians are inside it already) or switched off
    (``crop: false``) leaves them as drawn."""
    workspace = getattr(scene, "workspace", None)
    if scene.editor is None or scene.editor.crop_box is not None or workspace is None:
        return drawn, ""
    kept = workspace.crop(drawn)
    return kept, (
        f"cropped to the workspace box, {workspace.text()}: {drawn.num - kept.num} of {drawn.num} Gaussians outside "
        "left out (C then C again: every Gaussian)"
    )
