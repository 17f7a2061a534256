"""The "Insert object" panel section: an object of another scene, placed with its centre at (x, y) on this
scene's floor (:meth:`particlesplat.editing.editor.SceneEditor.insert_object`; saved in edit files as ``insert``)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from particlesplat.editing.editor import Insert
from particlesplat.editing.open_scene import demo_scene_name, demo_scenes, encode_scene

if TYPE_CHECKING:
    from particlesplat.editing.editor import SceneEditor


@dataclass
class InsertFields:
    """What the section holds between frames: the source scene folder, the object index (as ``particlesplat
    encode`` numbers objects) and the position (x, y) in metres on the surface there, or ``free_spot``: a place no
    object of this scene takes (:func:`particlesplat.editing.placement.free_spot`)."""

    scene: str = ""
    object: int = 0
    at: list[float] = field(default_factory=lambda: [0.0, 0.0])
    free_spot: bool = True


def draw_insert_section(fields: InsertFields) -> bool:
    """The section's widgets; returns whether Insert was clicked (the app does the work after the frame)."""
    from imgui_bundle import imgui

    if not imgui.collapsing_header("Insert object from another scene"):
        return False
    scenes = demo_scenes()
    if scenes:
        names = ["(choose)"] + [demo_scene_name(p) for p in scenes]
        current = 1 + next((i for i, p in enumerate(scenes) if str(p) == fields.scene), -1)
        changed, idx = imgui.combo("demo##insert", current, names)
        if changed and idx > 0:
            fields.scene = str(scenes[idx - 1])
    _, fields.scene = imgui.input_text("from scene", fields.scene)
    changed, value = imgui.input_int("object", fields.object)
    if changed:
        fields.object = max(0, int(value))
    _, fields.free_spot = imgui.checkbox("at a free spot", fields.free_spot)
    if not fields.free_spot:
        changed, at = imgui.input_float2("at x, y (m)", fields.at, "%.3f")
        if changed:
            fields.at = [float(v) for v in at]
    imgui.text_wrapped(
        "Objects are numbered as particlesplat encode's 'object'. The object's centre goes to (x, y) on the surface "
        "there (the table, or the floor past its edge), or the free spot nearest to it; or to the free spot nearest "
        "the scene's objects."
    )
    return bool(imgui.button("Insert")) and bool(fields.scene.strip())


def insert_from_fields(editor: SceneEditor, fields: InsertFields) -> tuple[int, str]:
    """Encode ``fields.scene`` with the editor's model (its default context frames) and insert the object at
    (x, y) on the surface there (the table, or the floor past its edge), or the free spot nearest to it, or (with
    ``free_spot``) the free spot nearest the scene's objects (:func:`particlesplat.editing.placement.insert_spot`):
    returns (the new object's first particle, a status line, which says where it went when that is not (x, y)).
    Errors (no such scene or object, no free spot, a move out of range) propagate for the app to show."""
    from particlesplat.editing.compose import object_members
    from particlesplat.editing.placement import footprints, insert_spot, scene_footprints

    scene = fields.scene.strip()
    source = encode_scene(editor.model, scene)
    members = object_members(editor.model, source.particles, int(fields.object))
    radius = footprints(editor.model, source.particles, members)[0].radius
    edited = editor.scene
    feet = scene_footprints(edited.decode(), edited.objects().labels, edited.particles.support_heights()[:, 0])
    wanted = None if fields.free_spot else (float(fields.at[0]), float(fields.at[1]))
    at, note = insert_spot(editor.world, list(feet.values()), radius, wanted, "at x, y")
    fields.at = [at[0], at[1]]
    ins = Insert(scene, int(fields.object), at, tuple(source.context))
    first = editor.insert_object(source.particles, ins)
    return first, (
        f"inserted object {ins.object} of {Path(ins.scene).name} as particles "
        f"{first}..{editor.num_particles - 1} at ({ins.at[0]:g}, {ins.at[1]:g})" + (f"; {note}" if note else "")
    )
