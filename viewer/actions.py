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
    step_camera: int


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
        names = {"delete": "Del", "escape": "Esc", "equal": "=", "minus": "-", "keypad_add": "Keypad +"}
        names |= {
            "keypad_subtract": "Keypad -",
            "page_up": "PageUp",
            "page_down": "PageDown",
            "comma": ",",
            "period": ".",
        }
        name = names.get(self.key, self.key.lstrip("_").upper())
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
    """Copy the selected particle's object about ``offset`` (3,) metres away, on the surface there and clear of the
    other objects (:meth:`SceneEditor.copy_object`; one operation); the copy becomes the selection. Returns (new
    selection, status message: the offset it took, and why it differs from ``offset``)."""
    if selected is None:
        return selected, "select an object first (click it)"
    try:
        copy, note = editor.copy_object(selected, [float(v) for v in offset])
    except (MoveError, PickError) as e:
        return selected, f"error: {e}"
    members = editor.object_members(copy)
    done = editor.history.undo[-1]
    taken = getattr(done, "offset", offset)
    return copy, (
        f"copied the object: new particles {', '.join(map(str, members))}, offset {_metres(taken)}"
        + (f"; {note}" if note else "")
    )


SCALE_STEP = 1.1  # one press of the grow key; the shrink key divides by it


def scale_selected(editor: SceneEditor, selected: int | None, factor: float) -> tuple[int | None, str]:
    """Scale the selected particle's object ``factor`` times about its resting centre, on its support (one
    operation). Returns (selection, status message)."""
    if selected is None:
        return selected, "select an object first (click it)"
    try:
        editor.scale_object(selected, factor)
    except MoveError as e:
        return selected, f"error: {e}"
    return selected, f"scaled the object of {_members(editor.object_members(selected))} x{factor:.3g}"


def merge_selected(editor: SceneEditor, selected: int | None, previous: int | None) -> tuple[int | None, str]:
    """Join the selected particle's object with the previously selected one's (one operation)."""
    if selected is None or previous is None:
        return selected, "select two objects first (click one, then the other)"
    try:
        editor.merge_objects(selected, previous)
    except (MoveError, IndexError) as e:
        return selected, f"error: {e}"
    return selected, f"merged: one object of {_members(editor.object_members(selected))} (Ctrl+Z separates them)"


def split_selected(editor: SceneEditor, selected: int | None) -> tuple[int | None, str]:
    """Take the selected particle out of its object into an object of its own (one operation)."""
    if selected is None:
        return selected, "select a particle first (click it)"
    try:
        editor.split_particle(selected)
    except MoveError as e:
        return selected, f"error: {e}"
    return selected, f"particle {selected} is an object of its own now"


def _editable(ctx: ActionContext) -> bool:
    return ctx.session.editor is not None


def _selected(ctx: ActionContext) -> bool:
    return ctx.session.editor is not None and ctx.state.selected is not None


def _undo(ctx: ActionContext) -> None:
    """Undo the last edit and name it on the status line ("undid: scale object of particles 3, 7 x1.1")."""
    if ctx.session.editor is not None:
        op = ctx.session.editor.undo()
        ctx.status(f"undid: {op.label}" if op is not None else "nothing to undo")


def _redo(ctx: ActionContext) -> None:
    """Redo the last undone edit and name it on the status line."""
    if ctx.session.editor is not None:
        op = ctx.session.editor.redo()
        ctx.status(f"redid: {op.label}" if op is not None else "nothing to redo")


def _on_selection(do: Callable[[SceneEditor, int | None], tuple[int | None, str]]) -> Callable[[ActionContext], None]:
    """An action that does ``do`` on the scene's editor and the selection, and shows what it did."""

    def run(ctx: ActionContext) -> None:
        if ctx.session.editor is not None:
            ctx.state.selected, message = do(ctx.session.editor, ctx.state.selected)
            ctx.status(message)

    return run


_remove = _on_selection(remove_selected)
_grow = _on_selection(lambda ed, s: scale_selected(ed, s, SCALE_STEP))
_shrink = _on_selection(lambda ed, s: scale_selected(ed, s, 1.0 / SCALE_STEP))
_split = _on_selection(split_selected)


def _duplicate(ctx: ActionContext) -> None:
    _on_selection(lambda ed, s: duplicate_selected(ed, s, ctx.copy_offset))(ctx)


def _merge(ctx: ActionContext) -> None:
    _on_selection(lambda ed, s: merge_selected(ed, s, ctx.state.previous))(ctx)


def _two_selected(ctx: ActionContext) -> bool:
    return _selected(ctx) and ctx.state.previous is not None


def _request(name: str) -> Callable[[ActionContext], None]:
    """An action that asks the app for ``name`` (a flag of :class:`UiRequests`) after the frame."""
    return lambda ctx: setattr(ctx.requests, name, True)


def _snap(i: int) -> Callable[[ActionContext], None]:
    return lambda ctx: setattr(ctx.requests, "snap_camera", i)


def _step(by: int) -> Callable[[ActionContext], None]:
    """Ask for the input camera ``by`` after the current one (or the last one snapped to), wrapping around."""
    return lambda ctx: setattr(ctx.requests, "step_camera", by)


def _has_cameras(ctx: ActionContext) -> bool:
    return bool(ctx.session.cameras)


def _toggle(name: str) -> Callable[[ActionContext], None]:
    return lambda ctx: setattr(ctx.state, name, not getattr(ctx.state, name))


def _ruler(ctx: ActionContext) -> None:
    ctx.state.ruler = not ctx.state.ruler
    ctx.state.ruler_points.clear()
    ctx.status("ruler on: click two points on surfaces" if ctx.state.ruler else "ruler off")


def _next_mode(ctx: ActionContext) -> None:
    ctx.state.seg_mode = SEG_MODES[(SEG_MODES.index(ctx.state.seg_mode) + 1) % len(SEG_MODES)]
    ctx.status(ctx.state.mode_note() or f"mode: {ctx.state.seg_mode.value}")


def _crop(ctx: ActionContext) -> None:
    """Switch the crop box on or off (:func:`viewer.tools.crop_box.toggle_crop`: one edit)."""
    from .tools.crop_box import toggle_crop

    ctx.status(toggle_crop(ctx.session))


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
    ),
    Action(
        "save_edits",
        "Save edits",
        "save the edits to the 'edits YAML' path",
        (Chord("s", ctrl=True),),
        _request("save_edits"),
        _editable,
    ),
    Action("delete", "Delete object", "delete the selected object", (Chord("delete"),), _remove, _selected),
    Action("duplicate", "Duplicate", "duplicate the selected object", (Chord("d", ctrl=True),), _duplicate, _selected),
    Action(
        "grow",
        "Grow",
        "grow the selected object 10 % (about its centre, on its support)",
        (Chord("equal"), Chord("keypad_add")),
        _grow,
        _selected,
    ),
    Action(
        "shrink",
        "Shrink",
        "shrink the selected object 10 %",
        (Chord("minus"), Chord("keypad_subtract")),
        _shrink,
        _selected,
    ),
    Action(
        "merge",
        "Merge with previous",
        "merge the selected object with the one selected before it",
        (Chord("j"),),
        _merge,
        _two_selected,
    ),
    Action(
        "split",
        "Split particle off",
        "take the selected particle out of its object",
        (Chord("u"),),
        _split,
        _selected,
    ),
    Action(
        "gizmo_scale",
        "Scale handles",
        "switch the gizmo between its move and its scale handles",
        (Chord("s"),),
        _toggle("gizmo_scale"),
        _editable,
    ),
    Action(
        "ruler",
        "Ruler",
        "ruler on / off: clicks pick two surface points, the distance in metres",
        (Chord("l"),),
        _ruler,
    ),
    Action(
        "crop",
        "Crop box",
        "crop box on / off: hide the Gaussians outside it (a robot scene's workspace until one is set)",
        (Chord("c"),),
        _crop,
        _editable,
    ),
    Action("reset_view", "Reset view", "reset the view", (Chord("r"),), _request("reset_view")),
    Action("screenshot", "Screenshot", "screenshot (no UI)", (Chord("p"), Chord("f12")), _request("screenshot")),
    Action(
        "export_ply",
        "Export",
        "export the drawn Gaussians (format: Output section)",
        (Chord("e"),),
        _request("export_ply"),
    ),
    Action("next_mode", "Next mode", "next segmentation mode", (Chord("m"),), _next_mode),
    Action("panel", "Panel", "hide / show the panel", (Chord("h"),), _toggle("panel")),
    Action("overlay", "Overlay", "hide / show the overlay", (Chord("o"),), _toggle("overlay")),
    Action("deselect", "Deselect", "deselect", (Chord("escape"),), _deselect),
    Action(
        "next_camera",
        "Next camera",
        "snap to the next input camera (every camera of the scene, past 9 too)",
        (Chord("page_down"), Chord("period")),
        _step(1),
        _has_cameras,
    ),
    Action(
        "previous_camera",
        "Previous camera",
        "snap to the previous input camera",
        (Chord("page_up"), Chord("comma")),
        _step(-1),
        _has_cameras,
    ),
    *(
        Action(
            f"snap_{i}",
            f"Camera {i}",
            "snap to input camera 0 .. 9 (numbered as --context and render --view)",
            (Chord(f"_{i}"),),
            _snap(i),
            keys_help="0 .. 9",
        )
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
    ("drag a crop box handle (a dot on a face)", "move that face of the box along its axis"),
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
