"""Checkpoints: ``{"config": dict, "state_dict": ..., "step": int}``, written atomically, read with weights_only."""

from __future__ import annotations

import hashlib
import importlib.resources
import json
import pickle
from os import PathLike
from pathlib import Path

import torch
from torch.torch_version import TorchVersion

from particlesplat.core.atomic import atomic_path
from particlesplat.core.errors import UserError, one_line
from particlesplat.model.config import model_config_from_dict, without_removed_keys
from particlesplat.model.particlesplat import ParticleSplat


def save_checkpoint(path: str | PathLike, model: ParticleSplat, step: int, extra: dict | None = None) -> None:
    """Write a model checkpoint atomically (``extra`` adds keys, e.g. optimiser and RNG states)."""
    config = model.config_dict()
    state = {
        "config": config,
        "state_dict": {k: v.detach().cpu() for k, v in model.state_dict().items()},
        "step": int(step),
        "config_sha256": config_digest(config),
    }
    if extra:
        state.update(extra)
    try:
        with atomic_path(path) as tmp:
            torch.save(state, tmp)
    except RuntimeError as e:  # torch reports a failed write (disk full, file too large) as RuntimeError
        raise OSError(
            f"{path}: cannot write the checkpoint ({one_line(e, 160)}); the previous file, if any, is unchanged"
        ) from None


class CheckpointError(UserError):
    """A checkpoint that cannot be used; the message names the file and the field."""


def config_digest(config: dict) -> str:
    """SHA-256 of a config dict (canonical JSON): saved beside the config so that a config edited after the
    weights were saved (e.g. another ``resolution``, which no weight shape reveals) is refused at load."""
    return hashlib.sha256(json.dumps(config, sort_keys=True, default=str).encode()).hexdigest()


def read_checkpoint(path: str | PathLike) -> dict:
    """Load a checkpoint dict (weights_only) and check its keys; errors name the file and the field."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: checkpoint not found")
    try:
        # TorchVersion: a str subclass, the torch version in the provenance of the first recipe checkpoints
        with torch.serialization.safe_globals([TorchVersion]):
            ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError:  # torch's own message suggests an unsafe load: never pass that on
        raise CheckpointError(
            f"{path}: refused: the checkpoint holds Python objects other than tensors and plain "
            "data (only weights-only checkpoints are loaded)"
        ) from None
    except Exception as e:  # torch raises several types for corrupt files
        detail = one_line(e, 160)
        if "weights_only" in detail:
            detail = "unsupported content"
        raise CheckpointError(f"{path}: not a readable checkpoint ({type(e).__name__}: {detail})") from None
    if not isinstance(ckpt, dict):
        raise CheckpointError(f"{path}: checkpoint must be a dict, got {type(ckpt).__name__}")
    for key in ("config", "state_dict", "step"):
        if key not in ckpt:
            raise CheckpointError(f"{path}: checkpoint has no '{key}' field")
    if not isinstance(ckpt["config"], dict):
        raise CheckpointError(f"{path}: config: expected a mapping, got {type(ckpt['config']).__name__}")
    check_state_dict(ckpt["state_dict"], str(path))
    if isinstance(ckpt["step"], bool) or not isinstance(ckpt["step"], int) or ckpt["step"] < 0:
        raise CheckpointError(f"{path}: step: expected a non-negative integer, got {type(ckpt['step']).__name__}")
    digest = ckpt.get("config_sha256")
    if digest is not None and digest != config_digest(ckpt["config"]):
        raise CheckpointError(
            f"{path}: config: changed after the weights were saved (config_sha256 does not "
            "match); the weights belong to the config they were trained with"
        )
    return ckpt


def check_state_dict(state: object, where: str) -> None:
    """CheckpointError naming ``where`` and the entry unless ``state`` maps names to finite tensors."""
    if not isinstance(state, dict):
        raise CheckpointError(
            f"{where}: state_dict: expected a mapping of names to tensors, got {type(state).__name__}"
        )
    for k, v in state.items():
        if not isinstance(v, torch.Tensor):
            raise CheckpointError(f"{where}: state_dict.{one_line(k, 80)}: expected a tensor, got {type(v).__name__}")
        if v.is_floating_point() and not bool(torch.isfinite(v).all()):
            raise CheckpointError(
                f"{where}: state_dict.{one_line(k, 80)}: non-finite weights (NaN or inf); the run "
                "that wrote it diverged: use an earlier checkpoint"
            )


def model_from_checkpoint(ckpt: dict, where: str = "checkpoint", device: str | torch.device = "cpu") -> ParticleSplat:
    """Build the model a checkpoint dict describes and load its weights (eval mode)."""
    cfg = model_config_from_dict(without_removed_keys(ckpt["config"], "model", f"{where}: config"), f"{where}: config")
    model = ParticleSplat(cfg)
    try:
        model.load_state_dict(ckpt["state_dict"])
    except RuntimeError as e:
        raise CheckpointError(f"{where}: state_dict does not match its config ({one_line(e, 300)})") from None
    return model.to(device).eval()


def shipped_model_path() -> Path:
    """Path of ``model.pt`` in the installed ``particlesplat.assets`` package."""
    return Path(str(importlib.resources.files("particlesplat.assets").joinpath("model.pt")))


def load_model(path: str | PathLike | None = None, device: str | torch.device = "cpu") -> ParticleSplat:
    """Load a trained model (eval mode). ``path=None`` loads the shipped ``assets/model.pt``."""
    if path is None:
        path = shipped_model_path()
        if not path.is_file():
            raise FileNotFoundError(
                f"{path}: the shipped model is missing; train one with 'particlesplat train' or pass a checkpoint path"
            )
    ckpt = read_checkpoint(path)
    return model_from_checkpoint(ckpt, str(path), device)
