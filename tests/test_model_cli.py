"""``particlesplat model``: a checkpoint's facts, and copies with inference keys changed that run exactly as the
original would with those keys, record the change, and never touch the original."""

from __future__ import annotations

import hashlib

import pytest
import torch
from test_model import scene_inputs, tiny_model

from particlesplat.cli.main import main
from particlesplat.core.outputs import OutputError
from particlesplat.model import ConfigError, read_checkpoint, save_checkpoint
from particlesplat.model.derive import DeriveError, derive_checkpoint
from particlesplat.model.io import load_model, model_from_checkpoint


@pytest.fixture
def trained(tmp_path):
    """A tiny model with a refiner (its last layer made non-zero, so refinement changes the particles), saved
    with run state beside it, as a run's last.pt is."""
    m = tiny_model(7, refine_steps=1, refine_hidden=16)
    with torch.no_grad():
        m.refiner.out.weight.normal_(0.0, 0.05)
    path = tmp_path / "last.pt"
    save_checkpoint(path, m, 40, {"optimizer": {"state": {}}, "rng": [1], "provenance": {"data": "d"}})
    return path, m


def digest(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_set_refine_scale_runs_as_the_model_with_that_key_and_keeps_the_original(trained, tmp_path, capsys):
    path, m = trained
    before = digest(path)
    out = tmp_path / "half.pt"
    assert (
        main(["model", "set", str(path), "refine.scale=0.5", "refine_keep=3", "--out", str(out), "--note", "why"]) == 0
    )  # a key by its nested path or by its flat name
    assert digest(path) == before
    ckpt = read_checkpoint(out)
    assert "optimizer" not in ckpt and "rng" not in ckpt  # a model, not a run to resume
    assert (
        ckpt["provenance"]["derived"]
        == f"derived from {path} step 40: refine.scale 1.0 -> 0.5, refine.keep 0 -> 3 (why)"
    )
    # truth: the original weights in a model built with those keys
    want = tiny_model(0, refine_steps=1, refine_hidden=16, refine_scale=0.5, refine_keep=3)
    want.load_state_dict(m.state_dict())
    got = load_model(out)
    rgb, depth, cs = scene_inputs(2)
    a, b = want.encode(rgb, depth, cs), got.encode(rgb, depth, cs)
    torch.testing.assert_close(a.z_p, b.z_p, rtol=0, atol=0)
    assert not torch.equal(b.z_p, m.encode(rgb, depth, cs).z_p)  # the key changed what the refinement saw
    assert main(["model", "info", str(out)]) == 0
    text = capsys.readouterr().out
    assert (
        "step 40" in text
        and "refine.scale 0.5" in text
        and "refine.keep 3" in text
        and "refine.scale 1.0 -> 0.5" in text
    )


def test_info_describes_the_model_its_run_data_and_scores_from_the_checkpoint(tmp_path, capsys):
    """What ``model info`` prints is what the checkpoint holds: the values written into it come back, and a
    checkpoint without a run's records says so rather than guessing."""
    m = tiny_model(3)
    path = tmp_path / "step_000040.pt"
    train = {"steps": 100, "batch_size": 3, "context_views": [1, 2], "target_views": 2, "val_scenes": 5}
    prov = {
        "data": "/data/mine",
        "train_scenes": 1234,
        "scene_list_sha256": "abcdef0123456789",
        "init": None,
        "wall_hours": 1.234,
        "cpu_hours": 2.5,
        "torch": "9.9",
        "git_commit": "c0ffee",
        "device": "cuda",
    }
    val = {"psnr": 21.256, "ssim": 0.8, "fg_ari": 0.5, "miou": float("nan"), "objects": 3.25}
    save_checkpoint(path, m, 40, {"train": train, "val": val, "provenance": prov})
    assert main(["model", "info", str(path)]) == 0
    text = capsys.readouterr().out
    cfg = m.config
    family = "tabletop" if cfg.bg_static_grid > 0 else "robot workspace"
    assert text.startswith(f"{path}: a ParticleSplat model of the {family} family, {cfg.resolution}x{cfg.resolution}")
    assert "training: step 40 of a 100-step run (batch 3, 1/2 context + 2 target views a scene)" in text
    assert "from: random initialisation" in text
    assert "cost: 1.23 h wall, 2.50 CPU h on cuda; torch 9.9, code c0ffee" in text
    assert "data: /data/mine, 1,234 training scenes (scene list sha256 abcdef012345)" in text
    # the NaN mIoU is left out, the rest in the checkpoint's own values
    assert "on 5 validation scenes: PSNR 21.26 dB, SSIM 0.800, FG-ARI 0.500, object groups 3.2\n" in text
    assert f"{sum(v.numel() for v in m.state_dict().values()):,} learned values" in text

    bare = tmp_path / "bare.pt"
    save_checkpoint(bare, m, 7)
    assert main(["model", "info", str(bare)]) == 0
    text = capsys.readouterr().out
    assert "training: step 7 (the run's length and batch not recorded)" in text
    assert "provenance: none recorded" in text and "validation scores: none recorded in this checkpoint" in text


@pytest.mark.parametrize(
    ("model", "says"),
    [
        ("model.pt", ["tabletop family, 64x64 RGB-D, step 3,000", "a 72x72 floor grid", "support.cut 0.01"]),
        (
            "robot/model.pt",
            [
                "robot workspace family, 128x128 RGB-D, step 25,000",
                "step 25,000 of a 25,000-step run",
                "static layer: none",
                "247 training scenes",
                "on 12 validation scenes: PSNR 21.01 dB",
                "background.colour_from_views False -> True, background.hidden_from_views False -> True, "
                "background.support_map False -> True",
                "keypoints.min_separation 0.25 -> 0.2",
            ],
        ),
    ],
)
def test_info_on_each_shipped_model(model, says, capsys):
    from particlesplat.core.bundled import bundled_assets

    assert main(["model", "info", str(bundled_assets() / model)]) == 0
    text = capsys.readouterr().out
    assert text.startswith(f"assets/{model}: ")
    for phrase in says:
        assert phrase in text, phrase


def test_dropping_the_refiner_is_the_model_with_refinement_off(trained, tmp_path):
    path, m = trained
    out = tmp_path / "plain.pt"
    assert main(["model", "set", str(path), "refine_steps=0", "--out", str(out)]) == 0
    ckpt = read_checkpoint(out)
    assert not any(k.startswith("refiner.") for k in ckpt["state_dict"])
    rgb, depth, cs = scene_inputs(2)
    m.refine_enabled = False
    torch.testing.assert_close(load_model(out).encode(rgb, depth, cs).z_f, m.encode(rgb, depth, cs).z_f, rtol=0, atol=0)
    # a second change appends to the first in the provenance
    again = derive_checkpoint(ckpt, {"support_cut": 0.01}, "plain.pt")
    assert again["provenance"]["derived"].startswith(ckpt["provenance"]["derived"] + "; derived from plain.pt step 40")
    with pytest.raises(DeriveError, match=r"refine\.steps: plain\.pt has no refiner weights"):
        derive_checkpoint(ckpt, {"refine_steps": 1}, "plain.pt")


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ("resolution=64", r"resolution: not a key a trained model can change"),
        ("refine_scale=2", r"model\.refine\.scale: must be in \(0, 1\]"),
        ("refine.scale=2", r"model\.refine\.scale: must be in \(0, 1\]"),
        ("refine_keep=-1", r"refine\.keep"),
        ("refine_static=ahead", r"refine\.static: must be render or behind"),
        ("refine.static=1", r"refine\.static: expected str"),
        ("patch.base=2", r"patch\.base: not a key a trained model can change"),
        ("refine_scale=[1", r"model set: refine_scale: not valid YAML"),
        ("refine_scale", r"expected KEY=VALUE"),
        ("refine_scale=1.0", r"nothing to change"),
    ],
)
def test_bad_changes_are_refused_and_write_nothing(trained, tmp_path, change, message):
    path, _ = trained
    out = tmp_path / "out.pt"
    with pytest.raises((DeriveError, ConfigError, ValueError), match=message):
        main(["model", "set", str(path), change, "--out", str(out)])
    assert not out.exists()


def test_set_refuses_a_key_given_by_both_its_names(trained, tmp_path):
    path, _ = trained
    out = tmp_path / "out.pt"
    with pytest.raises(ConfigError, match=r"^model set: refine_scale and refine\.scale are the same key"):
        main(["model", "set", str(path), "refine_scale=0.5", "refine.scale=0.25", "--out", str(out)])
    assert not out.exists()


def test_set_never_writes_over_its_input(trained):
    path, _ = trained
    before = digest(path)
    with pytest.raises(OutputError, match="is CHECKPOINT .*, which this command reads"):
        main(["model", "set", str(path), "refine_scale=0.5", "--out", str(path)])
    assert digest(path) == before


def test_set_reads_a_config_with_keys_of_removed_branches_as_loading_does(trained):
    """A checkpoint written before a branch was removed stores its key at the "off" value (the shipped tabletop
    model holds five): ``model set`` drops them as loading does, and refuses one that switched the branch on."""
    path, m = trained
    old = read_checkpoint(path)
    for off in ({"bg_copy_input": False, "kp_selection": "residual"}, {"bg_copy_input": True}):
        ckpt = {**old, "config": {**old["config"], **off}}
        ckpt.pop("config_sha256")
        if off.get("bg_copy_input"):
            with pytest.raises(ConfigError, match="bg_copy_input: True switches on a branch"):
                derive_checkpoint(ckpt, {"refine_scale": 0.5}, "old.pt")
            continue
        derived = derive_checkpoint(ckpt, {"refine_scale": 0.5}, "old.pt")
        assert "bg_copy_input" not in derived["config"] and "kp_selection" not in derived["config"]
        copy = model_from_checkpoint(derived, "copy.pt")
        assert copy.config.refine_scale == 0.5
        for k, v in m.state_dict().items():
            torch.testing.assert_close(copy.state_dict()[k], v, rtol=0, atol=0)
