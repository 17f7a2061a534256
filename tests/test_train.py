"""Training CLI tests on a tiny config: progress, checkpoints, exact resume, and a two-process DDP run."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys

import pytest
import torch
import yaml
from model_data import tiny_config, tiny_dataset

from particlesplat.cli.main import main
from particlesplat.model import load_model, read_checkpoint


def _train(cfg, data, out, *extra) -> int:
    return main(["train", "--config", str(cfg), "--data", str(data), "--out", str(out), *extra])


def test_interrupted_and_resumed_equals_uninterrupted(tmp_path_factory, tmp_path, capsys):
    data = tiny_dataset(tmp_path_factory)
    cfg = tiny_config(tmp_path / "tiny.yaml", lr_final=0.1)  # the lr decays: resuming must pick up the schedule
    assert _train(cfg, data, tmp_path / "a") == 0
    assert (
        capsys.readouterr()
        .out.strip()
        .endswith(
            f"particlesplat train: done, step 4 of 4: {tmp_path / 'a' / 'last.pt'}, "
            f"the best validation score's weights in {tmp_path / 'a' / 'best.pt'}"
        )
    )
    assert _train(cfg, data, tmp_path / "b", "--stop-after", "2") == 0
    assert "particlesplat train: stopped at step 2 of 4" in capsys.readouterr().out
    assert read_checkpoint(tmp_path / "b" / "last.pt")["step"] == 2
    with open(tmp_path / "b" / "metrics.jsonl", "a") as f:  # logged after the checkpoint, then interrupted
        f.write(json.dumps({"step": 3, "loss": 1.0}) + "\n")
    assert _train(cfg, data, tmp_path / "b", "--resume") == 0
    a, b = read_checkpoint(tmp_path / "a" / "last.pt"), read_checkpoint(tmp_path / "b" / "last.pt")
    assert a["step"] == b["step"] == 4
    for k, v in a["state_dict"].items():
        assert torch.equal(v, b["state_dict"][k]), k
    for sa, sb in zip(a["optimizer"]["state"].values(), b["optimizer"]["state"].values(), strict=False):
        assert torch.equal(sa["exp_avg_sq"], sb["exp_avg_sq"])
    assert torch.equal(a["rng"][0]["torch"], b["rng"][0]["torch"])
    # the last step (index 3 of 4) ran at the end of the cosine: lr x lr_final
    from particlesplat.model import load_config

    assert a["optimizer"]["param_groups"][0]["lr"] == pytest.approx(load_config(cfg)[1].lr * 0.1)
    # logs and validation checkpoints
    lines = [json.loads(x) for x in (tmp_path / "a" / "metrics.jsonl").read_text().splitlines()]
    assert [r["step"] for r in lines if "loss" in r] == [1, 2, 3, 4]
    vals = [r for r in lines if "val" in r]
    assert [r["step"] for r in vals] == [2, 4]
    lines_b = [json.loads(x) for x in (tmp_path / "b" / "metrics.jsonl").read_text().splitlines()]
    assert [r["step"] for r in lines_b] == [r["step"] for r in lines]  # nothing logged twice
    # the logged running means go on as if the run had not stopped
    assert [r for r in lines_b if "loss" in r and r["step"] > 2] == [r for r in lines if "loss" in r and r["step"] > 2]
    assert read_checkpoint(tmp_path / "b" / "last.pt")["best"] == read_checkpoint(tmp_path / "a" / "last.pt")["best"]
    scores = [
        r["val"]["psnr"] / 30.0 + (r["val"]["fg_ari"] if r["val"]["fg_ari"] == r["val"]["fg_ari"] else 0.0)
        for r in vals
    ]
    assert read_checkpoint(tmp_path / "a" / "last.pt")["best"] == pytest.approx(max(scores))  # last val included
    assert set(vals[0]["val"]) >= {"psnr", "ssim", "depth_abs_rel", "fg_ari", "miou"}
    m = load_model(tmp_path / "a" / "best.pt")
    assert m.config.resolution == 32
    assert (tmp_path / "a" / "step_000004.pt").is_file()


def test_resume_without_config_goes_on_with_the_runs_own(tmp_path_factory, tmp_path, capsys):
    """A run started with a recipe of its own resumes without --config: OUT/config.yaml, not the bundled
    recipe (whose model differs, which resume would refuse)."""
    data = tiny_dataset(tmp_path_factory)
    cfg = tiny_config(tmp_path / "tiny.yaml", val_every=5)
    out = tmp_path / "r"
    assert _train(cfg, data, out, "--stop-after", "1") == 0
    assert main(["train", "--data", str(data), "--out", str(out), "--resume"]) == 0
    assert f"--resume without --config: the run's own {out / 'config.yaml'}" in capsys.readouterr().err
    assert read_checkpoint(out / "last.pt")["step"] == 4


def test_resume_refuses_a_different_model_config(tmp_path_factory, tmp_path):
    data = tiny_dataset(tmp_path_factory)
    cfg = tiny_config(tmp_path / "tiny.yaml", steps=1, val_every=5)
    assert _train(cfg, data, tmp_path / "r") == 0
    text = cfg.read_text().replace("d_obj: 4", "d_obj: 6")
    cfg.write_text(text)
    with pytest.raises(ValueError, match=r"model.d_obj: the run was trained with 4, --config \S+ gives 6"):
        _train(cfg, data, tmp_path / "r", "--resume")
    with pytest.raises(FileNotFoundError, match="nothing to resume"):
        _train(cfg, data, tmp_path / "empty", "--resume")


def test_training_reduces_the_loss_on_one_scene(tmp_path_factory, tmp_path):
    from pathlib import Path

    from model_data import TINY_MODEL

    from particlesplat.model import ModelConfig, TrainConfig
    from particlesplat.training.trainer import Trainer

    data = tiny_dataset(tmp_path_factory)
    tc = TrainConfig(batch_size=1, target_views=1, steps=60, lr=3e-3, seed=1, beta_fg=0.0)  # the reconstruction alone
    tr = Trainer(ModelConfig(**TINY_MODEL), tc, Path(data), tmp_path / "o", "cpu", False)
    losses = [tr.train_step()["rec"] for _ in range(60)]
    assert sum(losses[-10:]) / 10 < 0.85 * sum(losses[:10]) / 10


PER_VIEW = {"bg_per_view": True}  # the per-view background beside the static layer


@pytest.mark.slow
@pytest.mark.parametrize("model", [{}, PER_VIEW], ids=["recipe (static layer)", "with the per-view background"])
def test_two_process_ddp_run(tmp_path_factory, tmp_path, model):
    data = tiny_dataset(tmp_path_factory)
    cfg = tiny_config(tmp_path / "tiny.yaml", steps=2, val_every=2, batch_size=1)
    if model:
        text = yaml.safe_load(cfg.read_text())
        text["model"].update(model)
        cfg.write_text(yaml.safe_dump(text))
    torchrun = os.path.join(os.path.dirname(sys.executable), "torchrun")
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    proc = subprocess.run(
        [
            torchrun,
            "--nproc_per_node=2",
            "--standalone",  # a rendezvous on a free port, not a fixed one another process may hold
            "-m",
            "particlesplat.cli",
            "train",
            "--config",
            str(cfg),
            "--data",
            str(data),
            "--out",
            str(tmp_path / "ddp"),
        ],
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    ckpt = read_checkpoint(tmp_path / "ddp" / "last.pt")
    assert ckpt["step"] == 2 and len(ckpt["rng"]) == 2
    # the two ranks drew different batches and latents (different RNG streams) yet hold one model
    assert not torch.equal(ckpt["rng"][0]["torch"], ckpt["rng"][1]["torch"])
    assert all(torch.isfinite(v).all() for v in ckpt["state_dict"].values() if v.is_floating_point())


def test_lr_factor_is_a_cosine_from_one_to_lr_final():
    from particlesplat.model import TrainConfig
    from particlesplat.training.schedules import lr_factor

    tc = TrainConfig(steps=101, lr_final=0.2)
    assert lr_factor(0, tc) == pytest.approx(1.0)
    assert lr_factor(50, tc) == pytest.approx(0.6)  # half-way: the mean of 1 and 0.2
    assert lr_factor(25, tc) == pytest.approx(0.2 + 0.8 * 0.5 * (1 + 2**-0.5))
    assert lr_factor(100, tc) == pytest.approx(0.2) and lr_factor(500, tc) == pytest.approx(0.2)
    assert lr_factor(37, TrainConfig(steps=101, lr_final=1.0)) == 1.0  # lr_final 1: constant
    with pytest.raises(ValueError, match="lr_final"):
        TrainConfig(lr_final=1.5).validate()


def test_view_gaps_reach_their_full_range_after_gap_warmup():
    from particlesplat.data.views import gap_range
    from particlesplat.model import TrainConfig
    from particlesplat.training.schedules import gap_progress

    tc = TrainConfig(steps=1000, gap_warmup=0.2)
    assert gap_range(gap_progress(0, tc), "multi") == (1, 4)
    assert gap_range(gap_progress(100, tc), "multi") == (3, 12)  # half of the warm-up: half of the growth
    assert gap_range(gap_progress(200, tc), "multi") == (5, 20)
    assert gap_range(gap_progress(999, tc), "multi") == (5, 20)
    assert gap_range(gap_progress(0, TrainConfig(gap_warmup=0.0)), "multi") == (5, 20)


def test_learned_background_is_rendered_behind_the_gaussians_and_trained():
    """Gaussians that cover nothing leave every pixel at the model's background colour, and the
    gradient of the summed image w.r.t. that colour is the pixel count (analytic)."""
    from model_data import TINY_MODEL

    from particlesplat.core.gaussians import Gaussians
    from particlesplat.model import ModelConfig, ParticleSplat
    from particlesplat.training.loss import render_views

    m = ParticleSplat(ModelConfig(**TINY_MODEL))
    with torch.no_grad():
        m.background_logit.copy_(torch.logit(torch.tensor([0.2, 0.5, 0.7])))
    g = Gaussians.empty(0)
    K = torch.tensor([[[[40.0, 0, 16], [0, 40.0, 16], [0, 0, 1]]]])
    c2w = torch.eye(4)[None, None]
    bg = m.background_color()
    rgb, _, fg = render_views([g], K, c2w, 32, bg)
    assert fg is None
    torch.testing.assert_close(rgb[0, 0], torch.tensor([0.2, 0.5, 0.7])[:, None, None].expand(3, 32, 32))
    (grad,) = torch.autograd.grad(rgb.sum(), bg)
    torch.testing.assert_close(grad, torch.full((3,), 32.0 * 32.0))


def test_static_layer_trains_at_the_background_learning_rate(tmp_path_factory, tmp_path):
    """With lr ~ 0 and lr_background > 0, two steps move the static layer (and the background colour) and
    leave every network weight where it was: the layer is in the lr_background group."""
    data = tiny_dataset(tmp_path_factory)
    cfg = tiny_config(tmp_path / "tiny.yaml", steps=2, val_every=5, lr=1e-12, lr_background=0.05)
    assert _train(cfg, data, tmp_path / "s", "--stop-after", "1") == 0
    before = read_checkpoint(tmp_path / "s" / "last.pt")["state_dict"]
    assert _train(cfg, data, tmp_path / "s", "--resume") == 0
    after = read_checkpoint(tmp_path / "s" / "last.pt")["state_dict"]
    moved = {k for k in after if not torch.allclose(after[k].float(), before[k].float(), rtol=0, atol=1e-7)}
    assert {"static_bg.sh_dc", "static_bg.opacity_logit"} <= moved
    assert moved <= {"static_bg.sh_dc", "static_bg.opacity_logit", "background_logit"}


def test_foreground_error_targets_what_the_static_layer_cannot_explain():
    """On the layer's own render the target is empty, so the error is Σ fg²; a 4x4 'object' (nearer, red)
    makes those 16 pixels the target: with fg = 1 exactly there the error is 0, with fg = 0 it is 16."""
    from model_data import TINY_MODEL

    from particlesplat.core.camera import Camera
    from particlesplat.model import ModelConfig, ParticleSplat
    from particlesplat.model.geometry import stack_cameras
    from particlesplat.rendering.api import render
    from particlesplat.training.loss import foreground_error

    m = ParticleSplat(ModelConfig(**TINY_MODEL)).eval()
    cam = Camera.orbit((0.0, 0.0, 0.15), 20.0, 30.0, 3.3, width=32, height=32)
    K, c2w = stack_cameras([cam])
    with torch.no_grad():
        floor = m.decode(
            m.encode(torch.rand(1, 3, 32, 32), 3.0 + torch.rand(1, 1, 32, 32), [cam]),
            torch.tensor([], dtype=torch.long),
        )
        r = render(floor, cam, background=m.background_color())
    rgb, depth = r.rgb.permute(2, 0, 1)[None], r.depth[None, None]
    fg = torch.rand(1, 1, 32, 32)

    def error(fg, rgb, depth):
        return foreground_error(fg, m.static_background_error(rgb, depth, K, c2w, block=1), 0.02)

    torch.testing.assert_close(error(fg, rgb, depth), (fg**2).flatten(1).sum(1))
    rgb[..., 10:14, 5:9] = torch.tensor([0.9, 0.1, 0.1])[:, None, None]
    depth[..., 10:14, 5:9] -= 0.4
    exact = torch.zeros(1, 1, 32, 32)
    exact[..., 10:14, 5:9] = 1.0
    assert float(error(exact, rgb, depth)) == 0.0
    assert float(error(torch.zeros_like(exact), rgb, depth)) == 16.0


def test_foreground_term_needs_the_static_layer(tmp_path_factory, tmp_path):
    from pathlib import Path

    from model_data import TINY_MODEL

    from particlesplat.model import ConfigError, ModelConfig, TrainConfig
    from particlesplat.training.trainer import Trainer

    with pytest.raises(ConfigError, match="beta_fg"):
        Trainer(
            ModelConfig(**{**TINY_MODEL, "bg_static_grid": 0, "bg_per_view": True}),
            TrainConfig(beta_fg=0.5),
            Path(tiny_dataset(tmp_path_factory)),
            tmp_path / "o",
            "cpu",
            False,
        )


def test_training_with_the_foreground_term_logs_it(tmp_path_factory, tmp_path):
    """Two steps with beta_fg: the term is logged, finite and at most one per pixel of the scene's views
    (2 context + 1 target views of 32x32), and the loss stays finite."""
    data = tiny_dataset(tmp_path_factory)
    cfg = tiny_config(tmp_path / "tiny.yaml", steps=2, val_every=5, beta_fg=0.5)
    assert _train(cfg, data, tmp_path / "f") == 0
    rows = [json.loads(ln) for ln in (tmp_path / "f" / "metrics.jsonl").read_text().splitlines()]
    fg = [r["fg"] for r in rows if "fg" in r]
    assert len(fg) == 2 and all(0.0 < v <= 3 * 32 * 32 for v in fg)
    assert all(math.isfinite(r["loss"]) for r in rows if "loss" in r)


def test_the_foreground_term_stops_at_beta_fg_until(tmp_path_factory, tmp_path):
    """beta_fg_until 0.5 of 4 steps: steps 1 and 2 add the term (and log it), steps 3 and 4 neither compute
    nor log it."""
    from particlesplat.model import TrainConfig

    tc = TrainConfig(steps=4, beta_fg=0.5, beta_fg_until=0.5)
    assert [tc.fg_weight(s) for s in range(4)] == [0.5, 0.5, 0.0, 0.0]
    assert TrainConfig(steps=4, beta_fg=0.5).fg_weight(3) == 0.5  # the default: throughout
    data = tiny_dataset(tmp_path_factory)
    cfg = tiny_config(tmp_path / "tiny.yaml", steps=4, val_every=5, beta_fg=0.5, beta_fg_until=0.5)
    assert _train(cfg, data, tmp_path / "f") == 0
    rows = [json.loads(ln) for ln in (tmp_path / "f" / "metrics.jsonl").read_text().splitlines()]
    rows = {r["step"]: r for r in rows if "loss" in r}
    assert sorted(rows) == [1, 2, 3, 4]
    assert "fg" in rows[1] and "fg" in rows[2] and "fg" not in rows[3] and "fg" not in rows[4]


def test_training_batch_stacks_the_items_the_loss_reads(tmp_path_factory):
    """TrainingBatch.collate: each field is the items' tensors stacked (what torch's default collate makes of
    them), masks and indices left out; .to keeps every field."""
    from dataclasses import fields

    from torch.utils.data import default_collate

    from particlesplat.data.dataset import SceneDataset, TrainingBatch

    ds = SceneDataset(tiny_dataset(tmp_path_factory) / "train", resolution=32, deterministic=True)
    items = [ds[0], ds[1]]
    batch = TrainingBatch.collate(items)
    want = default_collate(items)
    names = [f.name for f in fields(TrainingBatch)]
    assert "context_masks" not in names and "scene_index" not in names
    assert batch.pose is None  # these scenes are read without a pose (the model follows none)
    for name in names:
        if name != "pose":
            assert torch.equal(getattr(batch, name), want[name]), name
    assert batch.context_rgb.shape[:3] == (2, ds[0]["context_rgb"].shape[0], 3)
    moved = batch.to("cpu")
    assert all(torch.equal(getattr(moved, n), getattr(batch, n)) for n in names if n != "pose")
    assert moved.pose is None


@pytest.mark.parametrize("gpu", [False, True])
def test_train_takes_the_gpu_torch_finds_unless_told_and_says_so(monkeypatch, capsys, tmp_path, gpu):
    """Without --device a run trains on cuda where torch sees a GPU (one line on stderr), else on the CPU."""
    monkeypatch.setattr(torch.cuda, "is_available", lambda: gpu)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: int(gpu))
    # an empty train/ split: the command stops right after choosing the device, before anything touches it
    (tmp_path / "none" / "train").mkdir(parents=True)
    args = ["train", "--data", str(tmp_path / "none"), "--out", str(tmp_path / "run")]
    with pytest.raises(FileNotFoundError, match="no scene folders"):
        main(args)
    assert ("train: on cuda, which torch found (--device cpu trains on the CPU)" in capsys.readouterr().err) == gpu
    with pytest.raises(FileNotFoundError, match="no scene folders"):
        main([*args, "--device", "cpu"])
    assert "train: on" not in capsys.readouterr().err


def test_a_smoke_test_from_overrides_of_the_recipe(tmp_path_factory, tmp_path, capsys):
    """``train.steps=3 train.val_every=2``: the run trains 3 steps with a validation at step 2 (and at the last),
    records the changed recipe in its config.yaml, and ``curve`` plots it."""
    from particlesplat.model.config import load_config

    data = tiny_dataset(tmp_path_factory)
    cfg = tiny_config(tmp_path / "tiny.yaml", steps=50, val_every=25)
    assert _train(cfg, data, tmp_path / "run", "train.steps=3", "train.val_every=2") == 0
    err = capsys.readouterr().err
    assert "recipe changed by train.steps=3, train.val_every=2" in err
    assert "left=" in err and "s_step=" in err  # the bar's time left from the median step
    _, tc = load_config(tmp_path / "run" / "config.yaml")
    assert (tc.steps, tc.val_every) == (3, 2)
    val_steps = [
        json.loads(line)["step"]
        for line in (tmp_path / "run" / "metrics.jsonl").read_text().splitlines()
        if "val" in json.loads(line)
    ]
    assert val_steps == [2, 3]
    assert main(["curve", str(tmp_path / "run"), "--out", str(tmp_path / "c.png")]) == 0
    assert "2 validation point(s)" in capsys.readouterr().out
