"""The selected particle's section: its attributes (drag or reset), and its object (:mod:`viewer.ui.objects`)."""

from __future__ import annotations

from types import MappingProxyType
from typing import TYPE_CHECKING

from imgui_bundle import imgui

from particlesplat.editing.edited import SUNK_TOLERANCE
from particlesplat.model.particles import EDITABLE

from .objects import draw_object_section

if TYPE_CHECKING:
    from particlesplat.editing.editor import SceneEditor

    from ..actions import ActionContext
    from .fields import UiFields

DRAG_SPEED = MappingProxyType(
    {"z_p": 0.005, "z_s": 0.02, "z_d": 0.02, "z_e": 0.02, "z_t": 0.005, "move": 0.005}
)  # move: metres per pixel dragged


def warn_if_sunk(editor: SceneEditor, index: int, ctx: ActionContext) -> None:
    """Say so on the status line when a hand-set latent put particle ``index``'s object below its support (it
    stays: the user may want it)."""
    bottom, support = editor.object_bottom(index), editor.support_height(index)
    if bottom is not None and bottom < support - SUNK_TOLERANCE:
        ctx.status(f"warning: the object's bottom is at z = {bottom:.2f} m, below its support at {support:.2f} m")


def draw_selected_section(editor: SceneEditor, ctx: ActionContext, fields: UiFields) -> None:
    i = ctx.state.selected
    if i is None or not 0 <= i < editor.num_particles:
        return
    if not imgui.collapsing_header(f"Particle {i}", imgui.TreeNodeFlags_.default_open):
        return
    for name, width in EDITABLE.items():
        value = list(editor.value(i, name))
        if width == 2:
            changed, new = imgui.drag_float2(name, value, DRAG_SPEED[name])
        elif name == "z_t":
            changed, v = imgui.drag_float(name, value[0], DRAG_SPEED[name], 0.0, 1.0)
            new = [v]
        else:
            changed, v = imgui.drag_float(name, value[0], DRAG_SPEED[name])
            new = [v]
        if changed:
            editor.set_attribute(i, name, new, gesture="panel")
        if imgui.is_item_deactivated():
            editor.end_gesture()
            warn_if_sunk(editor, i, ctx)
        imgui.same_line()
        if imgui.small_button(f"reset##{name}"):
            editor.set_attribute(i, name, editor.original_value(i, name))
    if imgui.button("Reset particle to encoded values"):
        editor.reset_particle(i)
    # the object: every particle of it (one per view that holds it), moved in world metres, deleted, copied
    draw_object_section(editor, i, ctx, fields.objects)
