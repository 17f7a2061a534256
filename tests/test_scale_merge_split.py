"""Scale, merge and split: one operation class each, done and undone, saved in edit files and replayed.

Scale is checked against the Gaussians themselves (an object's opacity-weighted spread grows by the factor, the
others do not change, its bottom stays on the support); merge and split against the object labels; a saved file
against the particles and labels a fresh editor replays from it."""

from __future__ import annotations

import pytest
import torch
import yaml

from particlesplat.editing.editor import EditsError, SceneEditor, load_edit_file, parse_edit_file
from particlesplat.editing.open_scene import demo_scenes, load_model_scene
from particlesplat.editing.operations import Merge, Scale, Split

FIELDS = ("z_p", "z_s", "z_d", "z_e", "z_t", "z_f")


@pytest.fixture(scope="module", params=[0, 3], ids=["tabletop", "robot"])
def scene(request):
    torch.set_num_threads(1)
    model, enc, _ = load_model_scene(None, demo_scenes()[request.param], None)
    return model, enc


def editor(scene) -> SceneEditor:
    model, enc = scene
    return SceneEditor(model, enc.particles, enc.all_cameras, enc.context)


def spreads(ed: SceneEditor) -> dict[int, float]:
    """RMS distance (metres) of each object's Gaussians from their opacity-weighted mean, opacity-weighted: brute
    force per object from the decoded Gaussians (float64)."""
    g = ed.decode()
    labels = ed.objects()
    out = {}
    for k in sorted({int(v) for v in labels.tolist() if v >= 0}):
        members = torch.nonzero(labels == k).flatten()
        sel = torch.isin(g.owner, members)
        x, w = g.means[sel].double(), g.opacities[sel].double()
        mean = (w[:, None] * x).sum(0) / w.sum()
        out[k] = float(((w * ((x - mean) ** 2).sum(1)).sum() / w.sum()).sqrt())
    return out


def visible_objects(ed: SceneEditor) -> list[int]:
    """The first particle of each object an input frame shows (largest first), as a pick finds them."""
    counts: dict[int, int] = {}
    for f in ed.context or []:
        m = ed.object_map(f)
        for k, n in zip(*torch.unique(m[m >= 0], return_counts=True), strict=True):
            counts[int(k)] = max(counts.get(int(k), 0), int(n))
    labels = ed.objects()
    return [int(torch.nonzero(labels == k)[0]) for k in sorted(counts, key=counts.get, reverse=True)]


def assert_same_particles(a: SceneEditor, b: SceneEditor) -> None:
    for k in FIELDS:
        torch.testing.assert_close(getattr(a.particles, k), getattr(b.particles, k), rtol=0, atol=1e-5)
    assert torch.equal(a.objects(), b.objects())


def test_scale_grows_the_object_by_the_factor_and_keeps_it_on_its_support(scene, tmp_path):
    ed = editor(scene)
    index = visible_objects(ed)[0]
    k = int(ed.objects()[index])
    before, bottom = spreads(ed), ed.object_bottom(index)
    ed.scale_object(index, 1.5)
    after = spreads(ed)
    assert 1.35 <= after[k] / before[k] <= 1.65
    for j in before:
        if j != k:
            assert after[j] == pytest.approx(before[j], rel=0.05)
    support = ed.support_height()
    assert bottom is not None and ed.object_bottom(index) >= min(bottom, support) - 0.01
    path = ed.save(tmp_path / "s.yaml")
    doc = yaml.safe_load(path.read_text())
    assert doc["operations"][0]["scale"] == 1.5 and set(doc["operations"][0]) == {"pick", "scale"}
    again = editor(scene)
    again.apply_file(load_edit_file(path))
    assert_same_particles(again, ed)
    assert ed.undo() and spreads(ed) == pytest.approx(before, rel=1e-6)


def test_a_scale_drag_is_one_operation_of_the_product(scene):
    ed = editor(scene)
    index = visible_objects(ed)[0]
    for _ in range(4):
        ed.scale_object(index, 1.1, gesture="drag")
    ed.end_gesture()
    assert len(ed.history.undo) == 1 and ed.history.undo[0].factor == pytest.approx(1.1**4)
    once = editor(scene)
    once.scale_object(index, 1.1**4)
    for k in FIELDS:  # the steps compose about the (unmoving) pivot as one scale does
        torch.testing.assert_close(getattr(ed.particles, k), getattr(once.particles, k), rtol=0, atol=2e-3)


@pytest.mark.parametrize("value", [0, -1.5, ".inf", "'big'", "[1, 2]", "true"])
def test_a_bad_scale_factor_is_one_line_naming_the_field(value):
    doc = yaml.safe_load(f"version: 2\noperations:\n- pick: {{frame: 4, pixel: [3, 4]}}\n  scale: {value}\n")
    with pytest.raises(EditsError, match=r"f\.yaml: operations\[0\]\.scale: expected") as e:
        parse_edit_file(doc, "f.yaml")
    assert "\n" not in str(e.value)


def test_merge_joins_two_objects_and_split_takes_a_particle_out(scene, tmp_path):
    ed = editor(scene)
    a, b = visible_objects(ed)[:2]
    count = len({int(v) for v in ed.objects().tolist() if v >= 0})
    ed.move_object(a, [0.05, 0.0, 0.0])  # saved with a pick on the objects before the merge
    pa, pb = ed.pick_for(a), ed.pick_for(b)
    ed.apply_op(Merge(pick=pa, other=pb))
    joined = ed.object_members(a)
    assert len({int(v) for v in ed.objects().tolist() if v >= 0}) == count - 1
    assert set(ed.object_members(b)) == set(joined) and len(joined) >= 2
    with pytest.raises(EditsError, match="one object already"):
        ed.apply_op(Merge(pick=pa, other=pb), "again")
    ed.move_object(b, [0.0, 0.04, 0.0])  # moves both
    ed.split_particle(joined[0])
    assert ed.object_members(joined[0]) == [joined[0]]
    assert len({int(v) for v in ed.objects().tolist() if v >= 0}) == count
    path = ed.save(tmp_path / "m.yaml", scene="s")
    ops = yaml.safe_load(path.read_text())["operations"]
    assert [next(k for k in op if k not in ("pick", "particle")) for op in ops] == [
        "translate",
        "merge",
        "translate",
        "split",
    ]
    assert set(ops[1]["merge"]) == {"frame", "pixel"} and ops[3] == {"particle": joined[0], "split": True}
    again = editor(scene)
    again.apply_file(load_edit_file(path))
    assert_same_particles(again, ed)
    while ed.undo():
        pass
    assert torch.equal(ed.objects(), editor(scene).objects())


def test_split_refuses_a_particle_alone_and_names_the_operation(scene):
    ed = editor(scene)
    multi = next(i for i in visible_objects(ed) if len(ed.object_members(i)) >= 2)
    p = ed.object_members(multi)[0]
    ed.split_particle(p)
    done = len(ed.history.undo)
    with pytest.raises(EditsError, match=r"my\.yaml: operations\[0\] \(split\): split: particle \d+ is an object"):
        ed.apply_file(parse_edit_file({"version": 2, "operations": [{"particle": p, "split": True}]}), "my.yaml")
    assert len(ed.history.undo) == done
    with pytest.raises(EditsError, match="split: expected true"):
        parse_edit_file({"version": 2, "operations": [{"particle": 1, "split": 1}]})
    assert Split.read({"particle": 2, "split": True}, "w").particle == 2 and Scale(factor=2.0).kind == "scale"


def test_user_groups_win_in_the_particle_arrays_and_the_object_colours(scene, tmp_path):
    from particlesplat.analysis.particle_arrays import particle_arrays
    from particlesplat.cli.main import main
    from particlesplat.editing.scene_objects import SceneObjects

    model, enc = scene
    ed = editor(scene)
    a, b = visible_objects(ed)[:2]
    plain = particle_arrays(model, ed.particles)
    ed.merge_objects(a, b)
    ed.remove_object(visible_objects(ed)[-1])  # a removed object is in none
    arrays = particle_arrays(model, ed.particles, objects=SceneObjects(ed.objects()))
    assert arrays.num_objects == plain.num_objects - 2
    assert arrays.object[a] == arrays.object[b] >= 0 and sorted(set(arrays.object.tolist()) - {-1}) == list(
        range(arrays.num_objects)
    )
    path = ed.save(tmp_path / "m.yaml")
    out = tmp_path / "o.png"
    main(
        [
            "render",
            "--scene",
            str(enc.path),
            "--edits",
            str(path),
            "--view",
            "4",
            "--mode",
            "objects",
            "--out",
            str(out),
        ]
    )
    assert out.is_file()
    # encode --edits: the arrays a learner reads carry the same groups
    from particlesplat.analysis.particle_arrays import ParticleArrays

    args = ["encode", "--data", str(enc.path), "--edits", str(path), "--out", str(tmp_path / "enc"), "--no-progress"]
    assert main(args) == 0
    (written,) = (tmp_path / "enc").glob("*.npz")
    encoded = ParticleArrays.load(written)
    assert encoded.num_objects == arrays.num_objects and encoded.object.tolist() == arrays.object.tolist()
