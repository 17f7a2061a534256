"""The "Edits" section: undo, redo (:mod:`viewer.actions`), the edits file to save to or load from."""

from __future__ import annotations

from typing import TYPE_CHECKING

from imgui_bundle import imgui

from .buttons import action_button

if TYPE_CHECKING:
    from particlesplat.editing.editor import SceneEditor

    from ..actions import ActionContext
    from .fields import UiFields


def draw_edits_section(editor: SceneEditor, ctx: ActionContext, fields: UiFields) -> None:
    if not imgui.collapsing_header("Edits", imgui.TreeNodeFlags_.default_open):
        return
    h = editor.history
    action_button("undo", ctx, f"Undo ({len(h.undo)})")
    imgui.same_line()
    action_button("redo", ctx, f"Redo ({len(h.redo)})")
    imgui.text(f"edited particles: {len(editor.edits())}")
    _, fields.edits_path = imgui.input_text("edits YAML", fields.edits_path)
    action_button("save_edits", ctx, "Save edits")
    imgui.same_line()
    if imgui.button("Load edits"):
        ctx.requests.load_edits = True
