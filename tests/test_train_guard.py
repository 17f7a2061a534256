"""A finished run is never overwritten by accident; the console script reports bad input without a traceback."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
from model_data import tiny_config, tiny_dataset

from particlesplat.cli.main import main
from particlesplat.model import read_checkpoint


def test_existing_run_needs_resume(tmp_path_factory, tmp_path):
    data = tiny_dataset(tmp_path_factory)
    cfg = tiny_config(tmp_path / "tiny.yaml", steps=1, val_every=5)
    argv = ["train", "--config", str(cfg), "--data", str(data), "--out", str(tmp_path / "r")]
    assert main(argv) == 0
    before = (tmp_path / "r" / "last.pt").read_bytes()
    with pytest.raises(FileExistsError, match="not empty; pass --resume"):
        main(argv)
    assert (tmp_path / "r" / "last.pt").read_bytes() == before
    assert read_checkpoint(tmp_path / "r" / "last.pt")["step"] == 1


def test_overwrite_starts_a_new_run_and_keeps_foreign_files(tmp_path_factory, tmp_path):
    data = tiny_dataset(tmp_path_factory)
    out = tmp_path / "r"
    first = [
        "train",
        "--config",
        str(tiny_config(tmp_path / "a.yaml", steps=4, val_every=2)),
        "--data",
        str(data),
        "--out",
        str(out),
    ]
    assert main(first) == 0
    assert (out / "step_000004.pt").is_file()
    (out / "notes.txt").write_text("mine")
    second = [
        "train",
        "--config",
        str(tiny_config(tmp_path / "b.yaml", steps=1, val_every=5)),
        "--data",
        str(data),
        "--out",
        str(out),
        "--overwrite",
    ]
    assert main(second) == 0
    # the earlier run's step files are gone, not mixed with the new run's
    assert sorted(p.name for p in out.glob("step_*.pt")) == ["step_000001.pt"]
    steps = [json.loads(line)["step"] for line in (out / "metrics.jsonl").read_text().splitlines()]
    assert set(steps) == {1}  # a new log (a training and a validation record), not the old one continued
    assert read_checkpoint(out / "last.pt")["step"] == 1
    assert (out / "notes.txt").read_text() == "mine"


def test_console_script_reports_bad_input_in_one_line(tmp_path):
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "particlesplat.cli",
            "render",
            "--scene",
            str(tmp_path / "missing"),
            "--out",
            str(tmp_path / "x.png"),
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode != 0
    assert "Traceback" not in proc.stderr
    assert "missing" in proc.stderr
