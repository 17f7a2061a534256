"""The "Edits" section: undo, redo, the edits file to save to or load from."""

from __future__ import annotations

from typing import TYPE_CHECKING

from imgui_bundle import imgui

from ..session import SceneSession

if TYPE_CHECKING:
    from .fields import UiFields, UiRequests


def draw_edits_section(session: SceneSession, req: UiRequests, fields: UiFields) -> None:
    if not imgui.collapsing_header("Edits", imgui.TreeNodeFlags_.default_open):
        return
    h = session.history
    if imgui.button(f"Undo ({len(h.undo)})"):
        session.undo()
    imgui.same_line()
    if imgui.button(f"Redo ({len(h.redo)})"):
        session.redo()
    imgui.text(f"edited particles: {len(session.edits())}")
    _, fields.edits_path = imgui.input_text("edits YAML", fields.edits_path)
    if imgui.button("Save edits"):
        req.save_edits = True
    imgui.same_line()
    if imgui.button("Load edits"):
        req.load_edits = True
