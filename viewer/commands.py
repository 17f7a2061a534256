"""The UI requests of a frame (:class:`viewer.ui.panel.UiRequests`), carried out after it: view resets and snaps,
opening a scene, saving and loading edits, screenshots, exports and inserts. A failure becomes the status line's
error: a bad path or file never closes the viewer. Every file written is first asked of the scene's guard
(:meth:`viewer.session.SceneFiles.guard_output`): none replaces what the scene was opened from or lies in a live
run's folder."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Protocol

import torch

from .screenshot import BUNDLE, export_bundle, export_ply
from .session import EditableScene
from .tools.crop_box import export_crop

if TYPE_CHECKING:
    from .orbit import OrbitCamera
    from .scene_view import SceneView
    from .session import Scene
    from .state import ViewState
    from .ui.panel import UiFields, UiRequests


class CommandHost(Protocol):
    """What the commands use of the app: its scene, view and fields, opening a scene, a numbered screenshot."""

    orbit: OrbitCamera
    session: Scene
    state: ViewState
    fields: UiFields
    scene_view: SceneView

    def open_in_background(self, path: str) -> None: ...

    def screenshot_numbered(self) -> Path: ...


def carry_out(host: CommandHost, req: UiRequests) -> None:
    """Do what ``req`` asks, in a fixed order; the status line says what was done, or the error."""
    fields = host.fields
    try:
        if req.reset_view:
            host.orbit.reset()
        cams = host.session.cameras
        if req.snap_camera is not None:
            if 0 <= req.snap_camera < len(cams):
                host.orbit.snap(cams[req.snap_camera], req.snap_camera)
                fields.status = f"input camera {req.snap_camera} of {len(cams)} (0 .. {len(cams) - 1})"
            else:
                fields.status = f"error: no input camera {req.snap_camera}: this scene has " + (
                    f"{len(cams)}, numbered 0 .. {len(cams) - 1}" if cams else "none (a Gaussian file)"
                )
        if req.step_camera and cams:
            index = host.orbit.step_camera(cams, req.step_camera)
            fields.status = f"input camera {index} of {len(cams)} (0 .. {len(cams) - 1})"
        if req.open_path:
            host.open_in_background(req.open_path)
        editable = host.session if isinstance(host.session, EditableScene) else None
        if req.save_edits and editable is not None:
            save_edits(editable, fields)
        if req.load_edits and editable is not None:
            warning = editable.load_edits(fields.edits_path)
            fields.status = f"loaded edits from {Path(fields.edits_path).resolve()}" + (
                f"; warning: {warning}" if warning else ""
            )
        if req.screenshot:
            path = host.screenshot_numbered()
            fields.status = f"saved screenshot {Path(path).resolve()}"
        guard = lambda p: host.session.guard_output("export", p)  # noqa: E731
        if req.export_ply:
            g = host.scene_view.visible_gaussians(host.session, host.state)
            g, note = export_crop(host.session, g)  # a robot scene with no box set: its workspace, as export does
            if fields.export_format == BUNDLE:
                path = export_bundle(fields.output_dir, g, host.session)
            else:
                path = export_ply(fields.output_dir, g, fields.export_format, guard)
            fields.status = f"exported {Path(path).resolve()}" + (f"; {note}" if note else "")
        editor = host.session.editor
        if req.insert and editor is not None:
            from .ui.insert import insert_from_fields

            host.state.selected, fields.status = insert_from_fields(editor, fields.insert)
        if req.export_object and host.state.selected is not None and editor is not None:
            members = editor.object_members(host.state.selected)  # its Gaussians, as drawn
            g = editor.model.decode(editor.particles, torch.tensor(members), background=False)
            g = g.subset(g.opacities >= host.state.prune).detach().to("cpu")
            suffix = fields.export_format if fields.export_format != BUNDLE else ".ply"
            path = export_ply(fields.output_dir, g, suffix, guard)
            fields.status = f"exported object of particles {members} to {Path(path).resolve()}"
    except Exception as e:  # noqa: BLE001 - a bad path or file must not close the app: show it
        fields.status = f"error: {e}"


def save_edits(session: EditableScene, fields: UiFields) -> Path | None:
    """Save the edits to the 'edits YAML' path. A file that holds another scene's edits (or is no edit file) is not
    replaced: the status line says so, and a second Save to the same path replaces it. A path the scene was opened
    from (the checkpoint, a file of the scene folder) or in a live run's folder is refused, every time."""
    path = fields.edits_path
    session.guard_output("edits file", path)
    conflict = session.foreign_edit_file(path)
    target = str(Path(path).resolve())
    if conflict and fields.confirm_overwrite != target:
        fields.confirm_overwrite = target
        fields.status = f"error: not saved: {conflict}. Save again to replace it, or choose another path"
        return None
    fields.confirm_overwrite = None
    out = session.save_edits(path)
    fields.status = f"saved {len(session.editor.history.undo)} edit operation(s) to {out.resolve()}"
    return out
