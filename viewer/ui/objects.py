"""The selected object's panel section: its particles, its offset in metres (typed or dragged), delete and
duplicate. Every change is a do/undo operation of the session."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from particlesplat.core import palette
from particlesplat.editing.editor import PickError
from particlesplat.editing.move import MoveError

if TYPE_CHECKING:
    from ..session import SceneSession

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


def remove_selected(session: SceneSession, selected: int | None) -> tuple[int | None, str]:
    """Remove the selected particle's object (one operation). Returns (new selection, status message)."""
    if selected is None or not session.editable:
        return selected, "select an object first (click it)"
    members = session.object_members(selected)
    session.remove_object(selected)
    return (
        None,
        f"removed the object of particle{'s' if len(members) > 1 else ''} {', '.join(map(str, members))}"
        " (Ctrl+Z brings it back)",
    )


def duplicate_selected(session: SceneSession, selected: int | None, offset) -> tuple[int | None, str]:
    """Copy the selected particle's object, moved by ``offset`` (3,) metres (one operation); the copy becomes
    the selection. Returns (new selection, status message)."""
    if selected is None or not session.editable:
        return selected, "select an object first (click it)"
    try:
        copy = session.duplicate_object(selected, [float(v) for v in offset])
    except (MoveError, PickError) as e:
        return selected, f"error: {e}"
    members = session.object_members(copy)
    return copy, f"copied the object: new particles {', '.join(map(str, members))}, offset {_metres(offset)}"


def hint(text: str) -> None:
    """A greyed hint that wraps at the panel's edge (never cut off)."""
    from imgui_bundle import imgui

    imgui.push_style_color(imgui.Col_.text, imgui.get_style_color_vec4(imgui.Col_.text_disabled))
    imgui.text_wrapped(text)
    imgui.pop_style_color()


def _metres(v) -> str:
    return "(" + ", ".join(f"{float(x):+.3f}" for x in v) + ") m"


def draw_object_section(session: SceneSession, selected: int, fields: ObjectFields) -> tuple[int | None, str | None]:
    """The selected particle's object: members, offset (m) to type or drag, delete, duplicate.

    Returns (the selection after this frame, a status message or None)."""
    from imgui_bundle import imgui

    members = session.object_members(selected)
    imgui.separator_text("Object")
    imgui.text(f"particle{'s' if len(members) > 1 else ''} {', '.join(map(str, members))}")
    message = None
    offset = list(session.object_offset(selected))
    changed, new = imgui.drag_float3("offset (m)", offset, 0.005, 0.0, 0.0, "%.3f")
    if changed:
        try:
            session.move_object(selected, [a - b for a, b in zip(new, offset, strict=False)], gesture="panel-offset")
        except MoveError as e:
            message = f"error: {e}"
    if imgui.is_item_deactivated():
        session.end_gesture()
    hint("world X / Y on the floor, Z up; double-click a box to type metres")
    if imgui.button("Delete object (Del)"):
        selected, message = remove_selected(session, selected)
        return selected, message
    imgui.same_line()
    if imgui.button("Duplicate (Ctrl+D)"):
        return duplicate_selected(session, selected, fields.copy_offset)
    changed, value = imgui.input_float3("copy offset (m)", fields.copy_offset, "%.3f")
    if changed:
        fields.copy_offset = [float(v) for v in value]
    if imgui.tree_node("Rotation"):
        imgui.text_wrapped(ROTATION_NOTE)
        imgui.tree_pop()
    return selected, message
