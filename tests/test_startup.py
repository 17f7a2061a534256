"""What a command answers before any work comes before torch loads (help, argument and path errors: measured by
``particlesplat bench startup``), a dataset root named where a split is meant gets the split's name, and Ctrl-C
ends a console script at once after its one line."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from particlesplat.data.folders import check_split_folder

ROOT = Path(__file__).resolve().parents[1]

# (arguments, exit code) of quick answers; "error" = an exception the error policy turns into one line
QUICK = [
    (["train", "--help"], 0),
    (["eval", "--help"], 0),
    (["render", "--help"], 0),
    (["encode", "--help"], 0),
    (["object", "export", "--help"], 0),
    (["model", "set", "--help"], 0),
    (["synth", "--help"], 0),
    (["export", "--help"], 0),
    (["scene", "check", "--help"], 0),
    (["curve", "--help"], 0),
    (["policy", "collect", "--help"], 0),
    (["policy", "collect", "--out", "OUT", "--episodes", "0"], "error"),
    (["eval", "--data", "MISSING"], "error"),
    (["eval", "--data", "assets/scenes", "--checkpoint", "MISSING.pt"], "error"),
    (["encode", "--data", "MISSING", "--out", "OUT"], "error"),
    (["render", "--scene", "MISSING", "--out", "OUT.png"], 2),
    (["render", "--edits", "MISSING.yaml", "--out", "OUT.png"], 2),
    (["render", "--mode", "rgb,typo", "--out", "OUT.png"], 2),
    (["render", "--view", "4,4", "--out", "OUT.png"], 2),
    (["render", "--rasterizer", "typo", "--out", "OUT.png"], 2),
    (["export", "--scene", "MISSING", "--out", "OUT.ply"], 2),
    (["export", "--ply", "MISSING.spz", "--out", "OUT.ply"], 2),
    (["synth", "OUT", "--heldout", "2"], "error"),
    (["train", "--data", "MISSING", "--out", "OUT"], "error"),
    (["train", "--data", "DATA", "--out", "OUT", "train.stepz=5"], "error"),
    (["train", "--data", "DATA", "--out", "OUT", "train.steps=many"], "error"),
]


def test_quick_answers_come_before_torch_loads(tmp_path):
    """Each case runs in one fresh interpreter, in turn: none of them imports torch (a user's typo, or --help, is
    answered in a fraction of a second rather than after torch's 1-5 s import)."""
    data = tmp_path / "data"
    (data / "train").mkdir(parents=True)
    cases = [
        (
            [
                a.replace("MISSING", str(tmp_path / "missing"))
                .replace("OUT", str(tmp_path / "out"))
                .replace("DATA", str(data))
                for a in argv
            ],
            code,
        )
        for argv, code in QUICK
    ]
    script = textwrap.dedent(
        f"""
        import sys
        from particlesplat.cli.main import main
        from particlesplat.core.errors import is_user_error
        for argv, expected in {cases!r}:
            try:
                code = main(argv)
            except SystemExit as e:
                code = e.code
            except Exception as e:
                assert is_user_error(e), (argv, e)
                code = "error"
            assert code == expected, (argv, code, expected)
            assert "torch" not in sys.modules, argv
        print("ok")
        """
    )
    proc = subprocess.run([sys.executable, "-c", script], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.strip().endswith("ok")


def _scenes(folder: Path, names: list[str]) -> None:
    for n in names:
        (folder / n).mkdir(parents=True)
        (folder / n / "transforms.json").write_text("{}")


def test_a_dataset_root_names_its_split(tmp_path):
    _scenes(tmp_path / "test", ["scene_00000"])
    _scenes(tmp_path / "train", ["scene_00000"])
    with pytest.raises(FileNotFoundError) as e:
        check_split_folder(tmp_path, "--data")
    assert f"--data {tmp_path / 'test'}" in str(e.value) and "dataset root" in str(e.value)
    assert check_split_folder(tmp_path / "test", "--data") == tmp_path / "test"
    with pytest.raises(FileNotFoundError, match="name the folder that holds it"):
        check_split_folder(tmp_path / "test" / "scene_00000", "--data")
    with pytest.raises(FileNotFoundError, match="no such folder"):
        check_split_folder(tmp_path / "nothing", "--data")
    (tmp_path / "empty").mkdir()
    with pytest.raises(FileNotFoundError, match="no scene folders"):
        check_split_folder(tmp_path / "empty", "--data")


def test_interrupt_ends_at_once_with_its_line_and_code():
    """After the one line of Ctrl-C the process ends with 130, its output flushed, and the interpreter's teardown is
    skipped (an atexit handler would print: it does not)."""
    script = textwrap.dedent(
        """
        import atexit, sys
        from particlesplat.core.errors import end_at_once_if_interrupted, run_command
        atexit.register(lambda: print("teardown ran"))
        def work():
            print("working", end="")  # unflushed
            raise KeyboardInterrupt
        sys.exit(end_at_once_if_interrupted(run_command("prog", work)))
        """
    )
    proc = subprocess.run([sys.executable, "-c", script], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 130
    assert proc.stdout == "working" and proc.stderr.strip() == "prog: interrupted"
    ok = subprocess.run(
        [sys.executable, "-c", script.replace("raise KeyboardInterrupt", "return 0")],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert ok.returncode == 0 and "teardown ran" in ok.stdout


def test_the_viewer_without_a_display_ends_with_one_line():
    """No DISPLAY (a server, an ssh session): one line naming DISPLAY and xvfb-run, exit code 2, before the scene
    is encoded; no traceback."""
    import os

    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    proc = subprocess.run(
        [sys.executable, "-m", "viewer"], cwd=ROOT, env=env, capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == 2
    assert proc.stderr.count("\n") == 1 and "Traceback" not in proc.stderr
    assert "DISPLAY" in proc.stderr and "xvfb-run -a particlesplat-viewer" in proc.stderr
