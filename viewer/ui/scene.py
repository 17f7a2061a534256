"""The "Scene" section: the scene shown, its warnings, the model, demo scenes and a folder or a Gaussian file
(.ply, .compressed.ply, .splat, .spz, .sog) to open."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from imgui_bundle import imgui

from particlesplat.editing.open_scene import demo_scene_name, demo_scenes

from ..session import Scene

if TYPE_CHECKING:
    from .fields import UiFields, UiRequests


def draw_scene_section(session: Scene, req: UiRequests, fields: UiFields) -> None:
    if not imgui.collapsing_header("Scene", imgui.TreeNodeFlags_.default_open):
        return
    imgui.text_wrapped(f"{session.source}")
    for warning in session.warnings:
        imgui.push_style_color(imgui.Col_.text, imgui.ImVec4(1.0, 0.75, 0.3, 1.0))
        imgui.text_wrapped(f"warning: {warning}")
        imgui.pop_style_color()
    if session.model_name:
        imgui.text_wrapped(f"model: {session.model_name}")
    scenes = demo_scenes()
    if scenes:
        names = ["(choose)"] + [demo_scene_name(p) for p in scenes]
        shown = Path(session.source).resolve()  # the folder as opened: relative or not
        current = 1 + next((i for i, p in enumerate(scenes) if p.resolve() == shown), -1)
        changed, idx = imgui.combo("demo", current, names)
        if changed and idx != current and idx > 0:
            req.open_path = str(scenes[idx - 1])
    entered, fields.scene_path = imgui.input_text(
        "folder / file", fields.scene_path, imgui.InputTextFlags_.enter_returns_true
    )
    if (imgui.button("Open") or entered) and fields.scene_path.strip():  # Enter in the field opens it too
        req.open_path = fields.scene_path.strip()
