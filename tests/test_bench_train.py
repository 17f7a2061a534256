"""``particlesplat bench train``: phase timings of a recipe's steps, from random initialisation or a run's copy."""

from __future__ import annotations

import hashlib
import json

from model_data import tiny_config, tiny_dataset

from particlesplat.cli.main import console_main, main


def _digests(folder):
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.iterdir()) if p.is_file()}


def test_bench_train_times_the_phases_of_a_run_copy_and_leaves_the_run_alone(tmp_path_factory, tmp_path, capsys):
    data = tiny_dataset(tmp_path_factory)
    cfg = tiny_config(tmp_path / "tiny.yaml", steps=6, val_every=10)
    run = tmp_path / "run"
    assert main(["train", "--config", str(cfg), "--data", str(data), "--out", str(run), "--stop-after", "3"]) == 0
    before = _digests(run)
    capsys.readouterr()
    out_json = tmp_path / "bench.json"
    args = ["bench", "train", "--data", str(data), "--run", str(run), "--steps", "2", "--warmup", "1"]
    assert main([*args, "--threads", "1", "--json", str(out_json)]) == 0
    text = capsys.readouterr().out
    assert "| threads | rasterizer | s/step | data | forward | backward | update |" in text
    assert "(steps 3-6:" in text  # the copy resumed at the run's step; the run's own config was used
    (row,) = json.loads(out_json.read_text())["rows"]
    assert row["threads"] == 1 and row["start_step"] == 3 and row["recipe_steps"] == 6
    assert row["rasterizer"] == "fused"  # the CPU default
    phases = sum(row[f"{p}_s"] for p in ("data", "forward", "backward", "update"))
    assert 0 < phases <= row["step_s"] * 1.05 + 1e-3  # the phases add up to (about) the step, none left out
    assert row["forward_s"] > 0 and row["backward_s"] > 0
    assert _digests(run) == before  # the run folder was only read


def test_bench_train_refuses_bad_options_in_one_line(tmp_path_factory, tmp_path, capsys, monkeypatch):
    data = tiny_dataset(tmp_path_factory)
    cases = [
        (["--data", str(data), "--run", str(tmp_path)], "no last.pt"),
        (["--data", str(tmp_path)], "no train/ folder"),
        (["--data", str(data), "--threads", "0"], "thread counts must be >= 1"),
        (["--data", str(data), "--threads", "two"], "comma-separated list"),
        (["--data", str(data), "--steps", "0"], "--steps must be >= 1"),
    ]
    for argv, message in cases:
        monkeypatch.setattr("sys.argv", ["particlesplat", "bench", "train", *argv])
        assert console_main() == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and message in err, err
