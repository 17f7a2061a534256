"""Object edits (particlesplat.editing.editor): only active particles draw, picks by pixel, translate / remove /
duplicate as do/undo operations, version 2 edit files replayed by ``particlesplat render``."""

from __future__ import annotations

import pytest
import torch
import yaml

from particlesplat.editing.editor import (
    EditsError,
    Pick,
    PickError,
    SceneEditor,
    load_edit_file,
    parse_edit_file,
    save_edit_file,
    scene_mismatch,
)
from particlesplat.editing.move import anchor_points
from particlesplat.editing.open_scene import demo_scenes, load_model_scene
from particlesplat.editing.operations import Remove

CONTEXT = "4,16"


@pytest.fixture(scope="module")
def scene():
    torch.set_num_threads(1)
    model, enc, _ = load_model_scene(None, demo_scenes()[0], CONTEXT)
    return model, enc


def editor(scene) -> SceneEditor:
    model, enc = scene
    return SceneEditor(model, enc.particles, enc.all_cameras, enc.context)


def biggest_object(ed: SceneEditor) -> int:
    """The first particle of the object with the most opacity (a real object of the demo scene)."""
    g = ed.decode()
    labels = ed.objects()
    own, opacity = g.owner[g.owner >= 0], g.opacities[g.owner >= 0]
    keep = labels[own] >= 0
    weight = torch.zeros(ed.num_particles).index_add_(0, labels[own][keep], opacity[keep].float())
    return int(torch.nonzero(labels == int(weight.argmax()))[0])


def centroid(ed: SceneEditor, members: list[int]):
    g = ed.model.decode(ed.particles, torch.tensor(members), background=False)
    w = g.opacities.double()
    return (g.means.double() * w[:, None]).sum(0) / w.sum()


def test_only_active_particles_draw_and_active_means_draws(scene):
    model, enc = scene
    p = enc.particles
    everything = model.decode(p, z_t_threshold=0.0)
    drawn = model.decode(p)
    thr = model.config.bg_mask_threshold
    weak = [i for i in range(p.num) if float(p.z_t[i, 0]) < thr]
    assert weak, "the demo scene has inactive particles (the ghost's source)"
    ed = editor(scene)
    for i in range(p.num):
        draws = bool((drawn.owner == i).any())
        assert draws == ed.is_active(i) == (float(p.z_t[i, 0]) >= thr)
        if i in weak:  # they drew before, faintly (at most z_t opacity)
            faint = everything.opacities[everything.owner == i]
            assert faint.numel() and float(faint.max()) <= float(p.z_t[i, 0]) + 1e-6


def test_pick_for_an_object_picks_it_back_and_background_is_an_error(scene):
    ed = editor(scene)
    label = biggest_object(ed)
    pick = ed.pick_for(label)
    assert pick.frame in ed.context
    assert ed.pick(pick) == label
    with pytest.raises(PickError, match=r"operations\[3\].*hits no object"):
        ed.pick(Pick(4, (0, 0)), "e.yaml: operations[3] (translate)")  # the top-left corner is sky
    with pytest.raises(PickError, match="outside frame"):
        ed.pick(Pick(4, (500, 0)))
    with pytest.raises(PickError, match="frames 0..20"):
        ed.pick(Pick(99, (0, 0)))


def test_translate_moves_the_objects_centroid_by_the_requested_metres(scene):
    ed = editor(scene)
    label = biggest_object(ed)
    members = ed.object_members(label)
    delta = torch.tensor([0.25, -0.15, 0.0], dtype=torch.float64)
    before_c, before_a = centroid(ed, members), anchor_points(ed.particles, members, ed.model.config)
    ed.move_object(label, delta.tolist())
    torch.testing.assert_close(
        anchor_points(ed.particles, members, ed.model.config).double(), before_a.double() + delta, rtol=0, atol=1e-4
    )
    assert float((centroid(ed, members) - before_c - delta).norm()) < 0.02  # the perspective bound of move.py
    torch.testing.assert_close(
        torch.tensor(ed.object_offset(members[0]), dtype=torch.float64), delta, rtol=0, atol=1e-4
    )
    # the object's pixels in an input frame follow: its projected centroid moves as the centroid does
    assert ed.undo() and not ed.undo()


def test_remove_and_duplicate_are_undoable_and_the_copy_is_an_object(scene):
    ed = editor(scene)
    n = ed.num_particles
    label = biggest_object(ed)
    members = ed.object_members(label)
    copy = ed.duplicate_object(label, [0.0, 0.5, 0.0])
    assert ed.num_particles == n + len(members) and copy == n
    assert ed.object_members(copy) == list(range(n, n + len(members)))
    offset = torch.tensor([0.0, 0.5, 0.0], dtype=torch.float64)
    cfg = ed.model.config
    torch.testing.assert_close(
        anchor_points(ed.particles, ed.object_members(copy), cfg).double(),
        anchor_points(ed.particles, members, cfg).double() + offset,
        rtol=0,
        atol=1e-4,
    )
    # Gaussians off the anchor depth move up to |offset| x (depth spread) / depth (move.py): 10 % of 0.5 m here
    torch.testing.assert_close(centroid(ed, ed.object_members(copy)) - centroid(ed, members), offset, rtol=0, atol=0.05)
    ed.remove_object(label)
    g = ed.decode()
    assert not bool(torch.isin(g.owner, torch.tensor(members)).any())
    assert all(not ed.is_active(i) for i in members)
    assert ed.take_changes() is None  # the particle count changed: everything re-uploads
    assert ed.undo() and ed.undo()
    assert ed.num_particles == n and ed.objects().shape == (n,)
    assert all(torch.equal(getattr(ed.particles, k), getattr(ed.original, k)) for k in ("z_p", "z_d", "z_t"))
    assert ed.redo() and ed.num_particles == n + len(members)


def test_objects_are_numbered_and_centred_as_encode_writes_them(scene):
    """One numbering and one centre: the editor's object numbers are ``particlesplat encode``'s ``object`` array
    (0..K-1 by smallest particle, -1 for particles that draw nothing) and its object centre (the gizmo's) is the
    arrays' ``object_centroid`` (the resting centre); a copy takes number K."""
    import numpy as np

    from particlesplat.analysis.particle_arrays import particle_arrays

    model, enc = scene
    ed = editor(scene)
    arrays = particle_arrays(model, enc.particles, ed.decode())
    assert np.array_equal(ed.objects().numpy(), arrays.object)
    K = arrays.num_objects
    assert K >= 2 and set(arrays.object.tolist()) == set(range(K)) | ({-1} if (arrays.object < 0).any() else set())
    for k in range(K):
        first = int(np.flatnonzero(arrays.object == k)[0])
        centre = ed.object_centre(first)
        np.testing.assert_allclose(centre.numpy(), arrays.object_centroid[k], rtol=0, atol=1e-4)
    copy = ed.duplicate_object(biggest_object(ed), [0.0, 0.5, 0.0])
    assert int(ed.objects()[copy]) == K
    assert ed.pick(ed.pick_for(copy)) == copy


def test_edit_file_round_trip_replays_the_same_particles(scene, tmp_path):
    ed = editor(scene)
    label = biggest_object(ed)
    ed.move_object(label, [0.1, 0.0, 0.0], gesture="drag")
    ed.move_object(label, [0.1, -0.1, 0.0], gesture="drag")  # one drag: one operation of the summed offset
    ed.end_gesture()
    ed.duplicate_object(label, [-0.3, 0.3, 0.0])
    ed.set_attribute(1, "z_s", [-1.0, -1.2])
    path = ed.save(tmp_path / "e.yaml", scene="scene_00000")
    doc = yaml.safe_load(path.read_text())
    assert doc["version"] == 2 and doc["context"] == [4, 16]
    assert doc["operations"][0]["translate"] == pytest.approx([0.2, -0.1, 0.0])
    assert doc["operations"][2] == {"particle": 1, "set": {"z_s": [-1.0, -1.2]}}
    file = load_edit_file(path)
    assert [op.kind for op in file.operations] == ["translate", "duplicate", "set"]
    again = editor(scene)
    again.apply_file(file, str(path))
    for k in ("z_p", "z_s", "z_d", "z_e", "z_t", "z_f"):
        torch.testing.assert_close(getattr(again.particles, k), getattr(ed.particles, k), rtol=0, atol=1e-5)


def test_version_1_still_loads_and_bad_files_name_the_field(scene, tmp_path):
    v1 = tmp_path / "v1.yaml"
    v1.write_text("version: 1\nparticles:\n  2:\n    z_t: [0.0]\n")
    file = load_edit_file(v1)
    assert file.version == 1 and file.particles == {2: {"z_t": (0.0,)}}
    ed = editor(scene)
    ed.apply_file(file)
    assert ed.value(2, "z_t") == (0.0,)
    bad = {"version": 2, "operations": [{"pick": {"frame": 4, "pixel": [3, 4]}, "translate": [1, 2]}]}
    with pytest.raises(EditsError, match=r"f.yaml: operations\[0\].translate: expected 3"):
        parse_edit_file(bad, "f.yaml")
    with pytest.raises(EditsError, match=r"operations\[0\]: expected pick and exactly one"):
        parse_edit_file(
            {
                "version": 2,
                "operations": [{"pick": {"frame": 4, "pixel": [3, 4]}, "remove": True, "translate": [0, 0, 0]}],
            },
            "f.yaml",
        )
    with pytest.raises(EditsError, match="version: expected 1 or 2"):
        parse_edit_file({"version": 3, "operations": []}, "f.yaml")
    ops = [Remove(pick=Pick(4, (0, 0)))]
    save_edit_file(tmp_path / "sky.yaml", ops, scene="scene_00001", context=[4, 16])
    sky = load_edit_file(tmp_path / "sky.yaml")
    with pytest.raises(PickError, match=r"sky.yaml: operations\[0\] \(remove\): pick .* hits no object"):
        editor(scene).apply_file(sky, str(tmp_path / "sky.yaml"))
    assert "made on scene scene_00001" in scene_mismatch(sky, "assets/scenes/scene_00000", [4, 16])
    assert scene_mismatch(sky, "./scene_00001", [4, 16]) is None  # the same folder, resolved
    assert "another scene path" in scene_mismatch(sky, "x/scene_00001", [4, 16])  # the same name, another folder
    assert "context frames [4, 16]" in scene_mismatch(sky, "scene_00001", [3, 9])


def test_render_cli_replays_an_edit_file(scene, tmp_path, capsys):
    from particlesplat.cli.main import main

    ed = editor(scene)
    label = biggest_object(ed)
    ed.remove_object(label)
    path = ed.save(tmp_path / "rm.yaml", scene="scene_00000")
    base = ["render", "--scene", str(demo_scenes()[0]), "--context", CONTEXT, "--view", "10", "--width", "64"]
    assert main(base + ["--out", str(tmp_path / "a.png")]) == 0
    assert main(base + ["--edits", str(path), "--out", str(tmp_path / "b.png")]) == 0
    import numpy as np
    from PIL import Image

    a = np.asarray(Image.open(tmp_path / "a.png"), dtype=np.float64)
    b = np.asarray(Image.open(tmp_path / "b.png"), dtype=np.float64)
    # the removed object's pixels changed, the rest of the image hardly
    seg = ed.object_map(10, ed.original)
    seg = torch.nn.functional.interpolate(seg[None, None].float(), size=a.shape[:2], mode="nearest")[0, 0]
    obj = (seg == label).numpy()
    assert obj.sum() > 20
    diff = np.abs(a - b).sum(-1)
    assert diff[obj].mean() > 5 * diff[~obj].mean()
