"""The model config's groups: a nested config and the flat one written before the groups load to the same
ModelConfig; a key given both ways is refused naming both; errors, overrides and ``model set`` take the nested
path; what a run writes (config.yaml, checkpoints) is nested and resumes; old flat checkpoints (the shipped
models) and old run configs still load and give the same outputs."""

from __future__ import annotations

from dataclasses import asdict, fields
from pathlib import Path

import pytest
import torch
import yaml
from model_data import TINY_MODEL, tiny_dataset

from particlesplat.cli.main import main
from particlesplat.core.bundled import bundled_assets
from particlesplat.model import ConfigError, ModelConfig, ParticleSplat, TrainConfig, load_config, read_checkpoint
from particlesplat.model.config import MODEL_GROUPS, REMOVED_KEYS, model_config_from_dict, with_overrides

ROOT = Path(__file__).resolve().parents[1]
GROUPED = {f for keys in MODEL_GROUPS.values() for f in keys.values()}  # the fields that live in a group

# A model section as configs were written before the groups (flat names), and the same model nested: written out
# by hand, key by key, so that neither side comes from the code under test.
FLAT = {
    "resolution": 32,
    "particles_per_view": 3,
    "kp_patch": 4,
    "kp_min_separation": 0.3,
    "glimpse_ratio": 0.2,
    "glimpse_size": 8,
    "channels": 8,
    "d_obj": 4,
    "d_bg": 2,
    "bg_latent_stride": 8,
    "bg_block": 4,
    "bg_per_view": True,
    "bg_static_grid": 16,
    "bg_static_extent": 2.0,
    "bg_mask_threshold": 0.3,
    "patch_gaussians": 4,
    "patch_base": 2,
    "patch_channels": 8,
    "patch_hidden": 16,
    "support_clamp": True,
    "support_cut": 0.02,
    "refine_steps": 2,
    "refine_hidden": 16,
    "refine_scale": 0.5,
    "refine_keep": 5,
    "token_dim": 16,
    "transformer_layers": 1,
    "transformer_heads": 2,
    "prior_offset_std": 0.25,
    "prior_t_b": 0.02,
}
NESTED = {
    "resolution": 32,
    "particles_per_view": 3,
    "channels": 8,
    "d_obj": 4,
    "keypoints": {"patch": 4, "min_separation": 0.3, "glimpse_ratio": 0.2, "glimpse_size": 8},
    "background": {
        "latent_channels": 2,
        "latent_stride": 8,
        "block": 4,
        "per_view": True,
        "static_grid": 16,
        "static_extent": 2.0,
        "mask_threshold": 0.3,
    },
    "patch": {"gaussians": 4, "base": 2, "channels": 8, "hidden": 16},
    "support": {"clamp": True, "cut": 0.02},
    "refine": {"steps": 2, "hidden": 16, "scale": 0.5, "keep": 5},
    "transformer": {"token_dim": 16, "layers": 1, "heads": 2},
    "prior": {"offset_std": 0.25, "t_b": 0.02},
}


def _write(path: Path, model: dict, train: dict | None = None) -> Path:
    path.write_text(yaml.safe_dump({"model": model, "train": train or {}}, sort_keys=False))
    return path


def test_a_flat_config_and_a_nested_one_load_to_the_same_model_config(tmp_path):
    flat, _ = load_config(_write(tmp_path / "flat.yaml", FLAT))
    nested, _ = load_config(_write(tmp_path / "nested.yaml", NESTED))
    assert flat == nested
    # every value the files set arrived (against the flat names, read as attributes)
    for key, value in FLAT.items():
        assert getattr(nested, key) == value, key
    assert nested != ModelConfig()


def test_every_field_has_one_nested_place_and_a_written_config_reads_back():
    grouped = [f for keys in MODEL_GROUPS.values() for f in keys.values()]
    assert len(grouped) == len(set(grouped)) and set(grouped) <= {f.name for f in fields(ModelConfig)}
    cfg = model_config_from_dict(FLAT)
    written = yaml.safe_load(yaml.safe_dump(ParticleSplat(cfg).config_dict(), sort_keys=False))
    assert written["background"]["block"] == 4 and written["refine"]["keep"] == 5
    assert not set(written) & GROUPED  # no grouped field at the top level
    assert model_config_from_dict(written) == cfg


def test_every_recipe_and_every_recorded_run_config_loads():
    """Both recipes (nested) and the configs of the finished runs in docs/runs (written flat, some with keys of
    removed branches at their off value) load; the robot recipe's values arrive, and they are its run's."""
    tabletop, tc = load_config(bundled_assets() / "recipe.yaml")
    assert tabletop == ModelConfig() and tc == TrainConfig()
    robot, robot_train = load_config(bundled_assets() / "robot" / "recipe.yaml")
    assert (robot.resolution, robot.bg_static_points, robot.bg_static_pose, robot.fg_evidence) == (
        128,
        0,
        "robot_state",
        True,
    )
    # the robot recipe is the shipped robot model's run, as its run folder records it
    assert load_config(ROOT / "docs" / "runs" / "robot-wide" / "config.yaml") == (robot, robot_train)
    runs = sorted((ROOT / "docs" / "runs").glob("*/config.yaml"))
    assert len(runs) >= 10
    for path in runs:
        raw = yaml.safe_load(path.read_text())["model"]
        grid = raw["bg_static_grid"] if "bg_static_grid" in raw else raw["background"]["static_grid"]  # flat, nested
        cfg, _ = load_config(path)
        assert cfg.resolution == raw["resolution"] and cfg.bg_static_grid == grid, path


def test_a_key_given_flat_and_nested_is_refused_naming_the_file_and_both(tmp_path):
    path = _write(tmp_path / "mixed.yaml", {"bg_block": 4, "background": {"block": 2}})
    with pytest.raises(ConfigError) as e:
        load_config(path)
    message = str(e.value)
    assert "\n" not in message
    assert message.startswith(f"{path}: model: bg_block and background.block are the same key")
    # also spelled the other way round, and in the overrides of `particlesplat train`
    with pytest.raises(ConfigError, match=r"refine\.steps and refine_steps are the same key"):
        load_config(_write(tmp_path / "m2.yaml", {"refine": {"steps": 0}, "refine_steps": 1}))
    cfg, tc = ModelConfig(), TrainConfig()
    with pytest.raises(ConfigError, match=r"^override model: bg_block and background\.block are the same key"):
        with_overrides(cfg, tc, {"model.bg_block": 4, "model.background.block": 4})


def test_errors_name_the_nested_path_whichever_name_the_file_used(tmp_path):
    for model in ({"bg_block": 3}, {"background": {"block": 3}}):
        with pytest.raises(ConfigError, match=r"c\.yaml: model\.background\.block: must divide the resolution"):
            load_config(_write(tmp_path / "c.yaml", model))
    with pytest.raises(ConfigError, match=r"c\.yaml: model\.refine\.hidden: expected int, got 'wide'"):
        load_config(_write(tmp_path / "c.yaml", {"refine": {"hidden": "wide"}}))
    with pytest.raises(ConfigError, match=r"c\.yaml: model\.background: unknown key\(s\) blok \(known: per_view,"):
        load_config(_write(tmp_path / "c.yaml", {"background": {"blok": 2}}))
    with pytest.raises(ConfigError, match=r"c\.yaml: model\.refine: expected a mapping of refine keys \(steps,"):
        load_config(_write(tmp_path / "c.yaml", {"refine": 2}))
    with pytest.raises(ConfigError, match=r"c\.yaml: model: unknown key\(s\) blok \(known: resolution, .*background"):
        load_config(_write(tmp_path / "c.yaml", {"blok": 2}))


def test_overrides_take_the_nested_path_and_the_flat_name():
    cfg, tc = ModelConfig(), TrainConfig()
    by_path, _ = with_overrides(cfg, tc, {"model.background.block": 4, "model.refine.steps": 0})
    by_name, _ = with_overrides(cfg, tc, {"model.bg_block": 4, "model.refine_steps": 0})
    assert by_path == by_name and (by_path.bg_block, by_path.refine_steps) == (4, 0)
    with pytest.raises(ConfigError, match=r"override model\.refine\.scale: must be in \(0, 1\]"):
        with_overrides(cfg, tc, {"model.refine.scale": 2.0})
    with pytest.raises(ConfigError, match=r"override model: unknown key\(s\) refine\.stepz"):
        with_overrides(cfg, tc, {"model.refine.stepz": 1})


@pytest.mark.parametrize("model", ["model.pt"])
def test_a_shipped_flat_checkpoint_loads_and_its_nested_copy_gives_identical_outputs(model, tmp_path):
    """The shipped tabletop checkpoint stores a flat config with keys of removed branches: it loads, equals the
    model built from its flat dict by hand (the removed keys dropped), and a copy saved now stores the nested
    config and encodes and decodes a demo scene bit for bit as the original does. (The robot model was saved
    nested.)"""
    from particlesplat.editing.open_scene import encode_scene
    from particlesplat.model import load_model, save_checkpoint

    torch.set_num_threads(1)
    path = bundled_assets() / model
    ckpt = torch.load(path, map_location="cpu", weights_only=True)
    assert not set(ckpt["config"]) & set(MODEL_GROUPS)  # written flat
    loaded = load_model(path)
    by_hand = {k: v for k, v in ckpt["config"].items() if k not in REMOVED_KEYS["model"]}
    assert loaded.config == ModelConfig(**by_hand)

    copy = tmp_path / "copy.pt"
    save_checkpoint(copy, loaded, int(ckpt["step"]))
    stored = read_checkpoint(copy)["config"]
    assert set(MODEL_GROUPS) <= set(stored) and "bg_block" not in stored and stored["background"]["block"] == 2
    again = load_model(copy)
    again.refine_enabled = loaded.refine_enabled
    assert again.config == loaded.config
    scene = (bundled_assets() / ("robot/scenes" if "robot" in model else "scenes")) / "scene_00000"
    a, b = encode_scene(loaded, scene, None), encode_scene(again, scene, None)
    for name in ("z_p", "z_s", "z_d", "z_e", "z_t", "z_f"):
        assert torch.equal(getattr(a.particles, name), getattr(b.particles, name)), name
    ga, gb = loaded.decode(a.particles), again.decode(b.particles)
    assert len(ga) > 0 and torch.equal(ga.means, gb.means) and torch.equal(ga.opacities, gb.opacities)


def test_a_runs_config_yaml_and_checkpoints_are_nested_and_the_run_resumes(tmp_path_factory, tmp_path):
    """A run started from a nested config writes config.yaml and last.pt nested; --resume without --config reads
    that config.yaml and continues; a run folder whose config.yaml an older version wrote flat resumes too."""
    data = tiny_dataset(tmp_path_factory)
    nested = {  # tests/model_data.py's TINY_MODEL, nested by hand
        "resolution": 32,
        "particles_per_view": 3,
        "channels": 8,
        "d_obj": 4,
        "keypoints": {"patch": 4, "glimpse_size": 8},
        "background": {"latent_channels": 2, "latent_stride": 8, "block": 4, "static_grid": 16},
        "patch": {"gaussians": 4, "base": 2, "channels": 8, "hidden": 16},
        "refine": {"hidden": 16},
        "transformer": {"token_dim": 16, "layers": 1, "heads": 2},
    }
    train = {"batch_size": 1, "target_views": 1, "steps": 4, "val_every": 2, "val_scenes": 1, "num_threads": 1}
    cfg = _write(tmp_path / "nested.yaml", nested, train)
    assert load_config(cfg)[0] == ModelConfig(**TINY_MODEL)
    run = tmp_path / "r"
    argv = ["train", "--data", str(data), "--out", str(run)]
    assert main([*argv, "--config", str(cfg), "--stop-after", "2"]) == 0
    written = yaml.safe_load((run / "config.yaml").read_text())
    assert set(MODEL_GROUPS) <= set(written["model"]) and not set(written["model"]) & GROUPED
    assert written["model"]["background"]["block"] == 4 and written["model"]["refine"]["hidden"] == 16
    assert read_checkpoint(run / "last.pt")["config"]["background"] == written["model"]["background"]
    assert load_config(run / "config.yaml")[0] == load_config(cfg)[0]

    # an older version wrote config.yaml flat, with the keys of branches since removed: the run resumes from it
    old = {**asdict(ModelConfig(**TINY_MODEL)), "learned_background": True, "patch_back": True}
    flat = {**written, "model": old}
    (run / "config.yaml").write_text(yaml.safe_dump(flat, sort_keys=False))
    assert main([*argv, "--resume"]) == 0
    assert read_checkpoint(run / "last.pt")["step"] == 4


def test_a_run_resumed_with_another_model_key_names_its_nested_path(tmp_path_factory, tmp_path):
    data = tiny_dataset(tmp_path_factory)
    train = {"batch_size": 1, "target_views": 1, "steps": 4, "val_every": 2, "val_scenes": 1, "num_threads": 1}
    cfg = _write(tmp_path / "a.yaml", TINY_MODEL, train)
    other = _write(tmp_path / "b.yaml", {**TINY_MODEL, "bg_mask_threshold": 0.3}, train)
    argv = ["train", "--data", str(data), "--out", str(tmp_path / "r")]
    assert main([*argv, "--config", str(cfg), "--stop-after", "1"]) == 0
    with pytest.raises(
        ConfigError, match=r"last\.pt: model\.background\.mask_threshold: the run was trained with 0\.2"
    ):
        main([*argv, "--config", str(other), "--resume"])
