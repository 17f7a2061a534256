"""What the panel's sections share between frames: the requests they make of the app (carried out by
:mod:`viewer.commands`) and the fields they hold."""

from __future__ import annotations

from dataclasses import dataclass, field

from ..settings import PANEL_WIDTH
from .insert import InsertFields
from .objects import ObjectFields


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
    step_camera: int = 0  # snap to the input camera this many after the current one (next / previous camera)
    reset_view: bool = False
    insert: bool = False  # an object of another scene (UiFields.insert)


@dataclass
class UiFields:
    """Persistent text/number fields of the panel."""

    scene_path: str = ""
    edits_path: str = "edits.yaml"
    output_dir: str = "."  # the app sets the user's output folder (particlesplat.core.userdirs.output_dir)
    export_format: str = ".ply"  # the extension of what Export writes (particlesplat.formats.splat_files)
    shot_size: list[int] = field(default_factory=lambda: [0, 0])
    insert: InsertFields = field(default_factory=InsertFields)
    status: str = ""
    objects: ObjectFields = field(default_factory=ObjectFields)
    layout_size: tuple[float, float] = (0.0, 0.0)  # the window size the panel was last placed for
    confirm_overwrite: str | None = None  # a file of another scene that a second Save may replace
    panel_width: float = PANEL_WIDTH  # window points: the panel's width (the user drags its edge; remembered)
    panel_placed: float = 0.0  # window points: the width the panel was last given (0: not yet placed)
