"""Checkpoints: ``{"config": dict, "state_dict": ..., "step": int}``, written atomically, read with weights_only."""

from __future__ import annotations

import hashlib
import json
import pickle
from os import PathLike
from pathlib import Path

import torch
from torch.overrides import TorchFunctionMode
from torch.torch_version import TorchVersion

from particlesplat.core.atomic import atomic_path
from particlesplat.core.errors import UserError, one_line
from particlesplat.core.limits import check_memory
from particlesplat.data.families import DEFAULT_FAMILY, families, get_family, shipped_model_named
from particlesplat.model.config import ModelConfig, stored_model_config, stored_train_config
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
    if model.input_ranges is not None:
        state["input_ranges"] = model.input_ranges
    if extra:
        state.update(extra)
    try:
        with atomic_path(path) as tmp:
            torch.save(state, tmp)
    except RuntimeError as e:  # torch reports a failed write (disk full, file too large) as RuntimeError
        detail = one_line(e, 160)
        if "enforce fail" in detail or "write" in detail.lower():  # torch's C++ writer says nothing useful
            detail = f"the write failed: the disk is full or the file too large; {free_space(Path(path).parent)}"
        raise OSError(
            f"{path}: cannot write the checkpoint ({detail}); the previous file, if any, is unchanged"
        ) from None


def free_space(folder: Path) -> str:
    """``"N MiB free on FOLDER"`` (or that it is unknown), for messages about failed writes."""
    import shutil

    from particlesplat.core.limits import format_bytes

    try:
        return f"{format_bytes(shutil.disk_usage(folder).free)} free in {folder}"
    except OSError:
        return f"free space in {folder} unknown"


# what a weight may be: dense, real, floating-point or integer (a sparse, complex or quantised tensor is refused)
DENSE_DTYPES = (
    torch.float16,
    torch.bfloat16,
    torch.float32,
    torch.float64,
    torch.uint8,
    torch.int8,
    torch.int16,
    torch.int32,
    torch.int64,
    torch.bool,
)


# the largest weight or buffer a checkpoint may hold: the shipped models' largest is 14 (a workspace point's metres,
# a weight); 1e6 leaves room for any plausible training while a product of a few such values stays finite in float32
WEIGHT_MAX_ABS = 1e6


class CheckpointError(UserError):
    """A checkpoint that cannot be used; the message names the file and the field."""


def config_digest(config: dict) -> str:
    """SHA-256 of a config dict (canonical JSON): saved beside the config so that a config edited after the
    weights were saved (e.g. another ``resolution``, which no weight shape reveals) is refused at load."""
    return hashlib.sha256(json.dumps(config, sort_keys=True, default=str).encode()).hexdigest()


def read_checkpoint(path: str | PathLike) -> dict:
    """Load a checkpoint dict (weights_only) and check its keys; errors name the file and the field. A shipped
    model's name (``assets/robot/model.pt``) opens it from any working directory (:func:`shipped_model_named`)."""
    path = shipped_model_named(path) or Path(path)
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
    if ckpt.get("provenance") is not None:
        from particlesplat.model.provenance import provenance_problem

        problem = provenance_problem(ckpt["provenance"])
        if problem:
            raise CheckpointError(
                f"{path}: provenance.{problem}" if ":" in problem else f"{path}: provenance: {problem}"
            )
    if ckpt.get("input_ranges") is not None:
        from particlesplat.data.pose_ranges import check_ranges

        try:
            check_ranges(ckpt["input_ranges"], str(path))
        except UserError as e:
            raise CheckpointError(str(e)) from None
    if ckpt.get("train") is not None:  # the run's train section, checked as the config is
        if not isinstance(ckpt["train"], dict):
            raise CheckpointError(f"{path}: train: expected a mapping, got {type(ckpt['train']).__name__}")
        try:
            stored_train_config(ckpt["train"], f"{path}: train")
        except UserError as e:
            raise CheckpointError(str(e)) from None
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
        if v.layout != torch.strided or v.is_complex() or v.is_quantized or v.dtype not in DENSE_DTYPES:
            raise CheckpointError(
                f"{where}: state_dict.{one_line(k, 80)}: expected a dense real tensor, got {v.layout} {v.dtype} "
                "(weights are dense floating-point or integer tensors)"
            )
        if v.is_floating_point() and not bool(torch.isfinite(v).all()):
            raise CheckpointError(
                f"{where}: state_dict.{one_line(k, 80)}: non-finite weights (NaN or inf); the run "
                "that wrote it diverged: use an earlier checkpoint"
            )
        if v.numel() and v.dtype != torch.bool:
            largest = float(v.detach().abs().max())
            if largest > WEIGHT_MAX_ABS:
                raise CheckpointError(
                    f"{where}: state_dict.{one_line(k, 80)}: values up to {largest:.3g}, beyond the "
                    f"+-{WEIGHT_MAX_ABS:g} a weight or buffer may hold (float32 arithmetic on it overflows; a trained "
                    "model's stay below 100)"
                )


class _SmallTensorsOnCpu(TorchFunctionMode):
    """Inside ``torch.device("meta")``: tensors built from Python values (``torch.tensor``) stay real, so that a
    constructor may read them back (``float(...)``); parameters and buffers are shapes only."""

    def __torch_function__(self, func, types, args=(), kwargs=None):
        kwargs = dict(kwargs or {})
        if func in (torch.tensor, torch.as_tensor, torch.scalar_tensor) and kwargs.get("device") is None:
            kwargs["device"] = "cpu"
        return func(*args, **kwargs)


def model_values(cfg: ModelConfig) -> int | None:
    """Number of values (parameters and buffers) the model of ``cfg`` holds, counted by building it on the meta
    device (nothing is allocated; ~0.2 s). None when the model cannot be built that way."""
    try:
        with torch.device("meta"), _SmallTensorsOnCpu():
            model = ParticleSplat(cfg)
    except (RuntimeError, NotImplementedError, TypeError, ValueError):
        return None
    return sum(t.numel() for t in model.parameters()) + sum(t.numel() for t in model.buffers())


def check_model_memory(cfg: ModelConfig, where: str, copies: int = 1) -> None:
    """BudgetError naming ``where`` when the model of ``cfg`` (``copies`` float32 values per weight: 1 to use it,
    4 to train it with Adam: weights, gradients and two moments) would not fit the memory limit; checked
    before the weights are allocated."""
    n = model_values(cfg)
    if n is not None:
        check_memory(
            4.0 * copies * n,
            f"{where}: a model of {n:,} weights (transformer.token_dim {cfg.token_dim}, "
            f"transformer.layers {cfg.transformer_layers}){' with gradients and Adam moments' if copies > 1 else ''}",
        )


# Peak memory of encoding one scene of V context views (and decoding it), measured with the shipped model
# (resolution 64, 8 particles per view) on a 2-core CPU: 34, 58, 171, 426 and 865 MB above the loaded model for
# V = 1, 2, 4, 6, 8 (and ~2.8 GB for 12): about 21 MB * V + 1.36 MB * V^3 (the refinement renders every
# particle's Gaussians into every view). Scaled with the pixels and particles per view.
ENCODE_BYTES_PER_VIEW = 21e6
ENCODE_BYTES_PER_VIEW_CUBED = 1.36e6


def encode_memory(cfg: ModelConfig, views: int) -> float:
    """Estimated peak bytes of encoding (and decoding) one scene of ``views`` context views with a model of
    ``cfg`` (calibrated on the shipped model, :data:`ENCODE_BYTES_PER_VIEW`; weights not included)."""
    pixels = (cfg.resolution / 64.0) ** 2
    particles = max(cfg.particles_per_view, 1) / 8.0
    return pixels * (ENCODE_BYTES_PER_VIEW * views + ENCODE_BYTES_PER_VIEW_CUBED * particles**2 * views**3)


def model_from_checkpoint(ckpt: dict, where: str = "checkpoint", device: str | torch.device = "cpu") -> ParticleSplat:
    """Build the model a checkpoint dict describes and load its weights (eval mode)."""
    cfg = stored_model_config(ckpt["config"], f"{where}: config")
    check_model_memory(cfg, f"{where}: config")
    model = ParticleSplat(cfg)
    own = model.state_dict()
    for k, v in ckpt["state_dict"].items():  # an integer copy of a floating-point weight loses its fractions
        if k in own and own[k].is_floating_point() and not v.is_floating_point():
            raise CheckpointError(
                f"{where}: state_dict.{one_line(k, 80)}: stored as {v.dtype}, but the model's weight is "
                f"floating-point ({own[k].dtype})"
            )
    try:
        model.load_state_dict(ckpt["state_dict"])
    except RuntimeError as e:
        raise CheckpointError(f"{where}: state_dict does not match its config ({one_line(e, 300)})") from None
    model.refine_enabled = refinement_trained(ckpt)
    from particlesplat.data.pose_ranges import check_ranges

    model.input_ranges = check_ranges(ckpt.get("input_ranges"), where)
    return model.to(device).eval()


def refinement_trained(ckpt: dict) -> bool:
    """Whether the run that wrote ``ckpt`` had begun to train its refinement (from ``train.refine_start`` of
    ``train.steps``). Before that the refiner is still at its start, a correction of exactly zero, and the run
    validated without it; refining would only cost time (about 60 % of a robot model's encode). True for a
    checkpoint that does not record its schedule."""
    train = ckpt.get("train")
    if not isinstance(train, dict):
        return True
    start, steps = train.get("refine_start"), train.get("steps")
    if not isinstance(start, (int, float)) or isinstance(start, bool) or not isinstance(steps, int):
        return True
    return int(ckpt["step"]) >= start * steps


def shipped_model_path(family: str = DEFAULT_FAMILY) -> Path:
    """Path of the shipped model of a registered scene ``family`` (:attr:`Family.shipped_model`) in the installed
    ``particlesplat.assets`` package; ValueError naming the registered families for another name."""
    return get_family(family).shipped_model_path()


def shipped_model_name(path: str | PathLike) -> str:
    """How a model is named in screenshots, edit files and ``encode`` output: ``assets/…`` for a shipped one,
    else the path as given."""
    for family in families():
        if Path(path) == family.shipped_model_path():
            return f"assets/{family.shipped_model}"
    return str(path)


def load_model(
    path: str | PathLike | None = None, device: str | torch.device = "cpu", *, scene: str | PathLike | None = None
) -> ParticleSplat:
    """Load a trained model (eval mode).

    Args:
        path: a checkpoint, or a shipped model's name (``assets/robot/model.pt``, opened from any working
            directory). None: the shipped model of ``scene``'s family, as every command picks it without
            ``--checkpoint`` (what its ``scene.json`` records; the default family's ``assets/model.pt`` when
            ``scene`` is None or records none).
        device: where the weights go.
        scene: a scene folder (or a split or dataset folder of one family) whose family picks the model when
            ``path`` is None.
    """
    if path is None:
        from particlesplat.data.scene_meta import default_checkpoint

        if scene is not None and not Path(scene).is_dir():
            raise FileNotFoundError(f"{scene}: scene folder not found")
        path = default_checkpoint(scene)
    path = shipped_model_named(path) or Path(path)
    if not path.is_file() and any(path == f.shipped_model_path() for f in families()):
        raise FileNotFoundError(
            f"{path}: the shipped model is missing; train one with 'particlesplat train' or pass a checkpoint path"
        )
    ckpt = read_checkpoint(path)
    return model_from_checkpoint(ckpt, str(path), device)
