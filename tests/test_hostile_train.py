"""Training hygiene under hostile conditions: torn logs, roll back to a step_*.pt, non-finite
gradients and weights, stale temporaries, a corrupt validation scene, SIGINT/SIGTERM, a full disk."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
from model_data import TINY_MODEL, tiny_config, tiny_dataset

from particlesplat.cli.main import main
from particlesplat.model import ModelConfig, TrainConfig, read_checkpoint
from particlesplat.training.runlog import LogError, read_log
from particlesplat.training.trainer import MAX_SKIPPED, Trainer, TrainingDiverged


def _train(cfg, data, out, *extra) -> int:
    return main(["train", "--config", str(cfg), "--data", str(data), "--out", str(out), *extra])


def _trainer(data, out, **tc) -> Trainer:
    return Trainer(
        ModelConfig(**TINY_MODEL),
        TrainConfig(**{"batch_size": 1, "target_views": 1, "steps": 4, "val_scenes": 1, **tc}),
        Path(data),
        out,
        "cpu",
        False,
    )


def test_read_log_leaves_out_a_torn_last_line_and_names_it(tmp_path):
    p = tmp_path / "metrics.jsonl"
    p.write_bytes(b'{"step": 1}\n{"step": 2}\n{"step": 3, "loss": "ab')
    records, note = read_log(p)
    assert records == [{"step": 1}, {"step": 2}]
    assert note.startswith(f"{p}: line 3 is torn")
    p.write_bytes(b'{"step": 1}\n{"ste\n{"step": 3}\n')
    with pytest.raises(LogError, match=rf"{p}: line 2: not a JSON object"):
        read_log(p)


def test_resume_repairs_a_torn_log(tmp_path_factory, tmp_path, capsys):
    data = tiny_dataset(tmp_path_factory)
    cfg = tiny_config(tmp_path / "tiny.yaml", steps=3, val_every=10)
    assert _train(cfg, data, tmp_path / "r", "--stop-after", "2") == 0
    log = tmp_path / "r" / "metrics.jsonl"
    with open(log, "ab") as f:
        f.write(b'{"step": 3, "loss": 12.')  # the disk filled up mid-line
    assert _train(cfg, data, tmp_path / "r", "--resume") == 0
    assert f"{log}: line 3 is torn" in capsys.readouterr().err
    records = [json.loads(x) for x in log.read_text().splitlines()]
    assert [r["step"] for r in records if "loss" in r] == [1, 2, 3]


def test_any_step_checkpoint_resumes(tmp_path_factory, tmp_path, capsys):
    data = tiny_dataset(tmp_path_factory)
    cfg = tiny_config(tmp_path / "tiny.yaml", steps=4, val_every=2)
    assert _train(cfg, data, tmp_path / "r") == 0
    shutil.copyfile(tmp_path / "r" / "step_000002.pt", tmp_path / "r" / "last.pt")  # roll back
    cfg.write_text(cfg.read_text().replace("steps: 4", "steps: 3"))
    assert _train(cfg, data, tmp_path / "r", "--resume") == 0
    assert "no optimizer or RNG state" in capsys.readouterr().err
    assert read_checkpoint(tmp_path / "r" / "last.pt")["step"] == 3


def test_non_finite_gradients_skip_the_step(tmp_path_factory, tmp_path):
    tr = _trainer(tiny_dataset(tmp_path_factory), tmp_path / "o")
    param = next(tr.model.parameters())
    before = {k: v.clone() for k, v in tr.model.state_dict().items()}
    hook = param.register_hook(lambda g: g * float("nan"))
    assert tr.train_step() == {"skipped": 1.0}
    assert tr.step == 1
    for k, v in tr.model.state_dict().items():
        assert torch.equal(v, before[k]), k  # nothing moved: clipping did not spread the NaN
    hook.remove()
    assert "loss" in tr.train_step()


def test_a_diverged_run_stops_without_saving(tmp_path_factory, tmp_path):
    data = tiny_dataset(tmp_path_factory)
    tr = _trainer(data, tmp_path / "o", steps=MAX_SKIPPED + 5, ckpt_every=1000, val_every=1000)
    tr.run(stop_after=1)
    saved = (tmp_path / "o" / "last.pt").read_bytes()
    hook = next(tr.model.parameters()).register_hook(lambda g: g * float("nan"))
    with pytest.raises(TrainingDiverged, match=rf"steps 2-{MAX_SKIPPED + 1}: non-finite loss or gradients"):
        tr.run()
    hook.remove()
    assert (tmp_path / "o" / "last.pt").read_bytes() == saved
    with torch.no_grad():
        next(tr.model.parameters()).view(-1)[0] = float("inf")
    with pytest.raises(TrainingDiverged, match=r"weight '\S+' is not finite; stopped without saving"):
        tr.run()
    assert (tmp_path / "o" / "last.pt").read_bytes() == saved


def test_stale_temporaries_are_cleaned(tmp_path_factory, tmp_path):
    data = tiny_dataset(tmp_path_factory)
    out = tmp_path / "o"
    out.mkdir()
    dead = subprocess.run(
        [sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True
    ).stdout.strip()
    stale = [out / f".last.pt.{dead}.0123abcd.tmp.pt", out / "best.pt.tmp"]
    live = out / f".last.pt.{os.getppid()}.0123abcd.tmp.pt"  # a process that still runs: left alone
    for p in [*stale, live]:
        p.write_bytes(b"x")
    tr = Trainer(
        ModelConfig(**TINY_MODEL),
        TrainConfig(batch_size=1, target_views=1, steps=1, val_every=5),
        Path(data),
        out,
        "cpu",
        False,
        overwrite=True,
    )
    tr.run()
    assert not any(p.exists() for p in stale) and live.exists()


def test_corrupt_validation_scene_is_found_at_the_start(tmp_path_factory, tmp_path):
    data = tmp_path / "data"
    shutil.copytree(tiny_dataset(tmp_path_factory), data)
    val = next((data / "val").iterdir())
    (val / "transforms.json").write_text('{"frames": [')
    with pytest.raises(ValueError, match=rf"{val}/transforms.json: not valid JSON"):
        _trainer(data, tmp_path / "o")
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_signal_saves_a_checkpoint_and_exits_in_one_line(tmp_path_factory, tmp_path, sig):
    data = tiny_dataset(tmp_path_factory)
    cfg = tiny_config(tmp_path / "tiny.yaml", steps=100000, val_every=100000, ckpt_every=100000)
    out = tmp_path / "r"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "particlesplat.cli",
            "train",
            "--config",
            str(cfg),
            "--data",
            str(data),
            "--out",
            str(out),
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    deadline = time.time() + 240
    while not (out / "metrics.jsonl").is_file() and time.time() < deadline and proc.poll() is None:
        time.sleep(0.2)  # log_every 1: the first step is done
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=240)
    assert proc.returncode == 128 + sig
    lines = [x for x in err.splitlines() if x.strip() and not x.startswith("train")]  # (tqdm's bar)
    assert lines[-1].startswith(f"particlesplat train: interrupted (saved {out / 'last.pt'} at step ")
    assert "Traceback" not in err
    step = read_checkpoint(out / "last.pt")["step"]
    assert step >= 1 and lines[-1].endswith(f"at step {step}; continue with --resume)")
