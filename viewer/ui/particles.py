"""The "Particles" section: one row a particle (index, segmentation colour, swatch, status, visible, solo)."""

from __future__ import annotations

from typing import Literal

from imgui_bundle import imgui

from particlesplat.editing.editor import SceneEditor

from ..state import SegMode, ViewState
from .objects import segmentation_colour


def draw_particles_section(
    editor: SceneEditor, state: ViewState, swatches: dict[int, tuple[float, float, float]]
) -> None:
    if not imgui.collapsing_header("Particles", imgui.TreeNodeFlags_.default_open):
        return
    by_object = state.seg_mode is SegMode.BY_OBJECT
    labels = editor.objects() if by_object else None
    imgui.text(f"idx  {'object' if by_object else 'seg'} colour  active  visible  solo")
    for i in range(editor.num_particles):
        imgui.push_id(i)
        r, g, b = swatches.get(i, (0.5, 0.5, 0.5))
        clicked, _ = imgui.selectable(f"{i:3d}", state.selected == i, 0, imgui.ImVec2(28.0, 0.0))
        if clicked:
            state.selected = None if state.selected == i else i
        imgui.same_line()
        sr, sg, sb = segmentation_colour(int(labels[i]) if labels is not None else i)  # as "colour by ..." draws it
        imgui.color_button("##seg", imgui.ImVec4(sr, sg, sb, 1.0), 0, imgui.ImVec2(22.0, 0.0))
        imgui.same_line()
        imgui.color_button("##swatch", imgui.ImVec4(r, g, b, 1.0), 0, imgui.ImVec2(22.0, 0.0))
        imgui.same_line()
        status = particle_status(editor, i)
        imgui.text_colored(
            imgui.ImVec4(0.5, 1.0, 0.5, 1.0) if status == "active" else imgui.ImVec4(0.6, 0.6, 0.6, 1.0),
            f"{status:<8}",
        )
        imgui.same_line()
        changed, visible = imgui.checkbox("##visible", i not in state.hidden)
        if changed:
            (state.hidden.discard if visible else state.hidden.add)(i)
        imgui.same_line()
        changed, solo = imgui.checkbox("##solo", state.solo == i)
        if changed:
            state.solo = i if solo else None
        imgui.pop_id()


def particle_status(editor: SceneEditor, i: int) -> Literal["active", "deleted", "inactive"]:
    """How the particle list names particle ``i``: drawn, deleted (drawn as encoded, its object removed since), or
    inactive (the encoder left it off)."""
    if editor.is_active(i):
        return "active"
    return "deleted" if editor.original_value(i, "z_t")[0] >= editor.active_threshold else "inactive"
