"""The selected object's panel section: its particles, its offset in metres (typed or dragged), delete and
duplicate (:mod:`viewer.actions`). Every change is a do/undo operation of the scene's editor."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from particlesplat.core import palette
from particlesplat.editing.move import MoveError

from .buttons import action_button

if TYPE_CHECKING:
    from particlesplat.editing.editor import SceneEditor

    from ..actions import ActionContext

ROTATION_NOTE = (
    "Rotation is not available: a particle is a patch lifted along its own view's rays, with "
    "position, scale, depth and depth extent but no orientation latent, so turning an object "
    "would show each patch edge-on instead of the object's other side."
)


def segmentation_colour(key: int) -> tuple[float, float, float]:
    """The colour the "colour by particle / object" modes draw owner or object ``key`` with (the splat
    shader's ``owner_color``): :func:`particlesplat.core.palette.colour`."""
    return palette.colour(key)


@dataclass
class ObjectFields:
    """Persistent inputs of the object section: the copy's offset (metres)."""

    copy_offset: list[float] = field(default_factory=lambda: [0.3, 0.0, 0.0])


def hint(text: str) -> None:
    """A greyed hint that wraps at the panel's edge (never cut off)."""
    from imgui_bundle import imgui

    imgui.push_style_color(imgui.Col_.text, imgui.get_style_color_vec4(imgui.Col_.text_disabled))
    imgui.text_wrapped(text)
    imgui.pop_style_color()


def draw_object_section(editor: SceneEditor, selected: int, ctx: ActionContext, fields: ObjectFields) -> None:
    """The selected particle's object: members, offset (m) to type or drag, delete, duplicate."""
    from imgui_bundle import imgui

    members = editor.object_members(selected)
    imgui.separator_text("Object")
    imgui.text(f"particle{'s' if len(members) > 1 else ''} {', '.join(map(str, members))}")
    offset = list(editor.object_offset(selected))
    changed, new = imgui.drag_float3("offset (m)", offset, 0.005, 0.0, 0.0, "%.3f")
    if changed:
        try:
            editor.move_object(selected, [a - b for a, b in zip(new, offset, strict=False)], gesture="panel-offset")
        except MoveError as e:
            ctx.status(f"error: {e}")
    if imgui.is_item_deactivated():
        editor.end_gesture()
    hint("world X / Y on the floor, Z up; double-click a box to type metres")
    if action_button("delete", ctx):
        return
    imgui.same_line()
    if action_button("duplicate", ctx):
        return
    changed, value = imgui.input_float3("copy offset (m)", fields.copy_offset, "%.3f")
    if changed:
        fields.copy_offset[:] = [float(v) for v in value]
    if imgui.tree_node("Rotation"):
        imgui.text_wrapped(ROTATION_NOTE)
        imgui.tree_pop()
