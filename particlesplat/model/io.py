"""Checkpoints: ``{"config": dict, "state_dict": ..., "step": int}``, written atomically, read with weights_only."""

from __future__ import annotations

import importlib.resources
from os import PathLike
from pathlib import Path

import torch

from ..atomic import atomic_path
from .config import model_config_from_dict
from .particlesplat import ParticleSplat


def save_checkpoint(path: str | PathLike, model: ParticleSplat, step: int, extra: dict | None = None) -> None:
    """Write a model checkpoint atomically (``extra`` adds keys, e.g. optimiser and RNG states)."""
    state = {"config": model.config_dict(), "state_dict": {k: v.detach().cpu() for k, v in
                                                          model.state_dict().items()}, "step": int(step)}
    if extra:
        state.update(extra)
    with atomic_path(path) as tmp:
        torch.save(state, tmp)


def read_checkpoint(path: str | PathLike) -> dict:
    """Load a checkpoint dict (weights_only) and check its keys; errors name the file and the field."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: checkpoint not found")
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # torch raises several types for corrupt files
        raise ValueError(f"{path}: not a readable checkpoint ({e})") from e
    if not isinstance(ckpt, dict):
        raise ValueError(f"{path}: checkpoint must be a dict, got {type(ckpt).__name__}")
    for key in ("config", "state_dict", "step"):
        if key not in ckpt:
            raise ValueError(f"{path}: checkpoint has no '{key}' field")
    return ckpt


def model_from_checkpoint(ckpt: dict, where: str = "checkpoint", device: str | torch.device = "cpu") -> ParticleSplat:
    """Build the model a checkpoint dict describes and load its weights (eval mode)."""
    cfg = model_config_from_dict(ckpt["config"], f"{where}: config")
    model = ParticleSplat(cfg)
    try:
        model.load_state_dict(ckpt["state_dict"])
    except RuntimeError as e:
        raise ValueError(f"{where}: state_dict does not match its config ({e})") from e
    return model.to(device).eval()


def shipped_model_path() -> Path:
    """Path of ``model.pt`` in the installed ``particlesplat.assets`` package."""
    return Path(str(importlib.resources.files("particlesplat.assets").joinpath("model.pt")))


def load_model(path: str | PathLike | None = None, device: str | torch.device = "cpu") -> ParticleSplat:
    """Load a trained model (eval mode). ``path=None`` loads the shipped ``assets/model.pt``."""
    if path is None:
        path = shipped_model_path()
        if not path.is_file():
            raise FileNotFoundError(f"{path}: the shipped model is missing; train one with 'particlesplat train' "
                                    "or pass a checkpoint path")
    ckpt = read_checkpoint(path)
    return model_from_checkpoint(ckpt, str(path), device)
