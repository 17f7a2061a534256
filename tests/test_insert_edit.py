"""Insert an object of another scene as an edit: the operation appends editable particles, saves as an ``insert``
entry of a version 2 edit file, replays to the same particles, and undoes and redoes."""

from __future__ import annotations

import pytest
import torch

from particlesplat.cli.main import main
from particlesplat.editing.editor import Insert, SceneEditor, load_edit_file, parse_edit_file
from particlesplat.editing.open_scene import demo_scenes, encode_scene
from particlesplat.editing.operations import InsertObject
from particlesplat.editing.particle_edits import EditsError
from particlesplat.model import load_model


@pytest.fixture(scope="module")
def setup():
    model = load_model()
    b = encode_scene(model, demo_scenes()[0], [4, 16])
    return model, b, Insert(str(demo_scenes()[1]), 0, (0.8, 0.5), (4, 16))


def _editor(model, b) -> SceneEditor:
    return SceneEditor(model, b.particles, b.all_cameras, b.context)


def test_insert_is_an_editable_object_and_replays(setup, tmp_path):
    model, b, ins = setup
    ed = _editor(model, b)
    n = ed.num_particles
    ed.apply_op(InsertObject(insert=ins))
    new = list(range(n, ed.num_particles))
    assert new and ed.object_members(n) == new  # one object of its own
    assert ed.object_offset(n) == pytest.approx((0.0, 0.0, 0.0), abs=1e-6)
    assert ed.original_value(n, "z_p") == ed.value(n, "z_p")
    ed.move_object(n, [0.1, -0.05, 0.0])
    assert ed.object_offset(n) == pytest.approx((0.1, -0.05, 0.0), abs=1e-4)
    path = ed.save(tmp_path / "e.yaml", scene=str(b.path))
    file = load_edit_file(path)
    assert [op.kind for op in file.operations] == ["insert", "translate"]
    assert file.operations[0].insert == ins
    again = _editor(model, b)
    again.apply_file(file, str(path))
    assert again.num_particles == ed.num_particles
    for name in ("z_p", "z_s", "z_d", "z_t", "z_f"):
        torch.testing.assert_close(getattr(again.particles, name), getattr(ed.particles, name), atol=1e-4, rtol=0)
    assert ed.edits() == {}  # the encoded particles are untouched: version 1 edits stay empty
    # undo / redo
    ed.undo()
    ed.undo()
    assert ed.num_particles == n
    ed.redo()
    assert ed.num_particles == n + len(new) and ed.object_offset(n) == pytest.approx((0.0, 0.0, 0.0), abs=1e-6)
    # particlesplat render replays it
    assert (
        main(
            [
                "render",
                "--scene",
                str(b.path),
                "--context",
                "4,16",
                "--edits",
                str(path),
                "--width",
                "64",
                "--height",
                "48",
                "--out",
                str(tmp_path / "r.png"),
            ]
        )
        == 0
    )


def test_insert_entries_are_checked(setup):
    model, b, ins = setup
    ok = {"version": 2, "operations": [{"insert": {"scene": "A", "object": 1, "at": [0.1, 0.2]}}]}
    assert parse_edit_file(ok).operations[0].insert == Insert("A", 1, (0.1, 0.2), None)
    for bad in (
        {"scene": "A", "object": 1},
        {"scene": "A", "object": -1, "at": [0, 0]},
        {"scene": "A", "object": 1, "at": [0, 0], "context": "4,16"},
        {"scene": "A", "object": 1, "at": [0]},
    ):
        with pytest.raises(EditsError, match="e.yaml: operations\\[0\\].insert"):
            parse_edit_file({"version": 2, "operations": [{"insert": bad}]}, "e.yaml")
    ed = _editor(model, b)
    with pytest.raises(EditsError, match="insert: --object 99"):
        ed.apply_op(InsertObject(insert=Insert(ins.scene, 99, (0.8, 0.5), (4, 16))))
    assert ed.num_particles == b.particles.num
