"""The "Output" section: the folder, the screenshot size, screenshot and Gaussian file exports (.ply, .compressed.ply,
.splat, .spz, .sog, or an object bundle)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from imgui_bundle import imgui

from particlesplat.formats.splat_files import SUFFIXES

from ..screenshot import BUNDLE
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
        if imgui.button("Export object"):
            ctx.requests.export_object = True
    choices = [*SUFFIXES, BUNDLE]  # a bundle: a folder of one .ply an object (a particle for a file) + manifest
    current = choices.index(fields.export_format) if fields.export_format in choices else 0
    changed, idx = imgui.combo("format", current, choices)
    if changed:
        fields.export_format = choices[idx]
