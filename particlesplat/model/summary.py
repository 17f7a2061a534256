"""What a checkpoint is, in lines for ``particlesplat model info``: the model (family, resolution, particles,
static layer), how it was trained (steps of the run, batch, hours, init), on what data, the validation scores it
records, its inference keys and its provenance.

Everything comes from the checkpoint itself (``config``, ``step``, and where the run wrote them ``train``,
``val`` and ``provenance``); a key a checkpoint does not hold is said to be not recorded, never guessed.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

from particlesplat.core.panda_arm import ARM_STATE_KEY
from particlesplat.data.families import families
from particlesplat.model.config import ModelConfig, model_value
from particlesplat.model.derive import INFERENCE_KEYS
from particlesplat.model.provenance import describe

# validation metrics printed, in order: (key in the checkpoint's ``val``, label, format)
VAL_METRICS = (
    ("psnr", "PSNR", "{:.2f} dB"),
    ("ssim", "SSIM", "{:.3f}"),
    ("depth_abs_rel", "depth AbsRel", "{:.3f}"),
    ("fg_ari", "FG-ARI", "{:.3f}"),
    ("miou", "mIoU", "{:.3f}"),
    ("objects", "object groups", "{:.1f}"),
)


def family_of(cfg: ModelConfig) -> str:
    """The scene family a model's static layer is built for, by its registered title (the first family whose
    :attr:`~particlesplat.data.families.Family.static_layer` it is): a floor grid is the tabletop family's, free
    workspace Gaussians the robot workspace family's. A model that reads what a robot knows of itself
    (``bg_static_pose`` :data:`~particlesplat.core.panda_arm.ARM_STATE_KEY`) is the first robot family's."""
    if cfg.bg_static_pose == ARM_STATE_KEY:
        return next((f.title for f in families() if f.robot), "none registered (a robot's state)")
    layer = "points" if cfg.bg_static_points > 0 else "grid" if cfg.bg_static_grid > 0 else None
    if layer is None:
        return "none recorded (no static layer)"
    return next((f.title for f in families() if f.static_layer == layer), f"none registered (a {layer} static layer)")


def static_layer(cfg: ModelConfig) -> str:
    """One phrase for the layer every scene shares."""
    if cfg.bg_static_points > 0:
        follows = (
            f", moving with the scene's {cfg.bg_static_pose} ({cfg.bg_static_pose_dims} numbers)"
            if cfg.bg_static_pose
            else ""
        )
        return f"{cfg.bg_static_points:,} workspace Gaussians learned over the dataset{follows}"
    if cfg.bg_static_grid > 0:
        n = cfg.bg_static_grid
        return f"a {n}x{n} floor grid ({n * n:,} discs, +-{cfg.bg_static_extent:g} m)"
    return "none"


def _number(value: object) -> float | None:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    return float(value) if math.isfinite(value) else None


def training_line(step: int, train: object) -> str:
    """The step against the run's length, with its batch and views, from the checkpoint's ``train`` section."""
    if not isinstance(train, Mapping):
        return f"training: step {step:,} (the run's length and batch not recorded)"
    steps = train.get("steps")
    of = f" of a {steps:,}-step run" if isinstance(steps, int) and not isinstance(steps, bool) else ""
    parts = []
    if isinstance(train.get("batch_size"), int):
        parts.append(f"batch {train['batch_size']}")
    ctx, tgt = train.get("context_views"), train.get("target_views")
    if isinstance(ctx, list) and ctx and isinstance(tgt, int):
        parts.append(f"{'/'.join(str(c) for c in ctx)} context + {tgt} target views a scene")
    extra = f" ({', '.join(parts)})" if parts else ""
    return f"training: step {step:,}{of}{extra}"


def scores_line(val: object, train: object) -> str:
    """The validation scores the run recorded with this checkpoint, or that there are none."""
    if not isinstance(val, Mapping):
        return "validation scores: none recorded in this checkpoint"
    shown = []
    for key, label, fmt in VAL_METRICS:
        x = _number(val.get(key))
        if x is not None:
            shown.append(f"{label} {fmt.format(x)}")
    scenes = train.get("val_scenes") if isinstance(train, Mapping) else None
    where = f" on {scenes} validation scenes" if isinstance(scenes, int) and not isinstance(scenes, bool) else ""
    return f"validation scores at this step{where}: " + (", ".join(shown) if shown else "none readable")


def provenance_lines(prov: object) -> list[str]:
    """Where the weights come from (the checkpoint's ``provenance``): init, cost, code, data and any change
    made to the run's checkpoint after training."""
    if not isinstance(prov, Mapping):
        return [describe(None)]
    wall, cpu = _number(prov.get("wall_hours")), _number(prov.get("cpu_hours"))
    device = prov.get("device") or "not recorded"
    hours = (
        f"{wall:.2f} h wall, {cpu:.2f} CPU h on {device}"
        if wall is not None and cpu is not None
        else f"hours not recorded (device {device})"
    )
    commit = prov.get("git_commit") or "not recorded"
    n, sha = prov.get("train_scenes"), prov.get("scene_list_sha256")
    scenes = f", {n:,} training scenes" if isinstance(n, int) and not isinstance(n, bool) else ""
    listed = f" (scene list sha256 {sha[:12]})" if isinstance(sha, str) and sha else ""
    lines = [
        f"from: {prov.get('init') or 'random initialisation'}",
        f"cost: {hours}; torch {prov.get('torch')}, code {commit}",
        f"data: {prov.get('data') or 'not recorded'}{scenes}{listed}",
    ]
    if prov.get("derived"):
        lines.append(f"changed after training: {prov['derived']}")
    return lines


def summarize(ckpt: Mapping, cfg: ModelConfig, weights: int, refinement: str, name: str) -> list[str]:
    """The lines ``model info`` prints for checkpoint ``ckpt`` (read from ``name``) of a model built with
    ``cfg``, holding ``weights`` learned values, its refinement state in words."""
    step = int(ckpt["step"])
    per = cfg.gaussians_per_particle
    lines = [
        f"{name}: a ParticleSplat model of the {family_of(cfg)} family, {cfg.resolution}x{cfg.resolution} RGB-D, "
        f"step {step:,}",
        f"particles: {cfg.particles_per_view} a context view, {per} Gaussians each "
        f"({cfg.patch_gaussians}x{cfg.patch_gaussians} patch and a back layer); refinement {refinement}; "
        f"depth {cfg.d_min:g}-{cfg.d_max:g} m; {weights:,} learned values",
        f"static layer: {static_layer(cfg)}",
        training_line(step, ckpt.get("train")),
        *provenance_lines(ckpt.get("provenance")),
        scores_line(ckpt.get("val"), ckpt.get("train")),
        "inference keys ('particlesplat model set' changes them): "
        + ", ".join(f"{key} {model_value(cfg, key)}" for key in INFERENCE_KEYS),
    ]
    return lines[:1] + ["  " + line for line in lines[1:]]
