"""Scene families register in one place (``particlesplat.data.families``): a family registered there is what
``synth --family`` and ``scene check --family`` offer, what ``scene.json`` may record, the model its scenes open
with and the rigs ``scene check`` judges them against; an unknown name is refused naming the registered ones, and
no module outside the families' folder lists or compares family names itself."""

from __future__ import annotations

import ast
import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from particlesplat.cli.main import main
from particlesplat.core.bundled import bundled_assets
from particlesplat.core.errors import UserError
from particlesplat.data import families as registry
from particlesplat.data.families import Family, get_family, register
from particlesplat.data.scene_meta import default_checkpoint, read_family
from particlesplat.editing.open_scene import demo_scene_name, demo_scenes
from particlesplat.model.io import shipped_model_name, shipped_model_path

ROOT = Path(__file__).resolve().parents[1]
CALLS: list[tuple[Path, dict[str, int], int, str]] = []


def _fake_generate(out: Path, counts: dict[str, int], seed: int, options) -> list[float]:
    """The kitchen family's generator entry: records its call, writes nothing, took 0.25 s a scene."""
    CALLS.append((Path(out), dict(counts), seed, options.world))
    return [0.25] * sum(counts.values())


KITCHEN = Family(
    name="kitchen",
    summary="a counter with crockery",
    title="kitchen counter",
    generator=f"{__name__}:_fake_generate",
    generators=("tests.kitchen_generator",),
    shipped_model="kitchen/model.pt",
    demo_scenes="kitchen/scenes",
    static_layer="points",
    camera_distances=(30.0, 36.0),  # ten times the tabletop's: its scenes are judged at another scale
    heldout_worlds=("wide",),
)


@pytest.fixture
def kitchen(monkeypatch):
    """The registry with the kitchen family registered after the built-in ones (only for the test)."""
    monkeypatch.setattr(registry, "_REGISTRY", dict(registry._REGISTRY))
    CALLS.clear()
    return register(KITCHEN)


def _help(argv: list[str], capsys) -> str:
    with pytest.raises(SystemExit) as e:
        main([*argv, "--help"])
    assert e.value.code == 0
    return capsys.readouterr().out


def test_the_built_in_families_and_their_facts():
    assert registry.family_names() == ("tabletop", "robot")
    assert registry.DEFAULT_FAMILY == "tabletop"
    assert shipped_model_path() == bundled_assets() / "model.pt"
    assert shipped_model_path("robot") == bundled_assets() / "robot" / "model.pt"
    assert registry.family_of_generator("particlesplat.data.families.robot_wide") == "robot"
    assert registry.family_of_generator("particlesplat.data.synth") == "tabletop"
    assert registry.family_of_generator("elsewhere") is None
    # the tabletop rig's distances are its generator's draws; the robot rigs' cover the narrow world's arc and
    # the wide world's arc and RLBench-style cameras
    from particlesplat.data.families import tabletop

    assert get_family("tabletop").camera_distances == tabletop.DISTANCE_RANGE
    assert get_family("robot").camera_distances == (0.8, 1.25)
    firsts = {p.parent.relative_to(bundled_assets()).as_posix(): p for p in reversed(demo_scenes())}
    assert list(firsts)[::-1] == ["scenes", "robot/scenes"]  # the default family's demo scenes first
    names = [demo_scene_name(p) for p in demo_scenes()]  # the viewer's picker: the robot's after its family
    assert names[0] == "scene_00000" and "robot/scene_00019" in names and "scenes/scene_00019" not in names


def test_a_registered_family_is_offered_and_run_by_synth(kitchen, tmp_path, capsys):
    assert "--family {tabletop,robot,kitchen}" in _help(["synth"], capsys)
    assert "kitchen (a counter with crockery)" in _help(["synth"], capsys).replace("\n", " ")
    assert "--family {tabletop,robot,kitchen}" in _help(["scene", "check"], capsys)
    out = tmp_path / "k"
    assert main(["synth", "--family", "kitchen", str(out), "--train", "3", "--val", "1", "--test", "0"]) == 0
    assert CALLS == [(out, {"train": 3, "val": 1, "test": 0, "heldout": 0}, 0, "narrow")]
    assert f"wrote 4 scenes to {out}, 0.25 s per scene per worker" in capsys.readouterr().out
    # its held-out split: only in the world it registers, and the refusal names every family's
    argv = ["synth", "--family", "kitchen", str(out), "--train", "0", "--test", "0", "--heldout", "2"]
    assert main([*argv, "--world", "wide", "--seed", "5"]) == 0
    assert CALLS[-1] == (out, {"train": 0, "val": 32, "test": 0, "heldout": 2}, 5, "wide")
    with pytest.raises(UserError) as e:
        main(argv)
    assert str(e.value) == (
        "--heldout: only the robot family's wide world (--family robot --world wide) or the kitchen family's wide "
        "world (--family kitchen --world wide) has one"
    )
    assert len(CALLS) == 2


def test_an_unregistered_family_is_no_choice(capsys, tmp_path):
    CALLS.clear()
    with pytest.raises(SystemExit) as e:
        main(["synth", "--family", "kitchen", str(tmp_path / "k")])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert re.search(r"invalid choice: 'kitchen' \(choose from '?tabletop'?, '?robot'?\)", err), err
    assert not CALLS and not (tmp_path / "k").exists()


def test_scene_json_may_record_a_registered_family_and_opens_with_its_model(kitchen, tmp_path):
    scene = tmp_path / "mine"
    shutil.copytree(ROOT / "assets" / "scenes" / "scene_00000", scene)
    (scene / "scene.json").write_text(json.dumps({"family": "kitchen"}))
    assert read_family(scene) == "kitchen"
    assert default_checkpoint(scene) == bundled_assets() / "kitchen" / "model.pt"
    assert shipped_model_name(bundled_assets() / "kitchen" / "model.pt") == "assets/kitchen/model.pt"
    # a dataset whose synth.json records only the kitchen generator is of the kitchen family
    data = tmp_path / "data"
    (data / "test").mkdir(parents=True)
    (data / "synth.json").write_text(json.dumps({"generator": "tests.kitchen_generator"}))
    assert read_family(data / "test") == "kitchen"
    assert "assets/kitchen/model.pt" in registry.checkpoint_help()


def test_an_unknown_family_is_refused_naming_the_registered_ones(kitchen, tmp_path):
    (tmp_path / "scene.json").write_text(json.dumps({"family": "zeppelin"}))
    with pytest.raises(UserError) as e:
        read_family(tmp_path)
    assert str(e.value) == f"{tmp_path / 'scene.json'}: key 'family' is 'zeppelin', not one of tabletop, robot, kitchen"
    with pytest.raises(ValueError, match=r"no scene family 'zeppelin' \(registered: tabletop, robot, kitchen\)"):
        shipped_model_path("zeppelin")


def test_the_kitchen_is_unknown_once_the_test_registering_it_is_over(tmp_path):
    (tmp_path / "scene.json").write_text(json.dumps({"family": "kitchen"}))
    with pytest.raises(UserError, match=r"key 'family' is 'kitchen', not one of tabletop, robot$"):
        read_family(tmp_path)


def test_scene_check_judges_a_scene_by_its_family_s_rigs(kitchen, capsys):
    """The tabletop demo scene, judged as a kitchen scene: the kitchen's cameras stand ten times as far, so the
    scale differs by 10 (the report quotes the registered distances); no robot is looked for."""
    scene = str(demo_scenes()[0])
    assert main(["scene", "check", scene, "--family", "kitchen"]) == 1
    out = capsys.readouterr().out
    assert "kitchen family" in out and "the kitchen training scenes' are 30-36 m" in out
    assert "s = 10," in out and "robot:" not in out
    assert main(["scene", "check", scene]) == 0  # the same scene as what it records: the tabletop family


def test_register_refuses_a_second_family_of_a_name_or_generator(kitchen):
    from dataclasses import replace

    with pytest.raises(ValueError, match="'kitchen' is registered already"):
        register(KITCHEN)
    with pytest.raises(ValueError, match="generator 'particlesplat.data.synth' is 'tabletop''s"):
        register(replace(KITCHEN, name="pantry", generators=("particlesplat.data.synth",)))
    assert registry.family_names() == ("tabletop", "robot", "kitchen")


def test_importing_the_registry_loads_nothing_heavy():
    script = (
        "import sys; from particlesplat.data.families import families; [f.name for f in families()]; "
        "print(sorted(m for m in ('torch', 'mujoco', 'numpy', 'robosuite') if m in sys.modules))"
    )
    proc = subprocess.run([sys.executable, "-c", script], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.strip() == "[]"


def _family_literals(tree: ast.AST, names: set[str]) -> list[int]:
    """Lines that compare a value with a family name or list two family names (a tuple, list, set or dict)."""
    lines = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Compare):
            operands = [node.left, *node.comparators]
            if any(isinstance(o, ast.Constant) and o.value in names for o in operands):
                lines.append(node.lineno)
        elif isinstance(node, (ast.Tuple, ast.List, ast.Set, ast.Dict)):
            items = node.keys if isinstance(node, ast.Dict) else node.elts
            if sum(isinstance(i, ast.Constant) and i.value in names for i in items) >= 2:
                lines.append(node.lineno)
    return lines


def test_no_module_outside_the_families_folder_names_the_families():
    """Choices, checks and branches on a family name read the registry: outside ``particlesplat/data/families/``
    no code compares with ``"robot"`` or ``"tabletop"`` or lists them."""
    names = set(registry.family_names())
    found = []
    for pkg in ("particlesplat", "viewer"):
        for path in sorted((ROOT / pkg).rglob("*.py")):
            if (ROOT / "particlesplat" / "data" / "families") in path.parents:
                continue
            for line in _family_literals(ast.parse(path.read_text(), str(path)), names):
                found.append(f"{path.relative_to(ROOT)}:{line}")
    assert found == []
    # the check finds what it looks for
    assert _family_literals(ast.parse('x = family == "robot"\ny = ("tabletop", "robot")'), names) == [1, 2]


def test_synth_writes_the_world_the_shipped_robot_model_was_trained_on(monkeypatch, tmp_path, capsys):
    """Without ``--world``, ``synth --family robot`` writes the world its shipped model was trained on (the wide one:
    the shipped robot demo scenes, test scenes of that model's dataset, record it), and its help says so; the
    other world is one option away, and a family of one world gets the narrow default as before."""
    import dataclasses

    robot = get_family("robot")
    demo_worlds = {
        json.loads((p / "scene.json").read_text()).get("world")
        for p in demo_scenes()
        if p.parent == bundled_assets() / robot.demo_scenes
    }
    assert demo_worlds == {"wide"} == {robot.model_world}
    text = " ".join(_help(["synth"], capsys).split())
    assert "the wide, randomised world in robosuite's frame (robot at -x), which the shipped robot model was" in text
    assert "default: the world of the family's shipped model (robot: wide), else narrow" in text
    monkeypatch.setattr(registry, "_REGISTRY", dict(registry._REGISTRY))
    registry._REGISTRY["robot"] = dataclasses.replace(robot, generator=f"{__name__}:_fake_generate")
    CALLS.clear()
    out = tmp_path / "r"
    assert main(["synth", "--family", "robot", str(out), "--train", "1", "--val", "0", "--test", "0"]) == 0
    assert main(["synth", "--family", "robot", str(out), "--world", "narrow", "--train", "1"]) == 0
    assert [c[3] for c in CALLS] == ["wide", "narrow"]


def test_the_readme_states_each_family_s_camera_distances_as_scene_check_judges_them():
    """The README's data section gives each generator's camera distances as the registry's ranges, which
    ``scene check`` judges a capture against (a shipped wide robot scene: 1.15 m, within 0.8-1.25 m)."""
    text = " ".join((ROOT / "README.md").read_text().split())
    for name, phrase in (("tabletop", "21 cameras {}–{} m away"), ("robot", "21 cameras {}–{} m away (or 4")):
        low, high = get_family(name).camera_distances
        assert phrase.format(f"{low:g}", f"{high:g}") in text, (name, low, high)
    robot_demo = next(p for p in demo_scenes() if p.parent == bundled_assets() / get_family("robot").demo_scenes)
    distance = json.loads((robot_demo / "scene.json").read_text())["distance"]
    assert get_family("robot").camera_distances[0] <= distance <= get_family("robot").camera_distances[1]
