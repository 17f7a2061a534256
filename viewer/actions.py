"""The viewer's actions: one table (:data:`ACTIONS`) of what a key or a panel button does. Each action has a name,
a label, its keys, when it is enabled and what it runs; the key handler (:mod:`viewer.controls`), the panel's
buttons (:func:`viewer.ui.buttons.action_button`) and the shortcut help (:func:`help_rows`) all read it.

Actions change the scene only through its editor (do/undo operations) and the app only through its requests
(:class:`viewer.ui.fields.UiRequests`), so they never draw and never see the app or imgui.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

from particlesplat.editing.editor import PickError, SceneEditor
from particlesplat.editing.move import MoveError

from .state import SEG_MODES

if TYPE_CHECKING:
    from .session import Scene
    from .state import ViewState


class Requests(Protocol):
    """The app's requests the actions and buttons make (:class:`viewer.ui.fields.UiRequests` has them)."""

    save_edits: bool
    load_edits: bool
    reset_view: bool
    screenshot: bool
    export_ply: bool
    export_object: bool
    snap_camera: int | None


class ActionContext(Protocol):
    """What an action works on: the scene, the view state, the app's requests, the status line and the copy
    offset (3,) metres (:class:`viewer.controls.Viewport` is one; the panel builds another)."""

    @property
    def session(self) -> Scene: ...

    @property
    def state(self) -> ViewState: ...

    @property
    def requests(self) -> Requests: ...

    @property
    def status(self) -> Callable[[str], None]: ...

    @property
    def copy_offset(self) -> Sequence[float]: ...


@dataclass(frozen=True)
class Chord:
    """A key (an ``imgui.Key`` member name: ``"z"``, ``"delete"``, ``"_0"``) with Ctrl and Shift held or not."""

    key: str
    ctrl: bool = False
    shift: bool = False

    def label(self) -> str:
        name = {"delete": "Del", "escape": "Esc"}.get(self.key, self.key.lstrip("_").upper())
        return "Ctrl+" * self.ctrl + "Shift+" * self.shift + name


@dataclass(frozen=True)
class Action:
    """One thing the user can do by key or button.

    Attributes:
        name: its id; label: the button's text; help: what the shortcut help says it does.
        keys: its chords (none: a button only); keys_help: how the help names them when not by the chords.
        run: does it; enabled: whether it can be done now (a disabled action's keys do nothing).
    """

    name: str
    label: str
    help: str
    keys: tuple[Chord, ...]
    run: Callable[[ActionContext], None]
    enabled: Callable[[ActionContext], bool] = lambda ctx: True
    keys_help: str | None = None
    repeat: bool = False  # a held key repeats it (undo, redo)

    def keys_label(self) -> str:
        return self.keys_help or " / ".join(c.label() for c in self.keys)

    def button_label(self) -> str:
        """The label with its first chord, as a panel button shows it."""
        return f"{self.label} ({self.keys[0].label()})" if self.keys else self.label


def _members(members: list[int]) -> str:
    return f"particle{'s' if len(members) > 1 else ''} {', '.join(map(str, members))}"


def _metres(v: Sequence[float]) -> str:
    return "(" + ", ".join(f"{float(x):+.3f}" for x in v) + ") m"


def remove_selected(editor: SceneEditor, selected: int | None) -> tuple[int | None, str]:
    """Remove the selected particle's object (one operation). Returns (new selection, status message)."""
    if selected is None:
        return selected, "select an object first (click it)"
    members = editor.object_members(selected)
    editor.remove_object(selected)
    return None, f"removed the object of {_members(members)} (Ctrl+Z brings it back)"


def duplicate_selected(editor: SceneEditor, selected: int | None, offset: Sequence[float]) -> tuple[int | None, str]:
    """Copy the selected particle's object, moved by ``offset`` (3,) metres (one operation); the copy becomes
    the selection. Returns (new selection, status message)."""
    if selected is None:
        return selected, "select an object first (click it)"
    try:
        copy = editor.duplicate_object(selected, [float(v) for v in offset])
    except (MoveError, PickError) as e:
        return selected, f"error: {e}"
    members = editor.object_members(copy)
    return copy, f"copied the object: new particles {', '.join(map(str, members))}, offset {_metres(offset)}"


def _editable(ctx: ActionContext) -> bool:
    return ctx.session.editor is not None


def _selected(ctx: ActionContext) -> bool:
    return ctx.session.editor is not None and ctx.state.selected is not None


def _undo(ctx: ActionContext) -> None:
    if ctx.session.editor is not None:
        ctx.session.editor.undo()


def _redo(ctx: ActionContext) -> None:
    if ctx.session.editor is not None:
        ctx.session.editor.redo()


def _remove(ctx: ActionContext) -> None:
    if ctx.session.editor is not None:
        ctx.state.selected, message = remove_selected(ctx.session.editor, ctx.state.selected)
        ctx.status(message)


def _duplicate(ctx: ActionContext) -> None:
    if ctx.session.editor is not None:
        ctx.state.selected, message = duplicate_selected(ctx.session.editor, ctx.state.selected, ctx.copy_offset)
        ctx.status(message)


def _request(name: str) -> Callable[[ActionContext], None]:
    """An action that asks the app for ``name`` (a flag of :class:`UiRequests`) after the frame."""
    return lambda ctx: setattr(ctx.requests, name, True)


def _snap(i: int) -> Callable[[ActionContext], None]:
    return lambda ctx: setattr(ctx.requests, "snap_camera", i)


def _toggle(name: str) -> Callable[[ActionContext], None]:
    return lambda ctx: setattr(ctx.state, name, not getattr(ctx.state, name))


def _next_mode(ctx: ActionContext) -> None:
    ctx.state.seg_mode = SEG_MODES[(SEG_MODES.index(ctx.state.seg_mode) + 1) % len(SEG_MODES)]


def _deselect(ctx: ActionContext) -> None:
    ctx.state.selected = None


ACTIONS: tuple[Action, ...] = (
    Action("undo", "Undo", "undo", (Chord("z", ctrl=True),), _undo, _editable, repeat=True),
    Action(
        "redo",
        "Redo",
        "redo",
        (Chord("z", ctrl=True, shift=True), Chord("y", ctrl=True)),
        _redo,
        _editable,
        repeat=True,
    ),  # fmt: skip
    Action(
        "save_edits",
        "Save edits",
        "save the edits to the 'edits YAML' path",
        (Chord("s", ctrl=True),),
        _request("save_edits"),
        _editable,
    ),  # fmt: skip
    Action("delete", "Delete object", "delete the selected object", (Chord("delete"),), _remove, _selected),
    Action("duplicate", "Duplicate", "duplicate the selected object", (Chord("d", ctrl=True),), _duplicate, _selected),
    Action("reset_view", "Reset view", "reset the view", (Chord("r"),), _request("reset_view")),
    Action("screenshot", "Screenshot", "screenshot (no UI)", (Chord("p"), Chord("f12")), _request("screenshot")),
    Action("export_ply", "Export .ply", "export the drawn Gaussians to .ply", (Chord("e"),), _request("export_ply")),
    Action("next_mode", "Next mode", "next segmentation mode", (Chord("m"),), _next_mode),
    Action("panel", "Panel", "hide / show the panel", (Chord("h"),), _toggle("panel")),
    Action("overlay", "Overlay", "hide / show the overlay", (Chord("o"),), _toggle("overlay")),
    Action("deselect", "Deselect", "deselect", (Chord("escape"),), _deselect),
    *(
        Action(
            f"snap_{i}",
            f"Camera {i}",
            "snap to input camera 0 .. 9 (numbered as --context and render --view)",
            (Chord(f"_{i}"),),
            _snap(i),
            keys_help="0 .. 9",
        )  # fmt: skip
        for i in range(10)
    ),
)
BY_NAME = {a.name: a for a in ACTIONS}

MOUSE_HELP = (
    ("left drag", "orbit"),
    ("right / middle drag", "pan"),
    ("wheel", "zoom"),
    ("click", "select the particle under the cursor (its object is outlined)"),
    ("left drag on the selected object", "slide it on the floor (world X / Y)"),
    ("Shift + left drag", "slide the selected object on the floor from anywhere"),
    ("Ctrl + left drag", "lift or lower the selected object (world Z)"),
    ("gizmo arrows / planes", "move the selected object along world X, Y or Z, or in a plane"),
)


@dataclass
class ActionTarget:
    """An :class:`ActionContext` built from its parts (the panel's)."""

    session: Scene
    state: ViewState
    requests: Requests
    status: Callable[[str], None]
    copy_offset: Sequence[float]


def run(name: str, ctx: ActionContext) -> bool:
    """Run action ``name`` if it is enabled; returns whether it ran."""
    action = BY_NAME[name]
    if not action.enabled(ctx):
        return False
    action.run(ctx)
    return True


def help_rows() -> list[tuple[str, str]]:
    """(keys, what) rows of the shortcut help: the mouse, then every action with keys (one row per help text)."""
    rows = list(MOUSE_HELP)
    seen: set[str] = set()
    for a in ACTIONS:
        if a.keys and a.help not in seen:
            seen.add(a.help)
            rows.append((a.keys_label(), a.help))
    return rows
