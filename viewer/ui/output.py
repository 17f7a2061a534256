"""The "Output" section: the folder, the screenshot size, screenshot and .ply exports."""

from __future__ import annotations

from typing import TYPE_CHECKING

from imgui_bundle import imgui

from .buttons import action_button

if TYPE_CHECKING:
    from ..actions import ActionContext
    from .fields import UiFields


def draw_output_section(ctx: ActionContext, fields: UiFields, object_selected: bool = False) -> None:
    if not imgui.collapsing_header("Output", imgui.TreeNodeFlags_.default_open):
        return
    _, fields.output_dir = imgui.input_text("folder", fields.output_dir)
    changed, size = imgui.input_int2("shot size (0 = window)", list(fields.shot_size))
    if changed:
        fields.shot_size = [max(0, min(8192, int(v))) for v in size]
    action_button("screenshot", ctx)
    imgui.same_line()
    action_button("export_ply", ctx)
    if object_selected:
        imgui.same_line()
        if imgui.button("Export object .ply"):
            ctx.requests.export_object = True
