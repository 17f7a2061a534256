"""The ImGui panel and overlay. They read the session, view state and UI requests, and change
them only through their methods and fields; they never touch GL or the renderer. Each section of the panel is a
module of :mod:`viewer.ui` (scene, view, particles, selected, edits, insert, output)."""

from __future__ import annotations

from imgui_bundle import imgui

from particlesplat.core.camera import Camera

from ..actions import ActionTarget, help_rows
from ..session import Scene
from ..state import ViewState
from .edits import draw_edits_section
from .fields import UiFields, UiRequests
from .insert import draw_insert_section
from .output import draw_output_section
from .particles import draw_particles_section
from .scene import draw_scene_section
from .selected import draw_selected_section
from .view import draw_view_section

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
    draw_scene_section(session, req, fields)
    draw_view_section(session, state, req, counts)

    def status(message: str) -> None:
        fields.status = message

    ctx = ActionTarget(session, state, req, status, fields.objects.copy_offset)
    editor = session.editor
    if editor is not None:
        draw_particles_section(editor, state, swatches)
        draw_selected_section(editor, ctx, fields)
        draw_edits_section(editor, ctx, fields)
        req.insert = draw_insert_section(fields.insert) or req.insert
    draw_output_section(ctx, fields, editor is not None and state.selected is not None)
    if imgui.collapsing_header("Shortcuts"):
        for keys, what in help_rows():
            imgui.bullet_text(f"{keys}: {what}")
    imgui.pop_item_width()
    imgui.end()
