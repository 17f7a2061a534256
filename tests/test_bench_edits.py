"""The edit-fidelity benchmark's ground truth: one scene, the object moved on the floor, removed, copied; ground
truth read from disk (the robot family's test scenes) and scored."""

from __future__ import annotations

import importlib.util
import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from particlesplat.bench.edits import (
    MOVE_RANGE,
    GroundTruth,
    _dilate,
    _interior_pixel,
    edit_pairs,
    read_edits,
    score_scene,
)
from particlesplat.bench.edits import main as bench_main
from particlesplat.core.errors import OptionError
from particlesplat.data.families import tabletop
from particlesplat.data.scene import SceneFormatError
from particlesplat.data.synth import scene_cameras
from particlesplat.model.io import shipped_model_path


def test_edit_pairs_move_remove_and_copy_one_object_on_the_floor():
    pairs = edit_pairs(0, "test", 1, 64, [4, 16])
    orig, k = pairs["original"], pairs["object"]
    obj = orig.objects[k]
    dx, dy = pairs["offsets"]["move"]
    assert MOVE_RANGE[0] <= math.hypot(dx, dy) <= MOVE_RANGE[1]
    moved = pairs["move"].objects[k]  # the same instance id
    np.testing.assert_allclose(np.subtract(moved.center, obj.center), [dx, dy, 0.0], atol=1e-12)
    assert [o for i, o in enumerate(pairs["move"].objects) if i != k] == orig.objects[:k] + orig.objects[k + 1 :]
    assert pairs["remove"].objects == orig.objects[:k] + orig.objects[k + 1 :]
    copy = pairs["duplicate"].objects[-1]
    assert pairs["duplicate"].objects[:-1] == orig.objects
    np.testing.assert_allclose(np.subtract(copy.center, obj.center), [*pairs["offsets"]["duplicate"], 0.0])
    for scene in (pairs["move"], pairs["duplicate"]):  # nothing overlaps on the floor
        for i, a in enumerate(scene.objects):
            for b in scene.objects[i + 1 :]:
                assert (
                    math.hypot(a.center[0] - b.center[0], a.center[1] - b.center[1])
                    >= a.footprint_radius + b.footprint_radius
                )
    # the pick lies on the object in its frame
    cam = scene_cameras(orig, 64)[pairs["pick"].frame]
    _, _, inst = tabletop.render_view(orig, cam.K.numpy(), cam.c2w.numpy(), 64, 64)
    x, y = pairs["pick"].pixel
    assert inst[y, x] == k + 1


def test_the_scaled_ground_truth_is_the_object_grown_on_the_floor_where_it_has_room():
    """The scale edit's scene: the edited object 1.5 times its size (every half extent), its bottom still on the
    floor, clear of the others; drawing it takes nothing from the generator's stream (the other edits keep their
    scenes). A scene where the grown object would touch another has no scale edit."""
    from particlesplat.bench.edits import SCALE

    seen = 0
    for index in range(3, 7):
        pairs = edit_pairs(0, "test", index, 64, [4, 16])
        if pairs is None or "scale" not in pairs:
            continue
        seen += 1
        orig, k = pairs["original"], pairs["object"]
        obj, grown = orig.objects[k], pairs["scale"].objects[k]
        np.testing.assert_allclose(grown.size, np.multiply(obj.size, SCALE))
        assert grown.center[:2] == obj.center[:2] and grown.center[2] == pytest.approx(grown.size[2])  # on the floor
        others = [o for i, o in enumerate(pairs["scale"].objects) if i != k]
        assert others == orig.objects[:k] + orig.objects[k + 1 :]
        for o in others:
            assert math.hypot(o.center[0] - grown.center[0], o.center[1] - grown.center[1]) >= (
                o.footprint_radius + grown.footprint_radius
            )
    assert seen >= 2  # scenes 4 and 5 of the test split have room for it, scene 3 none


def test_interior_pixel_and_dilation():
    mask = torch.zeros(9, 12, dtype=torch.bool)
    mask[2:7, 3:10] = True  # rows 2..6, columns 3..9: the centre is (6, 4)
    assert _interior_pixel(mask) == (6, 4)
    grown = _dilate(mask[None], 1)[0]
    assert int(grown.sum()) == 7 * 9 and bool(grown[1, 2]) and not bool(grown[0, 2])


# ------------------------------------------------------------------------------------------ ground truth on disk
def _mask(folder: Path, frame: int) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(folder / "masks" / f"{frame:03d}.png")).astype(np.int64)


def _grow(mask: np.ndarray, px: int = 1) -> np.ndarray:
    """(H, W) bool grown by ``px`` pixels (square), by shifted copies."""
    out = mask.copy()
    h, w = mask.shape
    padded = np.pad(mask, px)
    for dy in range(-px, px + 1):
        for dx in range(-px, px + 1):
            out |= padded[px + dy : px + dy + h, px + dx : px + dx + w]
    return out


def _demo_copy(tmp_path: Path, edits: dict | None = None, text: str | None = None) -> Path:
    from particlesplat.editing.open_scene import demo_scenes

    scene = tmp_path / "split" / "scene_00000"
    shutil.copytree(demo_scenes()[0], scene)
    if edits is not None or text is not None:
        (scene / "edits.json").write_text(text if text is not None else json.dumps(edits))
    return scene


def test_read_edits_picks_the_object_and_refuses_bad_files(tmp_path):
    scene = _demo_copy(tmp_path, {"object": 2, "offset": [0.1, -0.05, 0.0], "move": "edits/move", "remove": "r"})
    truth = read_edits(scene, [4, 16])
    assert truth.object == 2 and truth.offsets == {"move": (0.1, -0.05)} and truth.kinds == ("move", "remove")
    assert truth.folders == {"original": scene, "move": scene / "edits/move", "remove": scene / "r"}
    counts = {f: int((_mask(scene, f) == 2).sum()) for f in (4, 16)}
    assert truth.pick.frame == max(counts, key=counts.get)  # the context frame where the object is largest
    x, y = truth.pick.pixel
    assert _mask(scene, truth.pick.frame)[y, x] == 2 and _grow(_mask(scene, truth.pick.frame) != 2)[y, x] == 0
    (scene / "edits.json").write_text(json.dumps({"object": None}))
    assert read_edits(scene, [4, 16]) is None  # a scene with no edit that fits
    good = {"object": 2, "offset": [0.1, 0.0, 0.0], "move": "edits/move", "remove": "edits/remove"}
    for bad, key in (
        ({"object": 0}, "object"),
        ({"object": "2"}, "object"),
        ({"offset": [0.1, 0.0]}, "offset"),
        ({"offset": [0.1, "x", 0.0]}, "offset"),
        ({"move": "../../elsewhere"}, "move"),
        ({"remove": "/abs"}, "remove"),
    ):
        (scene / "edits.json").write_text(json.dumps(good | bad))
        with pytest.raises(SceneFormatError) as e:
            read_edits(scene, [4, 16])
        assert str(scene / "edits.json") in str(e.value) and f"'{key}'" in str(e.value) and "\n" not in str(e.value)
    (scene / "edits.json").write_text("{")
    with pytest.raises(SceneFormatError, match="not valid JSON"):
        read_edits(scene, [4, 16])
    (scene / "edits.json").write_text(json.dumps(good))
    with pytest.raises(OptionError, match="--context"):
        read_edits(scene, [4, 21])


def test_bench_edits_data_option_bad_folders_are_one_line(tmp_path):
    with pytest.raises(OptionError, match="not a folder"):
        bench_main(["--data", str(tmp_path / "missing"), "--json", str(tmp_path / "b.json")])
    _demo_copy(tmp_path)  # a scene without ground-truth edits
    with pytest.raises(OptionError, match="edits.json"):
        bench_main(["--data", str(tmp_path / "split"), "--json", str(tmp_path / "b.json")])
    with pytest.raises(OptionError, match="--context: expected comma-separated frame indices"):
        bench_main(["--context", "", "--json", str(tmp_path / "b.json")])
    assert not (tmp_path / "b.json").exists()


def test_ceiling_is_the_encoding_of_the_edited_scene(tmp_path):
    """Scored against itself (the 'moved' scene is the original, the offset zero), the ceiling renders exactly
    what the no-op renders, and the zero move changes nothing."""
    from particlesplat.model import load_model

    scene = _demo_copy(tmp_path, {"object": 1, "offset": [0.0, 0.0, 0.0], "move": ".", "remove": "."})
    truth = read_edits(scene, [4, 16])
    truth = GroundTruth(truth.label, {"original": scene, "move": scene}, truth.object, truth.pick, truth.offsets)
    row = score_scene(load_model(None), truth, [4, 16], dilate=1)
    assert set(row) >= {"move"} and "remove" not in row and "duplicate" not in row
    for region in ("changed", "vacated", "view"):
        assert row["move"]["ceiling"][region]["sse"] == row["move"]["noop"][region]["sse"]
        assert row["move"]["edit"][region]["psnr"] == pytest.approx(row["move"]["noop"][region]["psnr"], abs=0.05)
    # at the model's 64 px: the stored 128 px pixel whose centre is nearest each pixel's centre (2i + 1)
    old = np.stack([_mask(scene, f)[1::2, 1::2] == 1 for f in range(21) if f not in (4, 16)])
    assert row["move"]["pixels"]["changed"] == sum(int(_grow(m).sum()) for m in old)
    assert row["move"]["pixels"]["vacated"] == sum(int((_grow(m) & ~m).sum()) for m in old)  # the dilation's rim


# ------------------------------------------------------------------------------------------ robot family
def _sim_missing() -> str | None:
    from particlesplat.data.families.robot_assets import INSTALL, SimSetupError, assets_dir

    if importlib.util.find_spec("mujoco") is None or importlib.util.find_spec("robosuite") is None:
        return f"robot scenes need the sim extra: {INSTALL}"
    try:
        assets_dir()
    except SimSetupError as e:
        return str(e)
    return None


@pytest.fixture(scope="module")
def robot_split(tmp_path_factory) -> Path:
    missing = _sim_missing()
    if missing:
        pytest.skip(missing)
    from particlesplat.data.families.robot import RobotSceneConfig
    from particlesplat.data.families.robot_synth import generate

    out = tmp_path_factory.mktemp("robot") / "data"
    generate(
        out,
        {"train": 0, "val": 0, "test": 1},
        seed=3,
        config=RobotSceneConfig(64, 64, views=5),
        workers=1,
        progress=False,
    )
    return out / "test"


def test_bench_edits_on_robot_ground_truth(robot_split, tmp_path, capsys):
    """``bench edits --data`` on a tiny generated robot scene: the simulator's move, lift and removal are scored
    (no copy), over regions that follow the ground-truth masks, with the edit's true offset and lift height and a
    pick on the object; the table has a lift row beside the move's and the removal's."""
    scene = robot_split / "scene_00000"
    edits = json.loads((scene / "edits.json").read_text())
    k = edits["object"]
    out_json = tmp_path / "bench.json"
    # the 64 px model on 64 px scenes (without --checkpoint, robot scenes get the 128 px robot model)
    tabletop = str(shipped_model_path("tabletop"))
    argv = ["--data", str(robot_split), "--context", "1,3", "--json", str(out_json), "--checkpoint", tabletop]
    assert bench_main(argv) == 0
    printed = capsys.readouterr().out
    out = json.loads(out_json.read_text())
    assert out["data"] == str(robot_split) and "seed" not in out and out["skipped"] == []
    assert set(out["mean"]) == {"move", "lift", "remove"}
    for region in ("changed", "vacated", "view"):
        assert any(line.split()[:2] == ["lift", region] for line in printed.splitlines()), printed
    (row,) = out["scenes"]
    assert row["scene"] == "test/scene_00000" and row["object"] == k - 1 and "duplicate" not in row
    assert row["offsets"]["move"] == pytest.approx(edits["offset"][:2])
    assert row["lift_height"] == edits["lift_height"] == 0.15
    x, y = row["pick"]
    assert row["pick_frame"] in (1, 3) and _mask(scene, row["pick_frame"])[y, x] == k
    others = [0, 2, 4]
    old = np.stack([_mask(scene, f) == k for f in others])
    for kind in ("move", "lift", "remove"):
        new = np.stack([_mask(scene / edits[kind], f) == k for f in others])
        assert kind != "remove" or not new.any()
        want = {
            "changed": sum(int(_grow(o | n).sum()) for o, n in zip(old, new, strict=True)),
            "vacated": sum(int((_grow(o) & ~n).sum()) for o, n in zip(old, new, strict=True)),
            "view": 3 * 64 * 64,
        }
        assert row[kind]["pixels"] == want
        for variant in ("edit", "noop", "ceiling"):
            for region, px in want.items():
                cell = row[kind][variant][region]
                assert cell["n"] == 3 * px
                if px and cell["sse"] > 0:
                    assert cell["psnr"] == pytest.approx(10 * math.log10(cell["n"] / cell["sse"]), abs=1e-6)
        if row[kind]["status"] != "ok":  # a refused pick is scored unedited
            assert all(row[kind]["edit"][r]["sse"] == row[kind]["noop"][r]["sse"] for r in want)


def test_read_edits_lift_and_scenes_written_before_it(tmp_path):
    """A lift is read where ``edits.json`` names its folder and height; absent (scenes written before the lift) or
    null (no room for it), the scene has the move and the removal only; a bad height is one line naming it."""
    base = {"object": 2, "offset": [0.1, -0.05, 0.0], "move": "edits/move", "remove": "edits/remove"}
    scene = _demo_copy(tmp_path, base | {"lift": "edits/lift", "lift_height": 0.12})
    truth = read_edits(scene, [4, 16])
    assert truth.kinds == ("move", "lift", "remove") and truth.lift == 0.12
    assert truth.folders["lift"] == scene / "edits/lift"
    for old in (base, base | {"lift": None, "lift_height": None}):
        (scene / "edits.json").write_text(json.dumps(old))
        truth = read_edits(scene, [4, 16])
        assert truth.kinds == ("move", "remove") and truth.lift == 0.0 and "lift" not in truth.folders
    for bad, key in (
        ({"lift": "edits/lift"}, "lift_height"),
        ({"lift": "edits/lift", "lift_height": -0.1}, "lift_height"),
        ({"lift": "edits/lift", "lift_height": True}, "lift_height"),
        ({"lift": "../x", "lift_height": 0.15}, "lift"),
    ):
        (scene / "edits.json").write_text(json.dumps(base | bad))
        with pytest.raises(SceneFormatError) as e:
            read_edits(scene, [4, 16])
        assert f"'{key}'" in str(e.value) and "\n" not in str(e.value)


def test_bench_edits_scores_a_robot_scene_written_before_the_lift(robot_split, tmp_path):
    """The same scene with ``edits.json`` as the generator wrote it before the lift (no lift keys, no folder):
    the move and the removal are scored, and nothing else."""
    split = tmp_path / "old" / "test"
    shutil.copytree(robot_split / "scene_00000", split / "scene_00000")
    scene = split / "scene_00000"
    edits = json.loads((scene / "edits.json").read_text())
    shutil.rmtree(scene / edits.pop("lift"))
    del edits["lift_height"]
    (scene / "edits.json").write_text(json.dumps(edits))
    out_json = tmp_path / "bench.json"
    tabletop = str(shipped_model_path("tabletop"))
    argv = ["--data", str(split), "--context", "1,3", "--json", str(out_json), "--checkpoint", tabletop]
    assert bench_main(argv) == 0
    out = json.loads(out_json.read_text())
    (row,) = out["scenes"]
    assert set(out["mean"]) == {"move", "remove"} and "lift" not in row and "lift_height" not in row
