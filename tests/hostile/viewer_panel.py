"""The viewer's panel commands without a window, for the runner's ``call`` cases: the App's own methods (numbered
screenshot, export, Save edits, opening a scene with its autosave) and :func:`viewer.commands.carry_out` on a
session loaded as the viewer loads it; only the screenshot's GL image is a blank array of the shot size."""

from __future__ import annotations

import sys

import numpy as np

from viewer import app as A
from viewer.commands import carry_out
from viewer.launch import build_parser
from viewer.ui.panel import UiFields, UiRequests


class _Drawn:
    """What the scene view would draw: every Gaussian of the session (nothing hidden, nothing pruned)."""

    def visible_gaussians(self, session, state):
        return session.gaussians().detach().to("cpu")


class HeadlessApp(A.App):
    """An :class:`viewer.app.App` without a window or GL context: the attributes the commands use, set as
    ``App.__init__`` sets them."""

    def __init__(self, argv: list[str]) -> None:  # no window: App.__init__ would create its GL context
        self.args = build_parser().parse_args(argv)
        self.session = A.load_session(self.args)
        self.orbit = A.OrbitCamera.from_view(A.initial_view(self.session, None, None))
        self.state = A.ViewState(panel=True, background=A.scene_background(self.session.model))
        self.req = UiRequests()
        self.fields = UiFields(output_dir=str(self.args.output_dir))
        self.fields.edits_path = str(self.session.default_edits_path(self.fields.output_dir))
        self.fields.shot_size = [32, 24]
        self.swatches, self._swatched = A.particle_swatches(self.session), self.session.num_owners()
        self.scene_view = _Drawn()
        self.opening = None
        self.background_open = False  # a scene opens at once, as with frames drawn at once

    def screenshot_image(self, camera):
        return np.zeros((camera.height, camera.width, 3), np.float32)


def panel(request: str, value: str, *viewer_argv: str) -> int:
    """Carry out one panel request on the viewer opened with ``viewer_argv``; print the status line on stderr.

    ``request``: ``screenshot`` or ``export`` (``value``: the output folder), ``save`` (``value``: the edits path;
    Save is pressed twice, as a user confirms replacing a file), ``open`` (``value``: the scene to open after an
    unsaved edit). Returns 2 when the status line is an error, 3 when a refused ``open`` replaced the scene anyway,
    else 0."""
    app = HeadlessApp(list(viewer_argv))
    shown = app.session
    for _ in range(2 if request == "save" else 1):
        req = UiRequests()
        if request in ("screenshot", "export"):
            app.fields.output_dir = value
            setattr(req, "export_ply" if request == "export" else request, True)
        elif request == "save":
            app.session.editor.move_object(0, [0.05, 0.0, 0.0])
            app.fields.edits_path, req.save_edits = value, True
        elif request == "open":
            app.session.editor.move_object(0, [0.05, 0.0, 0.0])  # unsaved: autosaved before the scene is replaced
            req.open_path = value
        carry_out(app, req)
    print(app.fields.status, file=sys.stderr)
    if request == "open" and app.fields.status.startswith("error") and app.session is not shown:
        return 3
    return 2 if app.fields.status.startswith("error") else 0
