"""The crop box: an edit operation (``crop: {min, max}`` / ``crop: false``) that hides the Gaussians whose means lie
outside a world-aligned box, done and undone by the editor, saved in an edit file and replayed from it by
``render`` and ``export``; a robot scene whose edits set no box exports its workspace (table and arm) only, so
another viewer frames the workspace. Checked against the decoded means tested box by box here and the scene's own
scene.json."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
import torch
import yaml

from particlesplat.cli.main import main
from particlesplat.core.gaussians import Gaussians
from particlesplat.core.viewpoints import default_view
from particlesplat.editing.crop_box import CropBox, workspace_box
from particlesplat.editing.editor import EditsError, SceneEditor, load_edit_file
from particlesplat.editing.open_scene import demo_scenes, load_model_scene

BOX = CropBox((-0.6, -0.5, -0.1), (0.4, 0.7, 0.9))  # part of the tabletop demo scene: some objects, some floor


@pytest.fixture(scope="module")
def tabletop():
    torch.set_num_threads(1)
    model, enc, name = load_model_scene(None, demo_scenes()[0], "4,16")
    return model, enc, name


def _inside(means: np.ndarray, lo, hi) -> np.ndarray:
    """Which means (N, 3) lie in [lo, hi] on every axis: one comparison at a time."""
    keep = np.ones(len(means), dtype=bool)
    for axis in range(3):
        keep &= (means[:, axis] >= lo[axis]) & (means[:, axis] <= hi[axis])
    return keep


def test_the_box_keeps_the_means_inside_it_bounds_included():
    pts = torch.tensor(
        [[0.0, 0.0, 0.0], [-0.6, 0.7, 0.9], [0.41, 0.0, 0.0], [0.0, -0.5000001, 0.0]], dtype=torch.float64
    )
    assert BOX.inside(pts).tolist() == [True, True, False, False]
    assert CropBox.everything().inside(pts).all() and not CropBox.everything().bounded
    assert BOX.text() == "x -0.60..0.40, y -0.50..0.70, z -0.10..0.90 m"


def test_a_crop_is_done_undone_saved_and_replayed(tabletop, tmp_path):
    model, enc, name = tabletop
    ed = SceneEditor(model, enc.particles, enc.all_cameras, enc.context)
    version = ed.version
    ed.set_crop(BOX)
    assert ed.crop_box == BOX and ed.version > version
    ed.set_crop(BOX)  # the same box again: nothing to do, no history entry
    assert len(ed.history.undo) == 1
    # a handle's drag: its steps are one operation, undone to the box before the drag
    ed.set_crop(CropBox((-0.6, -0.5, -0.1), (0.5, 0.7, 0.9)), gesture="handle")
    ed.set_crop(CropBox((-0.6, -0.5, -0.1), (0.6, 0.7, 0.9)), gesture="handle")
    ed.end_gesture()
    assert len(ed.history.undo) == 2 and ed.crop_box == CropBox((-0.6, -0.5, -0.1), (0.6, 0.7, 0.9))
    ed.undo()
    assert ed.crop_box == BOX
    ed.undo()
    assert ed.crop_box is None
    ed.redo()
    ed.move_object(int(ed.objects().argmax()), (0.05, 0.0, 0.0))  # a crop among object edits
    ed.set_crop(CropBox.everything())
    ed.set_crop(BOX)
    path = ed.save(tmp_path / "e.yaml", scene=str(enc.path), model=name)
    doc = yaml.safe_load(path.read_text())
    crops = [op["crop"] for op in doc["operations"] if "crop" in op]
    assert crops == [
        {"min": [-0.6, -0.5, -0.1], "max": [0.4, 0.7, 0.9]},
        False,
        {"min": [-0.6, -0.5, -0.1], "max": [0.4, 0.7, 0.9]},
    ]
    again = SceneEditor(model, enc.particles, enc.all_cameras, enc.context)
    again.apply_file(load_edit_file(path), str(path))
    assert again.crop_box == BOX
    torch.testing.assert_close(again.particles.z_p, ed.particles.z_p)  # the move replayed with it


def test_bad_crop_values_are_one_line_naming_the_field(tmp_path):
    cases = {
        "{min: [0, 0, 0], max: [1, 1]}": "operations[0].crop.max: expected 3 finite number(s)",
        "{min: [0, 0, 1], max: [1, 1, 1]}": "operations[0].crop: min z 1 is not below max z 1",
        "{min: [0, 0, 0], max: [1, 1, 2.0e+5]}": "operations[0].crop.max: beyond 100000 m from the origin",
        "{lo: [0, 0, 0], hi: [1, 1, 1]}": "operations[0].crop: expected {min: [x, y, z], max: [x, y, z]} or false",
        "true": "operations[0].crop: expected {min: [x, y, z], max: [x, y, z]} or false, got True",
    }
    for value, message in cases.items():
        path = tmp_path / "bad.yaml"
        path.write_text(f"version: 2\noperations:\n  - crop: {value}\n")
        with pytest.raises(EditsError) as info:
            load_edit_file(path)
        assert str(info.value).startswith(f"{path}: ") and message in str(info.value), str(info.value)
    path.write_text("version: 2\noperations:\n  - crop: false\n    pick: {frame: 4, pixel: [1, 1]}\n")
    with pytest.raises(EditsError, match="a crop operation has the one key crop"):
        load_edit_file(path)


def test_render_and_export_replay_the_crop_of_an_edit_file(tabletop, tmp_path, capsys):
    """The Gaussians ``render`` draws and those ``export`` writes under an edit file's crop are the decoded scene's
    whose means lie in the box; ``--no-crop`` writes them all. A tabletop scene without a crop exports whole."""
    model, enc, _ = tabletop
    edits = tmp_path / "crop.yaml"
    edits.write_text(
        f"version: 2\nscene: {enc.path}\ncontext: [4, 16]\noperations:\n"
        "  - crop: {min: [-0.6, -0.5, -0.1], max: [0.4, 0.7, 0.9]}\n"
    )
    full = model.decode(enc.particles).detach().to("cpu")
    means = full.means.double().numpy()
    keep = _inside(means, BOX.lo, BOX.hi)
    assert 0 < keep.sum() < len(keep)  # the box cuts the scene
    import argparse

    from particlesplat.cli import render as render_command

    parser = argparse.ArgumentParser()
    render_command.add_arguments(parser)
    drawn = render_command._scene_and_gaussians(
        parser.parse_args(["--edits", str(edits), "--out", str(tmp_path / "r.png")])
    )[0]
    np.testing.assert_allclose(drawn.means.double().numpy(), means[keep], atol=1e-6)  # the same decode, subset
    assert main(["render", "--edits", str(edits), "--out", str(tmp_path / "r.png")]) == 0
    capsys.readouterr()
    assert main(["export", "--edits", str(edits), "--out", str(tmp_path / "c.ply")]) == 0
    said = capsys.readouterr().out
    assert f"cropped to the edits' crop box, {BOX.text()}: {(~keep).sum()} of {len(keep)} Gaussians" in said
    written = Gaussians.load(tmp_path / "c.ply")
    assert written.num == int(keep.sum()) and _inside(written.means.double().numpy(), BOX.lo, BOX.hi).all()
    assert main(["export", "--edits", str(edits), "--no-crop", "--out", str(tmp_path / "all.ply")]) == 0
    assert Gaussians.load(tmp_path / "all.ply").num == len(keep)
    assert main(["export", "--scene", str(enc.path), "--out", str(tmp_path / "plain.ply")]) == 0
    assert "cropped" not in capsys.readouterr().out and Gaussians.load(tmp_path / "plain.ply").num == len(keep)
    assert workspace_box(enc.path) is None  # a tabletop scene records no workspace


def test_a_robot_scene_exports_its_workspace_and_opens_framed_on_it(tmp_path, capsys):
    """Without a crop in its edits a robot scene exports the Gaussians about its table and arm: the box holds the
    table top's corners and the robot's base (scene.json), every written mean lies in it, and the file's default
    view (what ``--ply`` opens with) is about as far as the scene's own cameras, not the room's walls away."""
    robot = next(p for p in demo_scenes() if json.loads((p / "scene.json").read_text()).get("family") == "robot")
    meta = json.loads((robot / "scene.json").read_text())
    box = workspace_box(robot)
    assert box is not None and box.bounded
    hx, hy = meta["table_half_extent"]
    corners = torch.tensor([[sx * hx, sy * hy, 0.0] for sx in (-1, 1) for sy in (-1, 1)], dtype=torch.float64)
    base = torch.tensor(meta["robot_base"], dtype=torch.float64)[:3, 3]
    assert box.inside(corners).all() and bool(box.inside(base[None])[0])
    assert main(["export", "--scene", str(robot), "--out", str(tmp_path / "w.spz")]) == 0
    said = capsys.readouterr().out
    assert "cropped to the workspace box (the table and the arm)" in said and "--no-crop keeps them" in said
    assert main(["export", "--scene", str(robot), "--no-crop", "--out", str(tmp_path / "all.spz")]) == 0
    work, room = Gaussians.load(tmp_path / "w.spz"), Gaussians.load(tmp_path / "all.spz")
    assert 0 < work.num < room.num
    lo, hi = np.array(box.lo) - 1e-3, np.array(box.hi) + 1e-3  # the .spz's fixed point rounds to 0.25 mm
    assert _inside(work.means.double().numpy(), lo, hi).all()
    framed, whole = default_view(None, work).look.distance, default_view(None, room).look.distance
    assert framed < 2 * meta["distance"] < whole, (framed, whole, meta["distance"])


def test_export_help_names_the_crop_before_torch_loads():
    script = (
        "import sys\nfrom particlesplat.cli.main import main\ntry:\n    main(['export', '--help'])\n"
        "except SystemExit:\n    pass\nprint('torch' in sys.modules)\n"
    )
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0 and proc.stdout.strip().endswith("False")
    assert "--no-crop" in proc.stdout and "workspace box" in " ".join(proc.stdout.split())
