"""Where the app's files go: per-scene names that never collide (two families' scenes of one name, two folders of
one name), the user's XDG folders (autosaves, settings, outputs), and the viewer's remembered panel width."""

from __future__ import annotations

import json
import shutil

import pytest

from particlesplat.core import userdirs
from particlesplat.data.scene_meta import read_family
from particlesplat.editing.open_scene import demo_scenes
from particlesplat.editing.scene_id import scene_file_key


def test_demo_scenes_of_two_families_get_their_own_files(tmp_path):
    scenes = demo_scenes()
    keys = {scene_file_key(s, read_family(s)) for s in scenes}
    assert len(keys) == len(scenes)
    assert {k.split("-")[0] for k in keys} == {"tabletop", "robot"}
    # scenes of two families with the same folder name do not share a file either
    tabletop = next(s for s in scenes if read_family(s) == "tabletop")
    robot = next(s for s in scenes if read_family(s) == "robot")
    a, b = tmp_path / "a" / "scene_00000", tmp_path / "b" / "scene_00000"
    shutil.copytree(tabletop, a)
    shutil.copytree(robot, b)
    assert scene_file_key(a, read_family(a)) != scene_file_key(b, read_family(b))


def test_scene_file_key_is_family_name_and_path(tmp_path):
    a, b = tmp_path / "train" / "scene_00000", tmp_path / "test" / "scene_00000"
    a.mkdir(parents=True)
    b.mkdir(parents=True)
    ka, kb = scene_file_key(a, "tabletop"), scene_file_key(b, "tabletop")
    assert ka != kb and ka.startswith("tabletop-scene_00000-") and len(ka.rsplit("-", 1)[1]) == 8
    (tmp_path / "link").symlink_to(a)
    assert scene_file_key(tmp_path / "link", "tabletop") == scene_file_key(a, "tabletop")  # resolved
    assert scene_file_key(tmp_path / "g.ply", None).startswith("ply-g-")
    assert scene_file_key(a, None).startswith("scene-scene_00000-")


def test_user_folders_follow_xdg(monkeypatch, tmp_path):
    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path / "s"))
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "c"))
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "d"))
    assert userdirs.autosave_dir() == tmp_path / "s" / "particlesplat" / "autosave"
    assert userdirs.config_dir() == tmp_path / "c" / "particlesplat"
    assert userdirs.output_dir() == tmp_path / "d" / "particlesplat"
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    for name in ("XDG_STATE_HOME", "XDG_CONFIG_HOME"):
        monkeypatch.setenv(name, "relative/path")  # ignored, as the specification says
    monkeypatch.delenv("XDG_DATA_HOME")
    assert userdirs.state_dir() == tmp_path / "home" / ".local" / "state" / "particlesplat"
    assert userdirs.config_dir() == tmp_path / "home" / ".config" / "particlesplat"
    assert userdirs.output_dir() == tmp_path / "home" / ".local" / "share" / "particlesplat"


def test_viewer_settings_round_trip_and_bad_files(tmp_path, capsys):
    from viewer.settings import PANEL_WIDTH, PANEL_WIDTH_RANGE, ViewerSettings, load_settings, save_settings

    path = tmp_path / "c" / "viewer.json"
    assert load_settings(path) == ViewerSettings(PANEL_WIDTH)  # none yet: the default
    save_settings(ViewerSettings(panel_width=420.0), path)
    assert json.loads(path.read_text()) == {"panel_width": 420.0}
    assert load_settings(path).panel_width == 420.0
    path.write_text('{"panel_width": 5}')
    assert load_settings(path).panel_width == PANEL_WIDTH_RANGE[0]  # kept within its range
    for text in ("{not json", '{"panel_width": "wide"}', "[1, 2]"):
        path.write_text(text)
        assert load_settings(path) == ViewerSettings()
        assert str(path) in capsys.readouterr().err


@pytest.mark.parametrize("family", ["tabletop", None])
def test_default_edit_file_and_autosave_use_the_key(family, tmp_path):
    """The session's default edit file and autosave are named by the scene's key, in the folders given."""
    from viewer.session import SceneFiles

    scene = tmp_path / "scene_00000"
    scene.mkdir()
    if family:
        (scene / "scene.json").write_text(json.dumps({"family": family}))
    session = SceneFiles(str(scene), "")  # the naming only: no model, no particles
    key = scene_file_key(scene, family)
    assert session.file_key == key
    assert session.default_edits_path(tmp_path / "out") == tmp_path / "out" / f"{key}.edits.yaml"
    auto = session.autosave_path(userdirs.autosave_dir())
    assert auto.parent == userdirs.autosave_dir() and auto.name.startswith(f"{key}-")
