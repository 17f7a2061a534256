"""The ImGui panel and overlay. They read the session, view state and UI requests, and change
them only through their methods and fields; they never touch GL or the renderer. Each section of the panel is a
module of :mod:`viewer.ui` (scene, view, particles, selected, edits, crop, insert, output)."""

from __future__ import annotations

from imgui_bundle import imgui

from particlesplat.core.camera import Camera

from ..actions import ActionTarget, help_rows
from ..session import Scene
from ..settings import PANEL_WIDTH, clamp_width
from ..state import ViewState
from .crop import draw_crop_section
from .edits import draw_edits_section
from .fields import UiFields, UiRequests
from .insert import draw_insert_section
from .output import draw_output_section
from .particles import draw_particles_section
from .scene import draw_scene_section
from .selected import draw_selected_section
from .view import draw_view_section

PANEL_MARGIN = 10.0  # window points: the panel docks at the right edge, this far from it


def clear_of_panel(camera: Camera, px_per_point: float, panel_width: float = PANEL_WIDTH) -> Camera:
    """``camera`` with its principal point moved left by half the panel's width (``panel_width`` window points,
    ``px_per_point`` camera pixels per window point), so what the orbit looks at sits in the middle of the part
    of the window the panel leaves free. Unchanged when the window is less than twice as wide as the panel."""
    shift = 0.5 * (panel_width + PANEL_MARGIN) * px_per_point
    if camera.width < 4.0 * shift:
        return camera
    K = camera.K.clone()
    K[0, 2] -= shift
    return Camera(K, camera.c2w, camera.width, camera.height)


def draw_overlay(text_lines: list[str]) -> None:
    """Frame time, Gaussian count and active particles in the top-left corner."""
    draw = imgui.get_foreground_draw_list()
    y = 6.0
    for line in text_lines:
        draw.add_text(imgui.ImVec2(9.0, y + 1.0), imgui.IM_COL32(0, 0, 0, 255), line)
        draw.add_text(imgui.ImVec2(8.0, y), imgui.IM_COL32(255, 255, 255, 255), line)
        y += imgui.get_text_line_height() + 2.0


def draw_panel(
    session: Scene,
    state: ViewState,
    req: UiRequests,
    fields: UiFields,
    swatches: dict[int, tuple[float, float, float]],
    counts: tuple[int, int],
    camera: int | None = None,
) -> None:
    """The side panel, docked at the right edge above the status line; its width is the user's (drag its left
    edge: ``fields.panel_width``, remembered by the app). Messages go to the status line, so the panel's layout
    never shifts under the mouse (nor does a drag inside it move it). ``swatches``: particle colours; ``counts``:
    (drawn, total) Gaussians; ``camera``: the input camera the view is at (marked among the camera buttons), or
    None."""
    vp = imgui.get_main_viewport()
    size = (float(vp.work_size.x), float(vp.work_size.y))
    cond = imgui.Cond_.always if size != fields.layout_size else imgui.Cond_.first_use_ever
    fields.layout_size = size  # the panel follows a window resize (docked right, full height)
    width = min(fields.panel_width, max(vp.work_size.x - 2.0 * PANEL_MARGIN, 1.0))
    imgui.set_next_window_pos(
        imgui.ImVec2(vp.work_pos.x + vp.work_size.x - width - PANEL_MARGIN, vp.work_pos.y + 8.0), cond
    )
    imgui.set_next_window_size(imgui.ImVec2(width, vp.work_size.y - 16.0 - status_line_height()), cond)
    if cond == imgui.Cond_.always or fields.panel_placed == 0.0:
        fields.panel_placed = width
    imgui.begin("ParticleSplat", None, imgui.WindowFlags_.no_move)  # docked: a drag inside it moves nothing
    if abs(imgui.get_window_width() - fields.panel_placed) > 0.5:  # the user dragged its edge
        fields.panel_placed = imgui.get_window_width()
        fields.panel_width = clamp_width(fields.panel_placed)
    imgui.push_item_width(-min(150.0, 0.45 * imgui.get_window_width()))
    draw_scene_section(session, req, fields)
    draw_view_section(session, state, req, counts, camera)

    def status(message: str) -> None:
        fields.status = message

    ctx = ActionTarget(session, state, req, status, fields.objects.copy_offset)
    editor = session.editor
    if editor is not None:
        draw_particles_section(editor, state, swatches)
        draw_selected_section(editor, ctx, fields)
        draw_edits_section(editor, ctx, fields)
        draw_crop_section(ctx)
        req.insert = draw_insert_section(fields.insert) or req.insert
    draw_output_section(ctx, fields, editor is not None and state.selected is not None)
    if imgui.collapsing_header("Shortcuts"):
        for keys, what in help_rows():
            imgui.bullet_text(f"{keys}: {what}")
    imgui.pop_item_width()
    imgui.end()


def status_line_height() -> float:
    """Window points the status line takes at the bottom of the window: one line and the window's padding (at
    least imgui's smallest window)."""
    style = imgui.get_style()
    return max(imgui.get_frame_height() + 2.0 * style.window_padding.y, style.window_min_size.y)


def draw_status_line(fields: UiFields, panel_width: float) -> None:
    """The last message (saved, exported, errors: ``fields.status``) on one line at the bottom of the window, where
    it is seen whatever the panel shows; errors in red, the rest in green; hovered, the whole message; a small
    button dismisses it. ``panel_width``: window points the panel takes on the right (0: hidden); the line spans
    the window."""
    if not fields.status:
        return
    vp = imgui.get_main_viewport()
    height = status_line_height()
    imgui.set_next_window_pos(imgui.ImVec2(vp.work_pos.x, vp.work_pos.y + vp.work_size.y - height))
    imgui.set_next_window_size(imgui.ImVec2(vp.work_size.x, height))
    flags = (
        imgui.WindowFlags_.no_decoration
        | imgui.WindowFlags_.no_move
        | imgui.WindowFlags_.no_saved_settings
        | imgui.WindowFlags_.no_focus_on_appearing
        | imgui.WindowFlags_.no_nav
    )
    imgui.begin("##status", None, flags)
    if imgui.small_button("x"):
        fields.status = ""
    imgui.same_line()
    error = fields.status.startswith("error")
    colour = imgui.ImVec4(1.0, 0.45, 0.4, 1.0) if error else imgui.ImVec4(0.55, 1.0, 0.55, 1.0)
    line = " ".join(fields.status.split())  # one line: a long message is cut at the window's edge
    imgui.text_colored(colour, line)
    if imgui.is_item_hovered():
        imgui.set_tooltip(fields.status)
    imgui.end()
