"""The gizmo respects the surface objects rest on: on each robot demo scene, at its default view, 100 random drags
of its handles (arrows, planes and the centre handle) leave no object's bottom below its support; the centre handle
slides an object on its plane as a plain drag does; an edit file that sinks an object is replayed but flagged."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from particlesplat.editing.open_scene import demo_scenes, load_model_scene
from particlesplat.editing.operations import Translate
from viewer.app import initial_view
from viewer.session import EditableScene
from viewer.tools.object_tools import GizmoDrag, object_centre

HANDLES = ((0,), (1,), (2,), (0, 1), (0, 2), (1, 2), "centre")
ROBOT_SCENES = [p for p in demo_scenes() if "robot" in str(p)]


@pytest.fixture(scope="module", params=range(len(ROBOT_SCENES)), ids=lambda i: f"robot-{i}")
def scene(request):
    torch.set_num_threads(1)
    model, enc, _ = load_model_scene(None, ROBOT_SCENES[request.param], None)
    return model, enc


def objects(ed) -> list[int]:
    labels = ed.objects()
    return [int(torch.nonzero(labels == k)[0]) for k in sorted({int(v) for v in labels.tolist() if v >= 0})]


def test_random_gizmo_drags_never_sink_an_object(scene):
    model, enc = scene
    session = EditableScene(model, enc, source=str(enc.path))
    ed = session.editor
    cam = initial_view(session, None, None).camera(640, 480)
    assert not ed.sunk_objects()  # as encoded, every object rests on the table
    rng = np.random.default_rng(0)
    firsts, downs = objects(ed), 0
    for _ in range(100):
        index = int(rng.choice(firsts))
        handle = HANDLES[int(rng.integers(len(HANDLES)))]
        centre = object_centre(ed, index)
        if centre is None:
            continue
        uv, _ = cam.project(centre[None].to(cam.K.dtype))
        mouse = (float(uv[0, 0]), float(uv[0, 1]))
        drag = GizmoDrag()
        for _ in range(3):
            if handle == "centre":  # ImGuizmo moves the centre handle in the screen plane: all three axes
                step = rng.normal(0.0, 0.05, 3)
                nxt = (mouse[0] + float(rng.normal(0.0, 20.0)), mouse[1] + float(rng.normal(0.0, 20.0)))
            else:
                step = np.zeros(3)
                step[list(handle)] = rng.normal(0.0, 0.08, len(handle))
                if 2 in handle:
                    step[2] = -abs(step[2]) if rng.random() < 0.7 else abs(step[2])  # mostly down: into the table
                    downs += 1
                nxt = mouse
            drag.step(ed, index, step, cam, nxt, mouse)
            mouse = nxt
        assert drag.mode == ("floor" if handle == "centre" else "axes")
        drag.stop(ed)
        assert not ed.sunk_objects(), (handle, ed.sunk_objects())
    assert downs > 50 and len(ed.history.undo) > 50  # the drags moved things, many of them down


def test_the_centre_handle_slides_on_the_plane_through_the_centre(scene):
    model, enc = scene
    session = EditableScene(model, enc, source=str(enc.path))
    ed = session.editor
    cam = initial_view(session, None, None).camera(640, 480)
    index = objects(ed)[0]
    centre = object_centre(ed, index)
    uv, _ = cam.project(centre[None].to(cam.K.dtype))
    x, y = float(uv[0, 0]), float(uv[0, 1])
    drag = GizmoDrag()
    drag.step(ed, index, np.array([0.01, -0.02, 0.03]), cam, (x + 30.0, y + 10.0), (x, y))
    drag.stop(ed)
    moved = object_centre(ed, index)
    assert drag.mode is None and len(ed.history.undo) == 1 and ed.history.undo[0].kind == "translate"
    assert ed.history.undo[0].offset[2] == 0.0  # on the plane: no vertical component at all
    assert float((moved[:2] - centre[:2]).norm()) > 0.01


def test_an_edit_file_that_sinks_an_object_is_replayed_and_flagged(scene, tmp_path):
    model, enc = scene
    session = EditableScene(model, enc, source=str(enc.path))
    ed = session.editor
    index = objects(ed)[0]
    ed.apply_op(Translate(pick=ed.pick_for(index), offset=(0.0, 0.0, -0.2)))
    lines = ed.sunk_objects()
    assert len(lines) == 1 and "below its support at 0.00 m" in lines[0] and "z = -0." in lines[0]
    path = ed.save(tmp_path / "sink.yaml")
    fresh = EditableScene(model, enc, source=str(enc.path))
    warning = fresh.load_edits(path)
    assert warning is not None and lines[0] in warning
    assert len(fresh.editor.history.undo) == 1  # allowed: the user may want it
