"""The recipe (assets/recipe.yaml): the config defaults are its values, a tiny run of it end to end, its
schedules (refinement start, particles per view while training), provenance in every checkpoint, and
checkpoints that name keys of removed branches."""

from __future__ import annotations

import hashlib
import os
from dataclasses import asdict, fields
from pathlib import Path

import pytest
import torch
import yaml
from model_data import TINY_MODEL, tiny_config, tiny_dataset

from particlesplat.cli.main import main
from particlesplat.core.bundled import bundled_assets
from particlesplat.core.camera import Camera
from particlesplat.model import ConfigError, ModelConfig, ParticleSplat, TrainConfig, load_model, read_checkpoint
from particlesplat.model.config import REMOVED_KEYS, config_to_dict, without_removed_keys
from particlesplat.model.io import model_from_checkpoint


def _recipe() -> dict:
    return yaml.safe_load((bundled_assets() / "recipe.yaml").read_text())


def _leaves(d: dict, prefix: str = "") -> dict:
    """{"background.block": 2, ...} of a nested mapping."""
    out = {}
    for k, v in d.items():
        out.update(_leaves(v, f"{prefix}{k}.") if isinstance(v, dict) else {f"{prefix}{k}": v})
    return out


def test_config_defaults_are_the_recipe_and_the_recipe_lists_every_key():
    """ModelConfig() and TrainConfig() equal assets/recipe.yaml exactly: the same keys (the model's nested, as a
    run's config.yaml writes them, in the same order), the same values and types."""
    recipe = _recipe()
    assert set(recipe) == {"model", "train"}
    for cls, section in ((ModelConfig, "model"), (TrainConfig, "train")):
        written = config_to_dict(cls())
        assert list(_leaves(recipe[section])) == list(_leaves(written)), section  # every key, no other
        for key, value in _leaves(recipe[section]).items():
            want = _leaves(written)[key]
            assert want == value and type(want) is type(value), f"{section}.{key}"
    assert len(_leaves(recipe["model"])) == len(fields(ModelConfig))
    # the bundled recipe is what `particlesplat train` uses without --config
    from particlesplat.core.bundled import recipe_path
    from particlesplat.model import load_config

    cfg, tc = load_config(recipe_path())
    assert cfg == ModelConfig() and tc == TrainConfig()


def test_tiny_recipe_run_end_to_end(tmp_path_factory, tmp_path, capsys):
    """`particlesplat train` with the recipe's training keys (a tiny model, 4 steps): it logs, validates, saves
    last/best/step checkpoints holding the model config (the inference particle count, not the training one)
    and provenance; the result loads and draws a scene; `particlesplat eval` prints the provenance."""
    data = tiny_dataset(tmp_path_factory)
    cfg = tiny_config(tmp_path / "tiny.yaml")  # only sizes and intervals differ from the recipe
    assert main(["train", "--config", str(cfg), "--data", str(data), "--out", str(tmp_path / "r")]) == 0
    last = read_checkpoint(tmp_path / "r" / "last.pt")
    assert last["step"] == 4
    assert (tmp_path / "r" / "best.pt").is_file() and (tmp_path / "r" / "step_000004.pt").is_file()
    assert last["config"]["particles_per_view"] == TINY_MODEL["particles_per_view"]
    assert last["train"]["particles_per_view"] == TrainConfig().particles_per_view
    model = load_model(tmp_path / "r" / "best.pt")
    cams = [Camera.orbit((0, 0, 0.15), az, 30, 3.3, width=32, height=32) for az in (-20, 20)]
    p = model.encode(torch.rand(2, 3, 32, 32), torch.rand(2, 1, 32, 32) + 3.0, cams)
    assert p.num == 2 * TINY_MODEL["particles_per_view"]
    assert torch.isfinite(model.decode(p).means).all()
    capsys.readouterr()
    assert main(["eval", "--checkpoint", str(tmp_path / "r" / "last.pt"), "--data", str(data / "val")]) == 0
    out = capsys.readouterr().out
    assert "step 4; provenance: from random initialisation; data " + str(data.resolve()) in out


def test_refiner_gets_no_gradient_before_refine_start_and_does_after(tmp_path_factory, tmp_path):
    """refine_start 0.5 of 4 steps: steps 0 and 1 leave every refiner weight without a gradient (and unchanged),
    steps 2 and 3 train it; during a step the model keeps train.particles_per_view, after it the model config
    is the inference one again."""
    from particlesplat.training.trainer import Trainer

    data = tiny_dataset(tmp_path_factory)
    tc = TrainConfig(batch_size=1, target_views=1, steps=4, refine_start=0.5, num_threads=1, val_every=100)
    tr = Trainer(ModelConfig(**TINY_MODEL), tc, Path(data), tmp_path / "o", "cpu", False)
    seen = []
    posterior = tr.model.posterior

    def spy(*args, **kw):
        post = posterior(*args, **kw)
        seen.append(post.kp.shape[1])
        return post

    tr.model.posterior = spy
    for step in range(4):
        before = {k: v.clone() for k, v in tr.model.refiner.state_dict().items()}
        tr.train_step()
        grads = [p.grad for p in tr.model.refiner.parameters()]
        if step < 2:
            assert all(g is None for g in grads), step
            assert all(torch.equal(v, before[k]) for k, v in tr.model.refiner.state_dict().items())
        else:
            assert all(g is not None for g in grads) and float(tr.model.refiner.out.weight.grad.abs().max()) > 0
        assert tr.model.config.particles_per_view == TINY_MODEL["particles_per_view"]
        assert tr.model.config.kp_min_separation == ModelConfig().kp_min_separation
    assert seen == [2 * tc.particles_per_view] * 4  # two context views, 4 particles each while training


def test_training_selection_restores_the_model_config_even_on_error():
    from particlesplat.training.schedules import training_selection

    cfg = ModelConfig(**TINY_MODEL)
    tc = TrainConfig(particles_per_view=5, kp_min_separation=0.4)
    with pytest.raises(RuntimeError, match="inside"):
        with training_selection(cfg, tc):
            assert (cfg.particles_per_view, cfg.kp_min_separation) == (5, 0.4)
            raise RuntimeError("inside")
    assert (cfg.particles_per_view, cfg.kp_min_separation) == (3, ModelConfig().kp_min_separation)
    with training_selection(cfg, TrainConfig(particles_per_view=0, kp_min_separation=0.0)):  # 0: the model's
        assert (cfg.particles_per_view, cfg.kp_min_separation) == (3, ModelConfig().kp_min_separation)


def test_checkpoints_hold_provenance_and_resume_adds_hours(tmp_path_factory, tmp_path):
    """A tiny run's checkpoints hold: init None, the data folder, the SHA-256 of its sorted training scene names
    (computed here from the folder), hours > 0, the torch version (a plain str); a resumed run keeps them
    and adds its own hours."""
    data = tiny_dataset(tmp_path_factory)
    cfg = tiny_config(tmp_path / "tiny.yaml")
    argv = ["train", "--config", str(cfg), "--data", str(data), "--out", str(tmp_path / "r")]
    assert main([*argv, "--stop-after", "2"]) == 0
    first = read_checkpoint(tmp_path / "r" / "last.pt")["provenance"]
    names = sorted(n for n in os.listdir(data / "train") if (data / "train" / n).is_dir())
    assert first["init"] is None
    assert first["data"] == str(data.resolve()) and first["train_scenes"] == len(names) == 2
    assert first["scene_list_sha256"] == hashlib.sha256("".join(f"{n}\n" for n in names).encode()).hexdigest()
    assert first["wall_hours"] > 0 and first["cpu_hours"] > 0
    assert type(first["torch"]) is str and first["torch"] == str(torch.__version__)
    assert (
        read_checkpoint(tmp_path / "r" / "step_000002.pt")["provenance"]["scene_list_sha256"]
        == first["scene_list_sha256"]
    )
    assert main([*argv, "--resume"]) == 0
    second = read_checkpoint(tmp_path / "r" / "last.pt")
    assert second["step"] == 4
    prov = second["provenance"]
    assert prov["wall_hours"] > first["wall_hours"] and prov["cpu_hours"] >= first["cpu_hours"]
    assert {k: prov[k] for k in ("init", "data", "scene_list_sha256", "torch")} == {
        k: first[k] for k in ("init", "data", "scene_list_sha256", "torch")
    }


# ------------------------------------------------------------------ checkpoints of removed branches
LEGACY_OFF = {
    "kp_selection": "residual",
    "kp_cross_view": False,
    "bg_detail": 0,
    "bg_detail_threshold": 0.05,
    "bg_copy_input": False,
    "patch_refine": 0,
    "patch_cell_mlp": 0,
    "patch_copy_input": False,
    "patch_copy_threshold": 0.3,
    "particle_depth_scale": "cell",
    "refine_glimpse": 0,
    "learned_background": True,
    "patch_back": True,
}
LEGACY_TRAIN_OFF = {"beta_coarse": 2.5, "fg_band": 0, "depth_dropout": 0.0, "bg_off_steps": 0, "freeze": []}


def _old_checkpoint(path: Path, **config) -> Path:
    """A checkpoint in the format written before the branches were removed (no config digest)."""
    torch.manual_seed(0)
    model = ParticleSplat(ModelConfig(**TINY_MODEL))
    torch.save({"config": {**asdict(model.config), **config}, "state_dict": model.state_dict(), "step": 3}, path)
    return path


def test_removed_keys_at_their_off_value_are_dropped(tmp_path):
    assert set(LEGACY_OFF) == set(REMOVED_KEYS["model"])
    path = _old_checkpoint(tmp_path / "old.pt", **LEGACY_OFF)
    model = load_model(path)
    assert model.config == ModelConfig(**TINY_MODEL)
    fresh = ParticleSplat(ModelConfig(**TINY_MODEL))
    fresh.load_state_dict(torch.load(path, weights_only=True)["state_dict"])
    cams = [Camera.orbit((0, 0, 0.15), az, 30, 3.3, width=32, height=32) for az in (-20, 20)]
    rgb, depth = torch.rand(2, 3, 32, 32), torch.rand(2, 1, 32, 32) + 3.0
    torch.testing.assert_close(
        model.decode(model.encode(rgb, depth, cams)).means,
        fresh.eval().decode(fresh.encode(rgb, depth, cams)).means,
        rtol=0,
        atol=0,
    )
    assert set(LEGACY_TRAIN_OFF) == set(REMOVED_KEYS["train"])
    train = without_removed_keys({**asdict(TrainConfig()), **LEGACY_TRAIN_OFF}, "train", "old.pt: train")
    assert train == asdict(TrainConfig())


@pytest.mark.parametrize(
    "key,value",
    [
        ("bg_detail", 2),
        ("bg_copy_input", True),
        ("kp_cross_view", True),
        ("patch_refine", 1),
        ("patch_cell_mlp", 64),
        ("patch_copy_input", True),
        ("kp_selection", "presence"),
        ("bg_detail", False),
        ("particle_depth_scale", "pixel"),
        ("refine_glimpse", 24),
        ("learned_background", False),
        ("patch_back", False),
    ],
)
def test_removed_keys_that_switch_a_branch_on_are_refused_by_name(tmp_path, key, value):
    path = _old_checkpoint(tmp_path / "on.pt", **{**LEGACY_OFF, key: value})
    with pytest.raises(ConfigError, match=rf"on\.pt: config\.{key}: {value!r} switches on a branch"):
        load_model(path)
    with pytest.raises(ConfigError, match=rf"on\.pt: config\.{key}"):
        model_from_checkpoint(read_checkpoint(path), str(path))


@pytest.mark.parametrize(
    "key,value", [("fg_band", 1), ("depth_dropout", 0.5), ("bg_off_steps", 100), ("freeze", ["encoder"])]
)
def test_removed_training_keys_that_switch_a_branch_on_are_refused_by_name(key, value):
    with pytest.raises(ConfigError, match=rf"old\.pt: train\.{key}: .* switches on a branch"):
        without_removed_keys({**asdict(TrainConfig()), key: value}, "train", "old.pt: train")


def test_a_key_no_version_had_is_still_refused(tmp_path):
    path = _old_checkpoint(tmp_path / "typo.pt", patch_refin=0)
    with pytest.raises(ConfigError, match=r"typo\.pt: config: unknown key\(s\) patch_refin"):
        load_model(path)
