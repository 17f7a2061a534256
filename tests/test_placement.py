"""Placement that respects the world, on both families' demo scenes with their shipped models: footprints against
the generators' own object sizes (scene.json), a drag past the robot table's edge landing on the floor (and drawn
there, not pressed onto the table's plane), a drag onto another object and a copy ending clear of the others, an
insert at a taken spot moved to a free one; the free-spot search against its geometry."""

from __future__ import annotations

import json
import math

import pytest
import torch

from particlesplat.cli.main import main
from particlesplat.core.world import SUPPORT_Z, Support
from particlesplat.data.scene_meta import default_checkpoint, read_support
from particlesplat.editing.editor import SceneEditor, load_edit_file
from particlesplat.editing.grouping import OPAQUE
from particlesplat.editing.open_scene import demo_scenes, encode_scene
from particlesplat.editing.placement import (
    GAP,
    GRID_STEP,
    Footprint,
    PlacementError,
    fits,
    insert_spot,
    nearest_free,
    scene_footprints,
)
from particlesplat.model import load_model
from viewer.actions import ActionTarget, run
from viewer.session import EditableScene
from viewer.state import ViewState
from viewer.ui.fields import UiRequests

TABLE = Support((0.4, 0.4), -0.8)


def _family(name: str):
    scene = next(p for p in demo_scenes() if ("robot" in str(p)) == (name == "robot"))
    model = load_model(default_checkpoint(scene))
    return model, encode_scene(model, scene), scene


@pytest.fixture(scope="module", params=["tabletop", "robot"])
def family(request):
    return _family(request.param)


@pytest.fixture(scope="module")
def robot():
    return _family("robot")


def editor_of(model, enc) -> SceneEditor:
    return SceneEditor(model, enc.particles, enc.all_cameras, enc.context, world=enc.support)


def true_feet(scene) -> list[tuple[float, float, float]]:
    """(x, y, footprint radius) of each object as the generator placed it (scene.json): a tabletop sphere or
    cylinder its radius, a box its half diagonal; a robot object the half diagonal of its box in x, y."""
    meta = json.loads((scene / "scene.json").read_text())
    out = []
    for o in meta["objects"]:
        if "shape" in o:
            r = math.hypot(o["size"][0], o["size"][1]) if o["shape"] == "box" else o["size"][0]
            out.append((o["center"][0], o["center"][1], r))
        else:
            hx, hy = ((a - b) / 2 for a, b in zip(o["aabb_max"][:2], o["aabb_min"][:2], strict=True))
            out.append((o["center"][0], o["center"][1], math.hypot(hx, hy)))
    return out


def objects_of(ed: SceneEditor) -> dict[int, int]:
    """{object label: its first particle}."""
    labels = ed.objects()
    return {int(k): int(torch.nonzero(labels == k)[0]) for k in labels.unique() if k >= 0}


def opaque_xy(ed: SceneEditor, members: list[int]) -> torch.Tensor:
    g = ed.model.decode(ed.particles, torch.tensor(members), background=False)
    return g.means[g.opacities >= OPAQUE, :2].double()


def share_inside(points: torch.Tensor, discs: list[tuple[float, float, float]]) -> float:
    """The share of ``points`` (N, 2) inside any of ``discs`` (x, y, radius)."""
    inside = torch.zeros(points.shape[0], dtype=torch.bool)
    for x, y, r in discs:
        inside |= torch.hypot(points[:, 0] - x, points[:, 1] - y) < r
    return float(inside.double().mean())


def test_the_robot_scenes_record_a_table_and_the_tabletop_scenes_a_floor():
    for scene in demo_scenes():
        support = read_support(scene)
        if "robot" in str(scene):
            assert support == TABLE  # robosuite's table: 0.8 x 0.8 m, its top 0.8 m above the floor
            assert support.height_at(0.39, -0.39) == SUPPORT_Z and support.height_at(0.41, 0.0) == -0.8
        else:
            assert support == Support() and support.height_at(5.0, 5.0) == SUPPORT_Z


def test_footprints_match_the_objects_the_generator_placed(family):
    """Every object the generator placed has a footprint within 4 cm (tabletop: 6 cm) of its centre and within 25 %
    (+1 cm) of its radius."""
    model, enc, scene = family
    ed = editor_of(model, enc)
    s = ed.scene
    feet = list(scene_footprints(s.decode(), s.objects().labels, s.particles.support_heights()[:, 0]).values())
    tolerance = 0.06 if "robot" not in str(scene) else 0.04
    for x, y, r in true_feet(scene):
        f = min(feet, key=lambda f: math.hypot(f.x - x, f.y - y))
        assert math.hypot(f.x - x, f.y - y) < tolerance, (x, y, f)
        assert abs(f.radius - r) < 0.25 * r + 0.01, (r, f)


def test_a_robot_object_slid_past_the_table_edge_lands_on_the_floor(robot, tmp_path):
    """A drag 0.6 m along +x takes an object past the table's edge (x = 0.4): let go, it rests on the floor 0.8 m
    below, clear of the table's side, drawn there (its Gaussians 0.8 m lower, none pressed onto the table's plane);
    the drag and its landing are one undo step, and its edit file replays it."""
    model, enc, scene = robot
    ed = editor_of(model, enc)
    first = objects_of(ed)
    index = first[min(first)]
    members = ed.object_members(index)
    z_before = opaque_xy(ed, members).shape[0]
    bottom = ed.object_bottom(index)
    n_ops = len(ed.history.undo)
    ed.move_object(index, [0.6, 0.0, 0.0], gesture="floor-drag")
    note = ed.place_object(index, resting=True, gesture="floor-drag")
    ed.end_gesture()
    assert len(ed.history.undo) == n_ops + 1 and "floor" in note and "past the table's edge" in note
    centre = ed.object_centre(index)
    assert ed.support_height(index) == pytest.approx(-0.8)
    assert ed.object_bottom(index) == pytest.approx(-0.8, abs=0.01) and not ed.sunk_objects()
    x, y = float(centre[0]), float(centre[1])
    assert not TABLE.on_table(x, y) and TABLE.table_gap(x, y) >= GAP
    g = ed.model.decode(ed.particles, torch.tensor(members), background=False)
    z = g.means[g.opacities >= OPAQUE, 2]
    assert z.numel() >= 0.9 * z_before and float(z.max()) < -0.5 and float(z.min()) > -0.8 - 0.02
    assert float(z.min()) == pytest.approx(bottom - 0.8, abs=0.05)  # moved down with the object, not squashed
    path = ed.save(tmp_path / "e.yaml", scene=str(scene))
    again = editor_of(model, enc)
    again.apply_file(load_edit_file(path))
    torch.testing.assert_close(again.particles.z_p, ed.particles.z_p, atol=1e-4, rtol=0)
    torch.testing.assert_close(again.particles.support_heights(), ed.particles.support_heights())
    ed.undo()
    assert ed.support_height(index) == SUPPORT_Z and ed.object_bottom(index) == pytest.approx(bottom, abs=1e-6)


def test_a_drag_onto_another_object_ends_clear_of_it(family):
    """Dragged so that its centre lands on another object's, an object ends beside it: their true footprints (the
    generator's sizes) do not overlap, nor do their opaque Gaussians' centres come within the gap, on the same
    surface; the note says it moved."""
    model, enc, scene = family
    ed = editor_of(model, enc)
    first = objects_of(ed)
    (a, ia), (b, ib) = sorted(first.items())[:2]
    ca, cb = ed.object_centre(ia), ed.object_centre(ib)
    ed.move_object(ia, [float(cb[0] - ca[0]), float(cb[1] - ca[1]), 0.0], gesture="floor-drag")
    note = ed.place_object(ia, resting=True, gesture="floor-drag")
    ed.end_gesture()
    assert note.startswith("moved") and "nearest free spot" in note
    now = ed.object_centre(ia)
    truth = true_feet(scene)
    ra = min(truth, key=lambda t: math.hypot(t[0] - ca[0], t[1] - ca[1]))[2]
    rb = min(truth, key=lambda t: math.hypot(t[0] - cb[0], t[1] - cb[1]))[2]
    assert math.hypot(float(now[0] - cb[0]), float(now[1] - cb[1])) > 0.9 * (ra + rb)
    others = [t for t in truth if math.hypot(t[0] - ca[0], t[1] - ca[1]) > 1e-3 + ra * 0.5]  # all but itself
    assert share_inside(opaque_xy(ed, ed.object_members(ia)), others) < 0.05
    assert abs(float(now[2] - ca[2])) < 0.01 and not ed.sunk_objects()  # on the same surface, at its height


def test_a_copy_lands_clear_of_every_object_on_its_support(family):
    """Ctrl+D with an offset that puts the copy onto its original lands it at the nearest free spot: clear of every
    object (the original included), resting on the same surface; the status line names the offset it took."""
    model, enc, scene = family
    es = EditableScene(model, enc, source=str(scene))
    ed = es.editor
    first = objects_of(ed)
    index = first[min(first)]
    said: list[str] = []
    ctx = ActionTarget(es, ViewState(selected=index), UiRequests(), said.append, (0.02, 0.0, 0.0))
    assert run("duplicate", ctx)
    copy = ctx.state.selected
    assert copy is not None and copy >= enc.particles.num
    assert "offset" in said[-1] and "moved" in said[-1]
    done = ed.history.undo[-1]
    assert done.kind == "duplicate" and math.hypot(done.offset[0], done.offset[1]) > 0.05
    others = scene_footprints(ed.decode(), ed.objects(), ed.particles.support_heights()[:, 0], int(ed.objects()[copy]))
    mine = scene_footprints(ed.decode(), ed.objects(), ed.particles.support_heights()[:, 0])[int(ed.objects()[copy])]
    for k, f in others.items():
        assert f.clearance(mine.x, mine.y) >= mine.radius + GAP - GRID_STEP, (k, f, mine)
    assert share_inside(opaque_xy(ed, ed.object_members(copy)), true_feet(scene)) < 0.05  # original included
    assert ed.object_bottom(copy) == pytest.approx(ed.object_bottom(index), abs=0.01)


def test_the_free_spot_search_against_its_geometry():
    """Analytic cases: a free spot is taken as it is; one inside a disc moves to the disc's edge plus the gap (to a
    grid step); past a table's edge the spot is on the floor clear of the table's side; a crowded surface has none
    within reach; every spot returned fits (brute force over a grid of candidates agrees)."""
    disc = Footprint(0.0, 0.0, 0.1)
    assert nearest_free(Support(), [disc], 0.05, (0.5, 0.0)) == (0.5, 0.0)
    spot = nearest_free(Support(), [disc], 0.05, (0.05, 0.0))
    assert spot is not None and 0.1 + 0.05 + GAP <= math.hypot(*spot) <= 0.1 + 0.05 + GAP + GRID_STEP
    assert math.hypot(spot[0] - 0.05, spot[1]) <= 0.1 + 0.05 + GAP - 0.05 + GRID_STEP  # about straight out, +x
    spot = nearest_free(TABLE, [], 0.03, (0.42, 0.0))  # over the floor, too near the table's side
    assert spot is not None and spot[0] >= 0.4 + 0.03 + GAP - 1e-9 and TABLE.height_at(*spot) == -0.8
    assert nearest_free(TABLE, [], 0.03, (0.3, 0.0)) == (0.3, 0.0)  # on the table
    crowd = [Footprint(x * 0.1, y * 0.1, 0.06) for x in range(-5, 6) for y in range(-5, 6)]
    assert nearest_free(Support(), crowd, 0.05, (0.0, 0.0)) is None
    feet = [Footprint(0.1, 0.05, 0.08), Footprint(-0.12, 0.0, 0.05), Footprint(0.0, -0.2, 0.1, -0.8)]
    for wanted in [(0.0, 0.0), (0.35, 0.1), (0.45, -0.2), (-0.1, 0.05)]:
        spot = nearest_free(TABLE, feet, 0.04, wanted)
        assert spot is not None
        height = TABLE.height_at(*wanted)
        assert fits(TABLE, feet, spot, 0.04, height)
        brute = [
            (wanted[0] + i * GRID_STEP, wanted[1] + j * GRID_STEP)
            for i in range(-20, 21)
            for j in range(-20, 21)
            if fits(TABLE, feet, (wanted[0] + i * GRID_STEP, wanted[1] + j * GRID_STEP), 0.04, height)
        ]
        best = min(math.hypot(p[0] - wanted[0], p[1] - wanted[1]) for p in brute)
        assert math.hypot(spot[0] - wanted[0], spot[1] - wanted[1]) == pytest.approx(best, abs=1e-6)
    with pytest.raises(PlacementError, match="no free spot within"):
        insert_spot(Support(), crowd, 0.05, (0.0, 0.0))


def test_object_insert_at_a_taken_spot_moves_to_a_free_one(tmp_path, capsys):
    """``object insert --at`` on another object's centre says so on one line and inserts beside it: the inserted
    object's opaque Gaussians (the composed .ply, read back) keep out of every object the generator placed."""
    from particlesplat import Gaussians

    scene_a, scene_b = demo_scenes()[1], demo_scenes()[0]
    x, y, _ = true_feet(scene_b)[0]
    out = tmp_path / "c.ply"
    args = ["object", "insert", "--scene", str(scene_b), "--from", str(scene_a), "--object", "0"]
    assert main([*args, "--at", f"{x},{y}", "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "is taken: moved" in err and "nearest free spot on the floor" in err
    g = Gaussians.load_ply(out)
    model = load_model(default_checkpoint(scene_b))
    n = encode_scene(model, scene_b).particles.num
    opaque = g.opacities >= OPAQUE
    new = g.means[opaque & (g.owner >= n), :2].double()
    assert new.shape[0] > 0 and share_inside(new, true_feet(scene_b)) < 0.05


def test_the_copy_offset_follows_the_scene_scale(family):
    """The panel's default copy offset is a tenth of the distance the scene's default view looks from: about 0.3 m
    on a tabletop scene, about 0.1 m on a robot table (where 0.3 m would often take a copy off the table)."""
    from viewer.app import initial_view
    from viewer.ui.objects import copy_step

    model, enc, scene = family
    step = copy_step(initial_view(EditableScene(model, enc, source=str(scene)), None, None).look.distance)[0]
    assert (0.08 <= step <= 0.16) if "robot" in str(scene) else (0.25 <= step <= 0.4)
    assert copy_step(3.14) == [0.31, 0.0, 0.0]
