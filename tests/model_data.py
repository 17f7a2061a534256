"""A tiny tabletop dataset (32x32, written once per pytest session) for the train and eval tests."""

from __future__ import annotations

from pathlib import Path

import yaml

from particlesplat.data.synth import scene_name, write_scene

# the recipe (ModelConfig() defaults: static floor layer, learned background colour, 2-layer patches with cubic
# cells, one refinement step), shrunk: 32x32 images, few channels, 4x4 patches grown from 2x2, a 16x16 floor layer
TINY_MODEL = dict(
    resolution=32,
    particles_per_view=3,
    kp_patch=4,
    glimpse_size=8,
    channels=8,
    d_obj=4,
    d_bg=2,
    bg_latent_stride=8,
    bg_block=4,
    bg_static_grid=16,
    patch_gaussians=4,
    patch_base=2,
    patch_channels=8,
    patch_hidden=16,
    refine_hidden=16,
    token_dim=16,
    transformer_layers=1,
    transformer_heads=2,
)


def tiny_dataset(tmp_path_factory) -> Path:
    """DATA/{train (2 scenes), val (1 scene)} at 32x32, shared by every test of the session."""
    root = tmp_path_factory.getbasetemp() / "tiny_tabletop"
    if not (root / "done").is_file():
        for split, n in (("train", 2), ("val", 1)):
            for i in range(n):
                write_scene(root / split / scene_name(i), 0, split, i, 32)
        (root / "done").write_text("ok")
    return root


def untrained_tiny_checkpoint(folder: Path) -> Path:
    """``folder/m.pt``: the tiny model at step 0, from torch's seed 0 (the same weights every call)."""
    import torch

    from particlesplat.model import ModelConfig, ParticleSplat, save_checkpoint

    torch.manual_seed(0)
    path = folder / "m.pt"
    save_checkpoint(path, ParticleSplat(ModelConfig(**TINY_MODEL)), step=0)
    return path


def tiny_config(path: Path, **train) -> Path:
    """Write a tiny model + train YAML to ``path``."""
    cfg = {
        "model": TINY_MODEL,
        "train": {
            "batch_size": 2,
            "target_views": 1,
            "steps": 4,
            "log_every": 1,
            "val_every": 2,
            "val_scenes": 1,
            "ckpt_every": 1,
            "num_threads": 1,
            **train,
        },
    }
    path.write_text(yaml.safe_dump(cfg))
    return path
