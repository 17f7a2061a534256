"""The "View" section: reset, snapping to input cameras (numbered from 0), segmentation mode, pruning, render scale
while moving, background and the support map behind the Gaussians."""

from __future__ import annotations

from typing import TYPE_CHECKING

from imgui_bundle import imgui

from particlesplat.core.vectors import float3

from ..actions import BY_NAME
from ..session import Scene, session_particles
from ..state import SEG_MODES, SegMode, ViewState
from ..tools.ruler import ruler_distance

if TYPE_CHECKING:
    from .fields import UiRequests


CURRENT_CAMERA = (0.85, 0.55, 0.1, 1.0)  # the button of the input camera the view is at
CONTEXT_CAMERA = (0.2, 0.5, 0.3, 1.0)  # the buttons of the context frames


def camera_button_label(i: int, current: int | None) -> str:
    """The snap button of input camera ``i``: its number, bracketed when the view is at it (``current``)."""
    return f"[{i}]##cam{i}" if i == current else f"{i:2d}##cam{i}"


def draw_view_section(
    session: Scene, state: ViewState, req: UiRequests, counts: tuple[int, int], current: int | None = None
) -> None:
    """The View section; ``current``: the input camera the view is at (its button is marked), or None."""
    if not imgui.collapsing_header("View", imgui.TreeNodeFlags_.default_open):
        return
    if imgui.button(BY_NAME["reset_view"].button_label()):
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
            colour = CURRENT_CAMERA if i == current else CONTEXT_CAMERA if i in (session.context or []) else None
            if colour is not None:
                imgui.push_style_color(imgui.Col_.button, imgui.ImVec4(*colour))
            if imgui.small_button(camera_button_label(i, current)):
                req.snap_camera = i
            if colour is not None:
                imgui.pop_style_color()
        imgui.text("at input camera " + (f"{current} of {len(cams)}" if current is not None else "- (a free view)"))
        shown = current if current is not None else 0
        typed, number = imgui.input_int("camera", shown, 1, 5, imgui.InputTextFlags_.enter_returns_true)
        if typed:
            req.snap_camera = max(0, min(len(cams) - 1, int(number)))
        if imgui.is_item_hovered():
            imgui.set_tooltip("type a camera number and press Enter; PageUp / PageDown (or , and .) step through them")
    changed, idx = imgui.combo("segmentation", SEG_MODES.index(state.seg_mode), [m.value for m in SEG_MODES])
    if changed:
        state.seg_mode = SEG_MODES[idx]
    if session.editor is None and state.seg_mode is not SegMode.NORMAL:
        imgui.text_wrapped(
            "a .ply holds Gaussians, not particles: the particle and object modes show the owner ids it stores "
            + ("(this file stores none, so everything is background)" if not session.owner_ids() else "")
            + "; keypoints and boxes need a model scene"
        )
    changed, value = imgui.slider_float("prune opacity", state.prune, 0.0, 1.0, "%.3f")
    if changed:
        state.prune = max(0.0, value)
    imgui.text(f"Gaussians drawn: {counts[0]:,} of {counts[1]:,}")
    if state.ruler:
        distance = ruler_distance(state)
        imgui.text("ruler: click two points" if distance is None else f"ruler: {distance:.3f} m")
    changed, value = imgui.slider_float("scale while moving", state.moving_scale, 0.25, 1.0, "%.2f")
    if changed:
        state.moving_scale = value
    changed, col = imgui.color_edit3("background", list(state.background))
    if changed:
        state.background = float3(col)
    particles = session_particles(session)
    if particles is not None and particles.support_map is not None:
        changed, on = imgui.checkbox("support map", state.support_map)
        if changed:
            state.support_map = on
        if imgui.is_item_hovered():
            imgui.set_tooltip("behind the Gaussians, the table top as the context views saw it (else one colour)")
