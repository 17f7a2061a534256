"""The "Crop box" section: the box's switch (the ``crop`` action, C), its min and max corners in world metres
(dragged or typed: one edit per field's drag) and a reset to a robot scene's workspace. Every change is a
do/undo operation of the scene's editor (:mod:`viewer.tools.crop_box`)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from imgui_bundle import imgui

from ..actions import run
from ..tools.crop_box import applied_box, last_box, set_bound

if TYPE_CHECKING:
    from ..actions import ActionContext

DRAG_SPEED = 0.005  # metres per pixel dragged


def draw_crop_section(ctx: ActionContext) -> None:
    scene = ctx.session
    editor = scene.editor
    if editor is None or not imgui.collapsing_header("Crop box", imgui.TreeNodeFlags_.default_open):
        return
    applied = applied_box(scene)
    box = applied or last_box(scene)
    if box is None:
        imgui.text_disabled("no Gaussian to crop")
        return
    changed, _ = imgui.checkbox("hide what lies outside (C)", applied is not None)
    if changed:
        run("crop", ctx)
    for which, corner in (("min", box.lo), ("max", box.hi)):
        moved, values = imgui.drag_float3(f"{which} x y z (m)", list(corner), DRAG_SPEED, format="%.3f")
        if moved:
            set_bound(scene, which, list(values), gesture=f"crop {which}")
        if imgui.is_item_deactivated():
            editor.end_gesture()
        if imgui.is_item_deactivated_after_edit() and editor.history.undo:
            ctx.status(editor.history.undo[-1].label)  # "crop to x -0.66..0.50, ..."
    workspace = getattr(scene, "workspace", None)
    if workspace is not None and imgui.button("Reset to the workspace"):
        editor.set_crop(workspace)
        ctx.status(f"cropped to the workspace, {workspace.text()}")
    if applied is None:
        imgui.text_disabled("off: every Gaussian shows")
