"""Panel buttons of the viewer's actions (:mod:`viewer.actions`): labelled with their keys, greyed when the action
cannot be done now."""

from __future__ import annotations

from typing import TYPE_CHECKING

from imgui_bundle import imgui

from ..actions import BY_NAME

if TYPE_CHECKING:
    from ..actions import ActionContext


def action_button(name: str, ctx: ActionContext, label: str | None = None) -> bool:
    """A button that runs action ``name`` (``label``: the text, default the action's with its key); returns
    whether it ran."""
    action = BY_NAME[name]
    enabled = action.enabled(ctx)
    imgui.begin_disabled(not enabled)
    clicked = imgui.button(label or action.button_label())
    imgui.end_disabled()
    if clicked and enabled:
        action.run(ctx)
    return clicked and enabled
