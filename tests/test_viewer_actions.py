"""The viewer's one table of actions: every key names a real imgui key, no chord does two things, the help lists
every action with keys, and running an action edits through the scene's editor (none on a .ply)."""

from __future__ import annotations

import pytest
import torch
from viewer_helpers import small_model

from particlesplat.editing.open_scene import demo_scenes, encode_scene
from viewer.actions import ACTIONS, BY_NAME, ActionTarget, Chord, help_rows, run
from viewer.session import EditableScene, PlyScene
from viewer.state import ViewState
from viewer.ui.fields import UiRequests


@pytest.fixture(scope="module")
def encoded():
    model = small_model()
    return model, encode_scene(model, demo_scenes()[0])


def target(scene) -> tuple[ActionTarget, list[str]]:
    said: list[str] = []
    return ActionTarget(scene, ViewState(), UiRequests(), said.append, (0.1, 0.0, 0.0)), said


def test_keys_are_imgui_keys_and_no_chord_does_two_things():
    from imgui_bundle import imgui

    chords = [c for a in ACTIONS for c in a.keys]
    assert all(isinstance(getattr(imgui.Key, c.key), imgui.Key) for c in chords)
    assert len(chords) == len(set(chords))
    assert len(BY_NAME) == len(ACTIONS)
    assert Chord("z", ctrl=True, shift=True).label() == "Ctrl+Shift+Z" and Chord("delete").label() == "Del"


def test_the_help_lists_every_action_with_keys_once():
    rows = help_rows()
    helps = [what for _, what in rows]
    assert len(helps) == len(set(helps))
    for a in ACTIONS:
        if a.keys:
            assert (a.keys_label(), a.help) in rows
    assert ("Ctrl+Z", "undo") in rows and ("Ctrl+Shift+Z / Ctrl+Y", "redo") in rows and ("0 .. 9", rows[-1][1]) in rows


def test_actions_edit_through_the_editor_and_undo(encoded):
    model, enc = encoded
    scene = EditableScene(model, enc)
    ctx, said = target(scene)
    ed = scene.editor
    obj = int(torch.nonzero(ed.objects() >= 0)[0])
    assert not run("delete", ctx) and not run("duplicate", ctx)  # nothing selected: disabled
    ctx.state.selected = obj
    n = ed.num_particles
    assert run("duplicate", ctx)
    members = ed.object_members(obj)
    assert ed.num_particles == n + len(members) and ctx.state.selected == n and said[-1].startswith("copied")
    assert run("delete", ctx) and ctx.state.selected is None and ed.history.undo[-1].kind == "remove"
    assert run("undo", ctx) and run("undo", ctx) and ed.num_particles == n and not ed.history.undo
    assert run("redo", ctx) and ed.num_particles == n + len(members)
    assert run("save_edits", ctx) and ctx.requests.save_edits
    assert run("snap_3", ctx) and ctx.requests.snap_camera == 3
    mode = ctx.state.seg_mode
    assert run("next_mode", ctx) and ctx.state.seg_mode != mode


def test_a_ply_scene_has_no_edit_actions(encoded):
    model, enc = encoded
    ctx, _ = target(PlyScene(model.decode(enc.particles), source="x.ply"))
    ctx.state.selected = 0
    for name in ("undo", "redo", "save_edits", "delete", "duplicate"):
        assert not BY_NAME[name].enabled(ctx) and not run(name, ctx)
    assert not ctx.requests.save_edits
    assert run("screenshot", ctx) and ctx.requests.screenshot


def test_grow_shrink_merge_and_split_by_key_are_one_undo_step_each(encoded):
    model, enc = encoded
    scene = EditableScene(model, enc)
    ctx, said = target(scene)
    ed = scene.editor
    labels = ed.objects()
    firsts = [int(torch.nonzero(labels == k)[0]) for k in sorted({int(v) for v in labels.tolist() if v >= 0})]
    assert len(firsts) >= 2
    ctx.state.selected = firsts[0]
    assert not run("merge", ctx)  # one object selected: nothing to merge with
    ctx.state.selected = firsts[1]
    assert ctx.state.previous == firsts[0]  # the selection before is remembered
    assert run("grow", ctx) and ed.history.undo[-1].factor == pytest.approx(1.1)
    assert run("shrink", ctx) and ed.history.undo[-1].factor == pytest.approx(1 / 1.1)
    count = len(set(ed.objects().tolist()) - {-1})
    assert run("merge", ctx) and ed.history.undo[-1].kind == "merge", said[-1]
    assert len(set(ed.objects().tolist()) - {-1}) == count - 1 and firsts[0] in ed.object_members(firsts[1])
    assert run("split", ctx) and ed.object_members(firsts[1]) == [firsts[1]]
    assert [op.kind for op in ed.history.undo] == ["scale", "scale", "merge", "split"]
    while run("undo", ctx) and ed.history.undo:
        pass
    assert torch.equal(ed.objects(), labels)
