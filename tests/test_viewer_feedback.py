"""What the viewer says and shows back: undo and redo named on the status line, the scale field following every
scale, the input camera the view is at (marked; reached past 9 by keys and a field), a click on the robot arm, and
"mask of selected" with nothing selected. Actions and state, no window (the window tests are test_viewer_app.py)."""

from __future__ import annotations

import pytest
import torch
from viewer_helpers import encoded_robot_demo, recording_target, small_model

from particlesplat.core.panda_arm import arm_points
from particlesplat.data.scene_meta import read_arm_state
from particlesplat.editing.open_scene import demo_scenes, encode_scene
from viewer.actions import BY_NAME, Chord, run
from viewer.app import initial_view
from viewer.commands import carry_out
from viewer.controls import ROBOT_CLICK, click_selection
from viewer.orbit import OrbitCamera
from viewer.session import EditableScene
from viewer.state import EMPTY_MASK, SegMode, ViewState
from viewer.tools.object_tools import GizmoDrag
from viewer.tools.ruler import surface_point
from viewer.ui.fields import UiFields, UiRequests
from viewer.ui.view import camera_button_label


@pytest.fixture(scope="module")
def tabletop():
    model = small_model()
    return model, encode_scene(model, demo_scenes()[0])


@pytest.fixture(scope="module")
def robot():
    return encoded_robot_demo()


def first_object(scene: EditableScene) -> int:
    return int(torch.nonzero(scene.editor.objects() >= 0)[0])


def test_undo_and_redo_name_what_they_did(tabletop):
    scene = EditableScene(*tabletop)
    ctx, said = recording_target(scene)
    assert run("undo", ctx) and said[-1] == "nothing to undo"
    ctx.state.selected = first_object(scene)
    members = ", ".join(map(str, scene.editor.object_members(ctx.state.selected)))
    assert run("grow", ctx) and run("shrink", ctx)
    assert run("undo", ctx) and said[-1] == f"undid: scale object of particle{'s' * (',' in members)} {members} x0.909"
    assert run("undo", ctx) and said[-1].startswith("undid: scale object of") and said[-1].endswith("x1.1")
    assert run("redo", ctx) and said[-1].startswith("redid: scale object of") and said[-1].endswith("x1.1")
    assert run("redo", ctx) and said[-1].endswith("x0.909")
    assert run("redo", ctx) and said[-1] == "nothing to redo"


def test_a_drag_of_the_scale_handles_is_named_by_its_whole_factor(tabletop):
    scene = EditableScene(*tabletop)
    ed = scene.editor
    index = first_object(scene)
    drag = GizmoDrag()
    for total in (1.1, 1.3, 1.5):  # what the handles show, from the drag's start
        assert drag.scale(ed, index, total) is None
    drag.stop(ed)
    assert ed.undo().label.endswith("x1.5")


def test_the_scale_field_follows_every_scale(tabletop):
    """The panel's scale field reads the object's scale as it is: three grows are 1.1 cubed, an undo takes one back,
    a drag of the scale handles multiplies in, another object stays at 1."""
    scene = EditableScene(*tabletop)
    ed = scene.editor
    ctx, _ = recording_target(scene)
    index = ctx.state.selected = first_object(scene)
    assert ed.object_scale(index) == pytest.approx(1.0, abs=1e-9)
    for _ in range(3):
        assert run("grow", ctx)
    assert ed.object_scale(index) == pytest.approx(1.1**3, rel=1e-5)
    ed.undo()
    assert ed.object_scale(index) == pytest.approx(1.1**2, rel=1e-5)
    drag = GizmoDrag()
    drag.scale(ed, index, 0.8)
    drag.stop(ed)
    assert ed.object_scale(index) == pytest.approx(1.1**2 * 0.8, rel=1e-5)
    ed.move_object(index, [0.05, 0.0, 0.0])  # a move keeps it
    assert ed.object_scale(index) == pytest.approx(1.1**2 * 0.8, rel=1e-5)
    other = next(i for i in range(ed.num_particles) if int(ed.objects()[i]) >= 0 and i not in ed.object_members(index))
    assert ed.object_scale(other) == pytest.approx(1.0, abs=1e-9)
    copy = ed.duplicate_object(index, [0.0, 0.6, 0.0])  # a copy is as large as what it copies
    assert ed.object_scale(copy) == pytest.approx(1.1**2 * 0.8, rel=1e-5)


def test_the_current_camera_is_marked_and_every_camera_is_reached(tabletop):
    """Snapping marks the camera until the view moves; next / previous (PageDown / PageUp) step through all 21,
    past 9, wrapping; a typed number past the last is refused with a line."""
    scene = EditableScene(*tabletop)
    cams = scene.cameras
    assert len(cams) == 21
    orbit = OrbitCamera.from_view(initial_view(scene, None, None))
    assert orbit.current_camera is None
    orbit.snap(cams[12], 12)
    assert orbit.current_camera == 12 and camera_button_label(12, 12) == "[12]##cam12"
    assert camera_button_label(11, 12) == "11##cam11"
    orbit.orbit(5.0, 0.0)
    assert orbit.current_camera is None  # moved: at no camera
    assert orbit.step_camera(cams, 1) == 13 and orbit.current_camera == 13  # from the last one snapped to
    for _ in range(7):
        orbit.step_camera(cams, 1)
    assert orbit.current_camera == 20 and orbit.step_camera(cams, 1) == 0 and orbit.step_camera(cams, -1) == 20
    fresh = OrbitCamera.from_view(orbit.home)
    assert fresh.step_camera(cams, 1) == 0 and OrbitCamera.from_view(orbit.home).step_camera(cams, -1) == 20

    ctx, _ = recording_target(scene)
    assert BY_NAME["next_camera"].keys[0] == Chord("page_down") and Chord("page_up").label() == "PageUp"
    assert run("next_camera", ctx) and ctx.requests.step_camera == 1
    assert run("previous_camera", ctx) and ctx.requests.step_camera == -1

    class Host:
        def __init__(self) -> None:
            self.orbit, self.session, self.state, self.fields = (
                OrbitCamera.from_view(orbit.home),
                scene,
                ViewState(),
                UiFields(),
            )

    host = Host()
    carry_out(host, UiRequests(snap_camera=17))
    assert host.orbit.current_camera == 17 and host.fields.status == "input camera 17 of 21 (0 .. 20)"
    carry_out(host, UiRequests(step_camera=1))
    assert host.orbit.current_camera == 18
    carry_out(host, UiRequests(snap_camera=21))
    assert (
        host.orbit.current_camera == 18
        and host.fields.status == "error: no input camera 21: this scene has 21, numbered 0 .. 20"
    )


def test_mask_of_selected_with_nothing_selected_says_so(tabletop):
    scene = EditableScene(*tabletop)
    ctx, said = recording_target(scene)
    assert ctx.state.seg_mode is SegMode.NORMAL  # M steps through the modes to "mask of selected"
    while ctx.state.seg_mode is not SegMode.MASK_SELECTED:
        run("next_mode", ctx)
    assert said[-1] == EMPTY_MASK and ctx.state.mode_note() == EMPTY_MASK
    ctx.state.selected = first_object(scene)
    assert ctx.state.mode_note() is None
    run("next_mode", ctx)
    assert said[-1] == f"mode: {ctx.state.seg_mode.value}"


def test_a_click_on_the_robot_arm_says_it_is_no_object(robot):
    """On a robot demo scene, the surface under a pixel where the arm's forearm shows lies on the arm: the click
    selects nothing and says why; a click on an object selects it; a click on the table says nothing."""
    model, enc, path = robot
    scene = EditableScene(model, enc, source=str(path))
    ed = scene.editor
    g = ed.decode()
    wrist = torch.as_tensor(arm_points(read_arm_state(path))[7], dtype=torch.float64)  # a point on the forearm
    for view in (4, 10, 16):  # from three input cameras
        cam = enc.all_cameras[view].to("cpu", torch.float64)
        (u, v), depth = (t[0] for t in cam.project(wrist[None]))
        assert float(depth) > 0 and 0 <= u < cam.width and 0 <= v < cam.height
        point = surface_point(g, cam, float(u), float(v))
        assert point is not None and ed.on_robot(point)
        assert click_selection(scene, -1, lambda p=point: p) == (None, ROBOT_CLICK)
    obj = first_object(scene)
    centre = ed.object_centre(obj)
    assert centre is not None and not ed.on_robot(centre)
    assert click_selection(scene, obj, lambda: centre) == (obj, "")
    table = torch.tensor([0.3, -0.3, 0.0], dtype=torch.float64)  # a table corner, away from the arm's base at -x
    assert not ed.on_robot(table) and click_selection(scene, -1, lambda: table) == (None, "")
    assert click_selection(scene, -1, lambda: None) == (None, "")
