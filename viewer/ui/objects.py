"""The selected object's panel section: its particles, its offset in metres (typed or dragged), delete and
duplicate (:mod:`viewer.actions`). Every change is a do/undo operation of the scene's editor."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import torch

from particlesplat.core import palette
from particlesplat.editing.grouping import OPAQUE
from particlesplat.editing.move import MoveError
from particlesplat.editing.operations import Scale, Translate

from .buttons import action_button

if TYPE_CHECKING:
    from particlesplat.editing.editor import SceneEditor

    from ..actions import ActionContext

COPY_STEP = 0.1  # a copy's default offset along x: this share of the distance the scene's default view looks from


def copy_step(distance: float) -> list[float]:
    """A copy's default offset (3,) metres for a scene whose default view looks from ``distance`` metres: along x,
    by :data:`COPY_STEP` of it, to the centimetre (0.31 m on a tabletop scene seen from 3.1 m, 0.12 m on a robot
    table seen from 1.15 m): beside the original at the scene's own scale (the copy then goes to the free spot
    nearest, :meth:`SceneEditor.copy_object`)."""
    return [round(COPY_STEP * float(distance), 2), 0.0, 0.0]


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
    """Persistent inputs of the object section: the copy's offset (metres) and the last measure (its key: editor,
    version, particle). The scale field shows the object's scale as it is (:meth:`SceneEditor.object_scale`)."""

    copy_offset: list[float] = field(default_factory=lambda: [0.3, 0.0, 0.0])
    measured: tuple[tuple, list[float], list[float]] | None = None


def object_measure(editor: SceneEditor, index: int) -> tuple[list[float], list[float]]:
    """(size, resting centre) of particle ``index``'s object as drawn: its extent along world x, y, z (metres,
    from the 2 % to the 98 % quantile of its opaque Gaussians' centres) and its resting centre (metres; zeros when
    it draws nothing)."""
    g = editor.model.decode(editor.particles, torch.tensor(editor.object_members(index)), background=False)
    x = g.means[g.opacities >= OPAQUE].detach().double()
    if x.shape[0] < 2:
        return [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]
    size = (torch.quantile(x, 0.98, dim=0) - torch.quantile(x, 0.02, dim=0)).tolist()
    centre = editor.object_centre(index)
    return size, [0.0, 0.0, 0.0] if centre is None else centre.tolist()


def gesture_readout(editor: SceneEditor, index: int) -> str | None:
    """What the drag under way has done to particle ``index``'s object so far, or None."""
    gesture = editor.history.gesture
    op = gesture.operation if gesture is not None else None
    if isinstance(op, Translate) and index in op.members:
        return "this drag: " + _metres(op.offset)
    if isinstance(op, Scale) and index in op.members:
        return f"this drag: x{op.factor:.3f}"
    return None


def _metres(v) -> str:
    return "(" + ", ".join(f"{float(x):+.3f}" for x in v) + ") m"


def hint(text: str) -> None:
    """A greyed hint that wraps at the panel's edge (never cut off)."""
    from imgui_bundle import imgui

    imgui.push_style_color(imgui.Col_.text, imgui.get_style_color_vec4(imgui.Col_.text_disabled))
    imgui.text_wrapped(text)
    imgui.pop_style_color()


def draw_object_section(editor: SceneEditor, selected: int, ctx: ActionContext, fields: ObjectFields) -> None:
    """The selected particle's object: members, its size and resting centre, offset (m) and scale to type or
    drag, grow / shrink, merge / split, delete, duplicate."""
    from imgui_bundle import imgui

    members = editor.object_members(selected)
    imgui.separator_text("Object")
    imgui.text(f"particle{'s' if len(members) > 1 else ''} {', '.join(map(str, members))}")
    key = (id(editor), editor.version, selected)
    if fields.measured is None or fields.measured[0] != key:
        fields.measured = (key, *object_measure(editor, selected))
    _, size, centre = fields.measured
    imgui.text(f"size {size[0]:.3f} x {size[1]:.3f} x {size[2]:.3f} m (x, y, z)")
    imgui.text(f"resting centre ({centre[0]:+.3f}, {centre[1]:+.3f}, {centre[2]:+.3f}) m")
    readout = gesture_readout(editor, selected)
    if readout:
        imgui.text(readout)
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
    current = editor.object_scale(selected)  # follows every scale: keys, gizmo, this field, undo
    changed, value = imgui.drag_float("scale (x)", current, 0.005, 0.1, 10.0, "%.3f")
    if changed and value > 0.0 and abs(value / current - 1.0) > 1e-6:
        try:
            editor.scale_object(selected, value / current, gesture="panel-scale")
        except MoveError as e:
            ctx.status(f"error: {e}")
    if imgui.is_item_deactivated():
        editor.end_gesture()
    for i, name in enumerate(("grow", "shrink", "merge", "split")):
        if i % 2:
            imgui.same_line()
        action_button(name, ctx)
    if ctx.state.previous is not None and ctx.state.previous < editor.num_particles:
        hint(f"Merge joins it with the object of particle {ctx.state.previous} (selected before)")
    if action_button("delete", ctx):
        return
    imgui.same_line()
    if action_button("duplicate", ctx):
        return
    changed, offset = imgui.input_float3("copy offset (m)", fields.copy_offset, "%.3f")
    if changed:
        fields.copy_offset[:] = [float(v) for v in offset]
    if imgui.tree_node("Rotation"):
        imgui.text_wrapped(ROTATION_NOTE)
        imgui.tree_pop()
