"""``particlesplat eval --data DATASET``: each split of a dataset folder in turn, one table row and one JSON entry a
split, equal to evaluating each split folder on its own; the splits chosen or refused in one line."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from model_data import tiny_dataset, untrained_tiny_checkpoint

from particlesplat.cli.main import main
from particlesplat.core.errors import EXIT_USER, OptionError, run_command
from particlesplat.data.folders import choose_splits, dataset_splits
from particlesplat.data.synth import scene_name, write_scene

ROOT = Path(__file__).resolve().parents[1]
TIMES = {"encode_ms", "fit_ms", "decode_ms", "render_ms"}  # wall-clock times: they differ from run to run


@pytest.fixture(scope="module")
def tiny_ckpt(tmp_path_factory):
    return untrained_tiny_checkpoint(tmp_path_factory.mktemp("ckpt"))


@pytest.fixture(scope="module")
def two_splits(tmp_path_factory):
    """DATA/{val, test} (the tiny dataset's validation scene) and DATA/heldout (a scene of its own)."""
    root = tmp_path_factory.mktemp("two_splits")
    val = tiny_dataset(tmp_path_factory) / "val"
    for split in ("val", "test"):
        shutil.copytree(val, root / split)
    write_scene(root / "heldout" / scene_name(0), 0, "heldout", 0, 32)
    return root


def _untimed(value):
    """``value`` without its wall-clock times."""
    if isinstance(value, dict):
        return {k: _untimed(v) for k, v in value.items() if k not in TIMES}
    if isinstance(value, list):
        return [_untimed(v) for v in value]
    return value


def _eval(ckpt, data, json_path, *extra):
    assert main(["eval", "--checkpoint", str(ckpt), "--data", str(data), "--json", str(json_path), *extra]) == 0
    return json.loads(json_path.read_text())


def test_a_dataset_folder_gets_a_row_and_an_entry_per_split_equal_to_each_split_alone(
    tiny_ckpt, two_splits, tmp_path, capsys
):
    figures = tmp_path / "fig"
    res = _eval(tiny_ckpt, two_splits, tmp_path / "all.json", "--figures", str(figures), "--num-figures", "1")
    printed = capsys.readouterr().out.splitlines()
    # test and heldout by default (val is there too, but not read), in that order; the record of the options
    assert list(res["splits"]) == ["test", "heldout"]
    said = (
        f"{two_splits}: not evaluated: val (val: the scenes its checkpoint is chosen on); --splits val,test,heldout "
        "evaluates every split"
    )
    assert said in printed  # what it leaves out, why, and how to read it
    assert (res["data"], res["context"], res["depth"]) == (str(two_splits), 2, True)
    alone = {s: _eval(tiny_ckpt, two_splits / s, tmp_path / f"{s}.json") for s in ("test", "heldout")}
    capsys.readouterr()
    for split in ("test", "heldout"):
        assert _untimed(res["splits"][split]) == _untimed(alone[split])
        assert res["splits"][split]["data"] == str(two_splits / split)
    test, heldout = (res["splits"][s]["mean"] for s in ("test", "heldout"))
    assert test["psnr"] != heldout["psnr"]  # two different scenes: the rows cannot be swapped unnoticed
    # the table: a header, then one row a split with its scene count and its means as printed
    (head,) = [i for i, line in enumerate(printed) if line.startswith("split ")]
    rows = {line.split()[0]: line for line in printed[head + 1 : head + 3]}
    assert set(rows) == {"test", "heldout"}
    for split, row in rows.items():
        m = res["splits"][split]["mean"]
        cells = row.split()
        assert cells[1] == "1" and cells[2] == f"{m['psnr']:.2f}" and cells[6] == f"{m['ssim']:.3f}"
        assert cells[3] == f"{m['psnr_seen']:.2f}" and cells[4] == f"{m['psnr_unseen']:.2f}"
        assert cells[5] == f"{100 * m['object_held']:.1f}"
        assert f"{m['fg_ari']:.3f}" in cells and f"{m['objects']:.1f}" in cells
        loc = res["splits"][split]["localisation"]["resting"]
        assert f"{loc['within_0.05']:.0%}" == cells[-6] and cells[-1] == f"{loc['median_m']:.3f}"
    assert "test:" in printed and "heldout:" in printed  # each split's error by region and localisation below
    # the figures: a folder per split
    assert sorted(p.relative_to(figures).as_posix() for p in figures.rglob("*.png")) == [
        "heldout/scene_00000.png",
        "test/scene_00000.png",
    ]


def test_splits_chooses_which_and_in_what_order(tiny_ckpt, two_splits, tmp_path, capsys):
    res = _eval(tiny_ckpt, two_splits, tmp_path / "v.json", "--splits", "val")
    assert list(res["splits"]) == ["val"]
    printed = capsys.readouterr().out.splitlines()
    assert sum(line.startswith("val ") for line in printed) == 1
    assert choose_splits(two_splits, dataset_splits(two_splits), "heldout, val,heldout", "--splits") == [
        "heldout",
        "val",
    ]
    assert dataset_splits(two_splits) == ("val", "test", "heldout")
    assert dataset_splits(two_splits / "test") == ()  # a split folder
    assert dataset_splits(tmp_path / "absent") == ()


def test_splits_reads_the_training_and_validation_splits_too(tiny_ckpt, tmp_path_factory, tmp_path, capsys):
    """``--splits train,val``: a row each, as each split folder alone; no line about left-out splits."""
    data = tiny_dataset(tmp_path_factory)
    res = _eval(tiny_ckpt, data, tmp_path / "tv.json", "--splits", "train,val")
    printed = capsys.readouterr().out
    assert list(res["splits"]) == ["train", "val"] and "not evaluated" not in printed
    assert len(res["splits"]["train"]["scenes"]) == 2
    alone = _eval(tiny_ckpt, data / "train", tmp_path / "t.json")
    assert _untimed(res["splits"]["train"]) == _untimed(alone)


def _refusal(argv, capsys) -> str:
    """The one line (exit 2) a refused command prints; nothing on stdout."""
    assert run_command("particlesplat eval", lambda: main(["eval", *argv])) == EXIT_USER
    out, err = capsys.readouterr()
    assert out == "" and len(err.splitlines()) == 1
    return err


def test_refusals_name_the_folder_and_its_splits(tiny_ckpt, two_splits, tmp_path_factory, tmp_path, capsys):
    only_train_val = tiny_dataset(tmp_path_factory)
    err = _refusal(["--data", str(only_train_val)], capsys)
    assert str(only_train_val) in err and "without test or heldout" in err and "its splits: train, val" in err
    assert err.rstrip().endswith("choose with --splits train,val")
    err = _refusal(["--data", str(only_train_val), "--splits", "val,heldout"], capsys)
    assert str(only_train_val) in err and "no heldout split" in err and "its splits: train, val" in err
    err = _refusal(["--data", str(two_splits / "test"), "--splits", "test"], capsys)
    assert "--splits" in err and "is a split folder" in err
    for bad in ("typo", "test,typo", ","):
        with pytest.raises(OptionError, match="--splits must name some of train,val,test,heldout"):
            main(["eval", "--data", str(two_splits), "--splits", bad])
    # the output guard: the dataset itself, and a split's figure folder that is the dataset
    err = _refusal(["--data", str(two_splits), "--figures", str(two_splits)], capsys)
    assert "which this command reads" in err
    named_test = tmp_path / "x" / "test"
    for split in ("test", "heldout"):
        shutil.copytree(two_splits / split, named_test / split)
    err = _refusal(
        ["--checkpoint", str(tiny_ckpt), "--data", str(named_test), "--figures", str(tmp_path / "x")], capsys
    )
    assert f"--figures {tmp_path / 'x' / 'test'}: is --data" in err


def test_a_refused_split_is_answered_before_torch_loads(two_splits):
    """A typo in --splits is one quick line: the command ends before it imports torch."""
    script = (
        "import sys\n"
        "from particlesplat.cli.main import main\n"
        "try:\n"
        f"    main(['eval', '--data', {str(two_splits)!r}, '--splits', 'test,heldot'])\n"
        "except ValueError as e:\n"
        "    print(e)\n"
        "print('torch' in sys.modules)\n"
    )
    proc = subprocess.run([sys.executable, "-c", script], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.splitlines() == ["--splits must name some of train,val,test,heldout, got 'test,heldot'", "False"]


def test_the_shipped_model_eval_chose_is_an_input_its_outputs_may_not_replace(
    tiny_ckpt, two_splits, tmp_path, monkeypatch, capsys
):
    """Without --checkpoint, eval opens the family's shipped model: --json naming that file is one line, exit 2,
    and the model is left as it was."""
    import particlesplat.data.scene_meta as scene_meta

    shipped = tmp_path / "shipped.pt"
    shutil.copy(tiny_ckpt, shipped)
    before = shipped.read_bytes()
    monkeypatch.setattr(scene_meta, "default_checkpoint", lambda data: shipped)
    code = run_command(
        "particlesplat eval", lambda: main(["eval", "--data", str(two_splits / "test"), "--json", str(shipped)])
    )
    assert code == EXIT_USER
    assert "shipped model" in capsys.readouterr().err
    assert shipped.read_bytes() == before
