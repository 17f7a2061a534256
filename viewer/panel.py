"""The ImGui panel and overlay. They read the session, view state and UI requests, and change
them only through their methods and fields; they never touch GL or the renderer."""

from __future__ import annotations

from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Literal

from imgui_bundle import imgui

from particlesplat.core.camera import Camera
from particlesplat.editing.open_scene import demo_scenes
from particlesplat.model.particles import EDITABLE

from .panels.insert import InsertFields, draw_insert_section
from .panels.objects import ObjectFields, draw_object_section, segmentation_colour
from .session import SceneSession
from .state import SEG_MODES, SegMode, ViewState

SHORTCUTS = (
    ("left drag", "orbit"),
    ("right / middle drag", "pan"),
    ("wheel", "zoom"),
    ("click", "select the particle under the cursor (its object is outlined)"),
    ("left drag on the selected object", "slide it on the floor (world X / Y)"),
    ("Shift + left drag", "slide the selected object on the floor from anywhere"),
    ("Ctrl + left drag", "lift or lower the selected object (world Z)"),
    ("gizmo arrows / planes", "move the selected object along world X, Y or Z, or in a plane"),
    ("Del / Ctrl+D", "delete / duplicate the selected object"),
    ("R", "reset the view"),
    ("0 .. 9", "snap to input camera 0 .. 9 (numbered as --context and render --view)"),
    ("Ctrl+Z / Ctrl+Shift+Z or Ctrl+Y", "undo / redo"),
    ("Ctrl+S", "save the edits to the 'edits YAML' path"),
    ("P or F12", "screenshot (no UI)"),
    ("E", "export the drawn Gaussians to .ply"),
    ("M", "next segmentation mode"),
    ("H", "hide / show the panel"),
    ("O", "hide / show the overlay"),
    ("Esc", "deselect"),
)

DRAG_SPEED = MappingProxyType(
    {"z_p": 0.005, "z_s": 0.02, "z_d": 0.02, "z_e": 0.02, "z_t": 0.005, "move": 0.005}
)  # move: metres per pixel dragged


PANEL_WIDTH, PANEL_MARGIN = 400.0, 10.0  # window points: the panel docks at the right edge


def clear_of_panel(camera: Camera, px_per_point: float) -> Camera:
    """``camera`` with its principal point moved left by half the panel's width (``px_per_point`` camera
    pixels per window point), so what the orbit looks at sits in the middle of the part of the window the
    panel leaves free. Unchanged when the window is less than twice as wide as the panel."""
    shift = 0.5 * (PANEL_WIDTH + PANEL_MARGIN) * px_per_point
    if camera.width < 4.0 * shift:
        return camera
    K = camera.K.clone()
    K[0, 2] -= shift
    return Camera(K, camera.c2w, camera.width, camera.height)


@dataclass
class UiRequests:
    """Work the panel asks the app to do after the frame (files, scene switches)."""

    open_path: str | None = None
    screenshot: bool = False
    export_ply: bool = False
    export_object: bool = False  # the selected particle's object to a .ply
    save_edits: bool = False
    load_edits: bool = False
    snap_camera: int | None = None
    reset_view: bool = False
    insert: bool = False  # an object of another scene (UiFields.insert)


@dataclass
class UiFields:
    """Persistent text/number fields of the panel."""

    scene_path: str = ""
    edits_path: str = "edits.yaml"
    output_dir: str = "."
    shot_size: list[int] = field(default_factory=lambda: [0, 0])
    insert: InsertFields = field(default_factory=InsertFields)
    status: str = ""
    objects: ObjectFields = field(default_factory=ObjectFields)
    layout_size: tuple[float, float] = (0.0, 0.0)  # the window size the panel was last placed for
    confirm_overwrite: str | None = None  # a file of another scene that a second Save may replace


def draw_overlay(text_lines: list[str]) -> None:
    """Frame time, Gaussian count and active particles in the top-left corner."""
    draw = imgui.get_foreground_draw_list()
    y = 6.0
    for line in text_lines:
        draw.add_text(imgui.ImVec2(9.0, y + 1.0), imgui.IM_COL32(0, 0, 0, 255), line)
        draw.add_text(imgui.ImVec2(8.0, y), imgui.IM_COL32(255, 255, 255, 255), line)
        y += imgui.get_text_line_height() + 2.0


def draw_panel(
    session: SceneSession,
    state: ViewState,
    req: UiRequests,
    fields: UiFields,
    swatches: dict[int, tuple[float, float, float]],
    counts: tuple[int, int],
) -> None:
    """The side panel. ``swatches``: particle colours; ``counts``: (drawn, total) Gaussians."""
    vp = imgui.get_main_viewport()
    size = (float(vp.work_size.x), float(vp.work_size.y))
    cond = imgui.Cond_.always if size != fields.layout_size else imgui.Cond_.first_use_ever
    fields.layout_size = size  # the panel follows a window resize (docked right, full height)
    imgui.set_next_window_pos(
        imgui.ImVec2(vp.work_pos.x + vp.work_size.x - PANEL_WIDTH - PANEL_MARGIN, vp.work_pos.y + 8.0), cond
    )
    imgui.set_next_window_size(imgui.ImVec2(PANEL_WIDTH, vp.work_size.y - 16.0), cond)
    imgui.begin("ParticleSplat")
    imgui.push_item_width(-150.0)
    if fields.status:  # at the top, where the user looks after a click (saved, exported, errors)
        error = fields.status.startswith("error")
        imgui.push_style_color(
            imgui.Col_.text, imgui.ImVec4(1.0, 0.45, 0.4, 1.0) if error else imgui.ImVec4(0.55, 1.0, 0.55, 1.0)
        )
        imgui.text_wrapped(fields.status)
        imgui.pop_style_color()
        if imgui.small_button("dismiss"):
            fields.status = ""
        imgui.separator()
    _scene_section(session, req, fields)
    _view_section(session, state, req, counts)
    if session.editable:
        _particles_section(session, state, swatches)
        _selected_section(session, state, fields)
        _edits_section(session, req, fields)
        req.insert = draw_insert_section(fields.insert) or req.insert
    _output_section(req, fields, session.editable and state.selected is not None)
    if imgui.collapsing_header("Shortcuts"):
        for keys, what in SHORTCUTS:
            imgui.bullet_text(f"{keys}: {what}")
    imgui.pop_item_width()
    imgui.end()


def _scene_section(session: SceneSession, req: UiRequests, fields: UiFields) -> None:
    if not imgui.collapsing_header("Scene", imgui.TreeNodeFlags_.default_open):
        return
    imgui.text_wrapped(f"{session.source}")
    for warning in getattr(session.encoded, "warnings", None) or []:
        imgui.push_style_color(imgui.Col_.text, imgui.ImVec4(1.0, 0.75, 0.3, 1.0))
        imgui.text_wrapped(f"warning: {warning}")
        imgui.pop_style_color()
    if session.model_name:
        imgui.text_wrapped(f"model: {session.model_name}")
    scenes = demo_scenes()
    if scenes:
        names = ["(choose)"] + [p.name for p in scenes]
        current = 1 + next((i for i, p in enumerate(scenes) if str(p) == session.source), -1)
        changed, idx = imgui.combo("demo", current, names)
        if changed and idx != current and idx > 0:
            req.open_path = str(scenes[idx - 1])
    entered, fields.scene_path = imgui.input_text(
        "folder / .ply", fields.scene_path, imgui.InputTextFlags_.enter_returns_true
    )
    if (imgui.button("Open") or entered) and fields.scene_path.strip():  # Enter in the field opens it too
        req.open_path = fields.scene_path.strip()


def _view_section(session: SceneSession, state: ViewState, req: UiRequests, counts: tuple[int, int]) -> None:
    if not imgui.collapsing_header("View", imgui.TreeNodeFlags_.default_open):
        return
    if imgui.button("Reset view (R)"):
        req.reset_view = True
    cams = session.cameras
    if cams:
        imgui.text_wrapped(
            "snap to input camera (numbered from 0, as --context, render --view and pick.frame in edit files)"
            + (f"; context frames {', '.join(map(str, session.context))}" if session.context else "")
        )
        for i in range(len(cams)):
            if i % 7:
                imgui.same_line()
            in_context = i in (session.context or [])
            if in_context:
                imgui.push_style_color(imgui.Col_.button, imgui.ImVec4(0.2, 0.5, 0.3, 1.0))
            if imgui.small_button(f"{i:2d}##cam{i}"):
                req.snap_camera = i
            if in_context:
                imgui.pop_style_color()
    changed, idx = imgui.combo("segmentation", SEG_MODES.index(state.seg_mode), [m.value for m in SEG_MODES])
    if changed:
        state.seg_mode = SEG_MODES[idx]
    if not session.editable and state.seg_mode is not SegMode.NORMAL:
        imgui.text_wrapped(
            "a .ply holds Gaussians, not particles: the particle and object modes show the owner ids it stores "
            + ("(this file stores none, so everything is background)" if not session.owner_ids() else "")
            + "; keypoints and boxes need a model scene"
        )
    changed, value = imgui.slider_float("prune opacity", state.prune, 0.0, 1.0, "%.3f")
    if changed:
        state.prune = max(0.0, value)
    imgui.text(f"Gaussians drawn: {counts[0]:,} of {counts[1]:,}")
    changed, value = imgui.slider_float("scale while moving", state.moving_scale, 0.25, 1.0, "%.2f")
    if changed:
        state.moving_scale = value
    changed, col = imgui.color_edit3("background", list(state.background))
    if changed:
        state.background = tuple(float(c) for c in col)


def _particles_section(
    session: SceneSession, state: ViewState, swatches: dict[int, tuple[float, float, float]]
) -> None:
    if not imgui.collapsing_header("Particles", imgui.TreeNodeFlags_.default_open):
        return
    by_object = state.seg_mode is SegMode.BY_OBJECT
    labels = session.objects() if by_object else None
    imgui.text(f"idx  {'object' if by_object else 'seg'} colour  active  visible  solo")
    for i in range(session.num_particles):
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
        status = particle_status(session, i)
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


def particle_status(session: SceneSession, i: int) -> Literal["active", "deleted", "inactive"]:
    """How the particle list names particle ``i``: drawn, deleted (drawn as encoded, its object removed since), or
    inactive (the encoder left it off)."""
    if session.is_active(i):
        return "active"
    return "deleted" if session.original_value(i, "z_t")[0] >= session.active_threshold else "inactive"


def _selected_section(session: SceneSession, state: ViewState, fields: UiFields) -> None:
    i = state.selected
    if i is None or not 0 <= i < session.num_particles:
        return
    if not imgui.collapsing_header(f"Particle {i}", imgui.TreeNodeFlags_.default_open):
        return
    for name, width in EDITABLE.items():
        value = list(session.value(i, name))
        if width == 2:
            changed, new = imgui.drag_float2(name, value, DRAG_SPEED[name])
        elif name == "z_t":
            changed, v = imgui.drag_float(name, value[0], DRAG_SPEED[name], 0.0, 1.0)
            new = [v]
        else:
            changed, v = imgui.drag_float(name, value[0], DRAG_SPEED[name])
            new = [v]
        if changed:
            session.set_attribute(i, name, new, gesture="panel")
        if imgui.is_item_deactivated():
            session.end_gesture()
        imgui.same_line()
        if imgui.small_button(f"reset##{name}"):
            session.end_gesture()
            session.set_attribute(i, name, session.original_value(i, name))
            session.end_gesture()
    if imgui.button("Reset particle to encoded values"):
        session.reset_particle(i)
    # the object: every particle of it (one per view that holds it), moved in world metres, deleted, copied
    state.selected, message = draw_object_section(session, i, fields.objects)
    if message:
        fields.status = message


def _edits_section(session: SceneSession, req: UiRequests, fields: UiFields) -> None:
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


def _output_section(req: UiRequests, fields: UiFields, object_selected: bool = False) -> None:
    if not imgui.collapsing_header("Output", imgui.TreeNodeFlags_.default_open):
        return
    _, fields.output_dir = imgui.input_text("folder", fields.output_dir)
    changed, size = imgui.input_int2("shot size (0 = window)", list(fields.shot_size))
    if changed:
        fields.shot_size = [max(0, min(8192, int(v))) for v in size]
    if imgui.button("Screenshot (P)"):
        req.screenshot = True
    imgui.same_line()
    if imgui.button("Export .ply (E)"):
        req.export_ply = True
    if object_selected:
        imgui.same_line()
        if imgui.button("Export object .ply"):
            req.export_object = True
