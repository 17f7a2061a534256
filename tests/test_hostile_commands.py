"""Hostile input at the commands: eval's outputs and limits, render's image size, the console
script's error policy (one line, exit 2; Ctrl-C one line, exit 130)."""

from __future__ import annotations

import json
import shutil
import signal
import subprocess
import sys
import time

import pytest
import torch
from model_data import TINY_MODEL, tiny_dataset

from particlesplat.cli.main import main
from particlesplat.core.errors import EXIT_INTERRUPTED, EXIT_USER, run_command


@pytest.fixture(scope="module")
def tiny_ckpt(tmp_path_factory):
    from particlesplat.model import ParticleSplat, save_checkpoint
    from particlesplat.model.config import model_config_from_dict

    torch.manual_seed(0)
    path = tmp_path_factory.mktemp("ckpt") / "m.pt"
    save_checkpoint(path, ParticleSplat(model_config_from_dict(TINY_MODEL)), 0)
    return path


def _snapshot(folder):
    return {p: p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def test_eval_limit_zero_is_an_error(tiny_ckpt, tmp_path_factory):
    data = tiny_dataset(tmp_path_factory)
    with pytest.raises(ValueError, match="--limit must be >= 1"):
        main(["eval", "--checkpoint", str(tiny_ckpt), "--data", str(data / "val"), "--limit", "0"])


def test_eval_scene_without_non_context_targets_is_an_error(tiny_ckpt, tmp_path_factory, tmp_path):
    data = tiny_dataset(tmp_path_factory)
    scene = tmp_path / "split" / "two"
    shutil.copytree(next((data / "val").iterdir()), scene)
    meta = json.loads((scene / "transforms.json").read_text())
    meta["frames"] = meta["frames"][:2]
    (scene / "transforms.json").write_text(json.dumps(meta))
    with pytest.raises(ValueError, match=r"two: 2 frame\(s\): no target view apart from the 2 context view\(s\)"):
        main(["eval", "--checkpoint", str(tiny_ckpt), "--data", str(tmp_path / "split")])


def test_eval_json_is_strict_json_with_null_for_nan(tiny_ckpt, tmp_path_factory, tmp_path):
    data = tiny_dataset(tmp_path_factory)
    out = tmp_path / "m.json"
    assert main(["eval", "--checkpoint", str(tiny_ckpt), "--data", str(data / "val"), "--json", str(out)]) == 0
    text = out.read_text()
    assert "NaN" not in text and "Infinity" not in text
    json.loads(text, parse_constant=lambda c: pytest.fail(f"non-standard JSON constant {c}"))


def test_eval_outputs_are_checked_before_the_work(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("")
    t0 = time.perf_counter()
    for flag in ("--json", "--figures"):
        # the checkpoint does not exist either: the output is checked first, before any loading
        with pytest.raises(OSError, match=rf"{blocker}/x.*cannot write"):
            main(
                [
                    "eval",
                    "--checkpoint",
                    str(tmp_path / "missing.pt"),
                    "--data",
                    str(tmp_path),
                    flag,
                    str(blocker / "x"),
                ]
            )
    assert _snapshot(tmp_path) == {blocker: b""}
    assert time.perf_counter() - t0 < 60  # (a hang guard, not a timing test)


def test_eval_json_to_a_device_is_refused(tmp_path):
    with pytest.raises(OSError, match="/dev/null: is a device node; refusing to replace it"):
        main(["eval", "--data", str(tmp_path), "--json", "/dev/null"])


def test_render_width_is_bounded(tmp_path):
    from viewer.bench.random_gaussians import random_gaussians

    random_gaussians(50, seed=1).save_ply(tmp_path / "g.ply")
    assert (
        main(["render", "--ply", str(tmp_path / "g.ply"), "--width", "40000", "--out", str(tmp_path / "o.png")])
        == EXIT_USER
    )
    assert not (tmp_path / "o.png").exists()


def test_run_command_policy(capsys):
    from particlesplat.core.errors import UserError, warn_input

    def user():
        raise UserError("f.yaml: lr: bad\nsecond line")

    def interrupted():
        raise KeyboardInterrupt

    def bug():
        raise ZeroDivisionError("a bug")

    def bare_value_error():  # a bug in the library, not the user's input: it keeps its traceback
        raise ValueError("internal: shapes differ")

    def warns():
        warn_input("scene/transforms.json: frames[0]: 'fl_x' 0.001 pixels\nfor a 64x64 image")
        return 0

    assert run_command("prog", user) == EXIT_USER
    assert capsys.readouterr().err == "prog: error: f.yaml: lr: bad second line\n"
    assert run_command("prog", interrupted) == EXIT_INTERRUPTED
    assert capsys.readouterr().err == "prog: interrupted\n"
    with pytest.raises(ZeroDivisionError):
        run_command("prog", bug)
    with pytest.raises(ValueError, match="internal"):
        run_command("prog", bare_value_error)
    assert run_command("prog", warns) == 0
    assert (
        capsys.readouterr().err
        == "prog: warning: scene/transforms.json: frames[0]: 'fl_x' 0.001 pixels for a 64x64 image\n"
    )


def test_console_script_ctrl_c_is_one_line(tmp_path):
    """SIGINT while a command works: one line on stderr, exit code 130, no traceback. The child says it is ready
    from inside the command, and restores Python's SIGINT handler first: a suite started in the background passes
    SIGINT on ignored."""
    proc = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import signal, time, sys; signal.signal(signal.SIGINT, signal.default_int_handler); "
            "from particlesplat.core.errors import run_command; "
            "sys.exit(run_command('particlesplat x', lambda: (print('ready', flush=True), time.sleep(60))))",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert proc.stdout.readline().strip() == "ready"
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == EXIT_INTERRUPTED and err == "particlesplat x: interrupted\n"
