"""Model and training configuration: dataclasses loaded from YAML with clear validation errors.

The model config is written nested (``model: {resolution: 64, background: {block: 2, ...}, refine: {...}}``):
:data:`MODEL_GROUPS` names each group's keys and the :class:`ModelConfig` field each one is. The dataclass stays
flat (``cfg.bg_block``), and the nesting lives at the dict boundary: :func:`flat_model_dict` reads either form
(an old flat config, an old checkpoint) and :func:`nested_model_dict` writes the nested one (``config.yaml``,
checkpoints). Errors name a key by its nested path (``model.background.block``); a flat name is read too.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, fields
from os import PathLike
from pathlib import Path
from typing import Any, Literal, get_args

from particlesplat.core.errors import UserError, one_line, short_repr
from particlesplat.core.limits import float32_problem
from particlesplat.core.yamlsafe import YamlError, read_yaml


class ConfigError(UserError):
    """A configuration value is missing, unknown or out of range."""


# how the refinement's render draws the static layer: its Gaussians among the particles' at ``refine.scale``
# (render), or the encoder's full-resolution render of the layer, pooled and composited behind them (behind)
RefineStatic = Literal["render", "behind"]

# The model config's groups: group -> {key inside the group: the ModelConfig field it is}. A field in no group is
# a top-level key of the same name. Which module reads each group: docs/architecture.md.
MODEL_GROUPS: dict[str, dict[str, str]] = {
    "keypoints": {
        "patch": "kp_patch",
        "min_separation": "kp_min_separation",
        "glimpse_ratio": "glimpse_ratio",
        "glimpse_size": "glimpse_size",
    },
    "background": {
        "per_view": "bg_per_view",
        "latent_channels": "d_bg",
        "latent_stride": "bg_latent_stride",
        "block": "bg_block",
        "static_grid": "bg_static_grid",
        "static_extent": "bg_static_extent",
        "static_points": "bg_static_points",
        "static_pose": "bg_static_pose",
        "static_pose_dims": "bg_static_pose_dims",
        "mask_threshold": "bg_mask_threshold",
        "colour_from_views": "bg_colour_from_views",
        "hidden_from_views": "bg_hidden_from_views",
        "support_map": "bg_support_map",
        "opaque_under_objects": "bg_opaque_under_objects",
        "min_width": "bg_min_width",
    },
    "patch": {
        "gaussians": "patch_gaussians",
        "base": "patch_base",
        "channels": "patch_channels",
        "hidden": "patch_hidden",
        "colour_anchor": "patch_colour_anchor",
    },
    "support": {"clamp": "support_clamp", "cut": "support_cut"},
    "refine": {
        "steps": "refine_steps",
        "hidden": "refine_hidden",
        "scale": "refine_scale",
        "keep": "refine_keep",
        "static": "refine_static",
    },
    "transformer": {"token_dim": "token_dim", "layers": "transformer_layers", "heads": "transformer_heads"},
    "prior": {
        "offset_std": "prior_offset_std",
        "scale_mean": "prior_scale_mean",
        "scale_std": "prior_scale_std",
        "depth_mean": "prior_depth_mean",
        "depth_std": "prior_depth_std",
        "extent_mean": "prior_extent_mean",
        "extent_std": "prior_extent_std",
        "t_a": "prior_t_a",
        "t_b": "prior_t_b",
    },
}
# field -> its nested path ("bg_block" -> "background.block"); and every name a key may be given by -> its field
_PATH_OF: dict[str, str] = {f: f"{g}.{k}" for g, keys in MODEL_GROUPS.items() for k, f in keys.items()}
_FIELD_OF: dict[str, str] = {**{f: f for f in _PATH_OF}, **{p: f for f, p in _PATH_OF.items()}}


def model_key(name: str) -> str:
    """The nested path of ModelConfig field ``name`` (``"bg_block"`` -> ``"background.block"``; a top-level key
    is its own)."""
    return _PATH_OF.get(name, name)


def model_field(name: str) -> str:
    """The ModelConfig field a model key names, by its nested path or its flat name (``"background.block"`` and
    ``"bg_block"`` -> ``"bg_block"``); a name that is neither comes back unchanged (for the unknown-key error)."""
    return _FIELD_OF.get(name, name)


def model_value(cfg: ModelConfig, name: str) -> Any:
    """The value of the model key ``name`` (nested path or flat name) in ``cfg``."""
    return getattr(cfg, model_field(name))


def _checker(cfg, where: str, path: Callable[[str], str]):
    """need(cond, key, msg): raise ConfigError naming ``where.path(key)`` and its value unless ``cond``."""

    def need(cond: bool, key: str, msg: str) -> None:
        if not cond:
            raise ConfigError(f"{where}.{path(key)}: {msg} (got {short_repr(getattr(cfg, key))})")

    return need


# Integer ranges checked before validation and before anything is allocated: far beyond any model or run that
# fits this machine, so a typo (refine.hidden: 40000, resolution: 1048576) or a hostile checkpoint config is one
# clear line instead of gigabytes of weights; the lower ends keep divisions and tensor shapes valid. Keyed by
# field (a model key's flat name).
INT_RANGES: dict[str, tuple[int, int]] = {
    "resolution": (16, 1024),
    "particles_per_view": (0, 1024),
    "kp_patch": (2, 1024),
    "glimpse_size": (4, 256),
    "channels": (1, 1024),
    "d_obj": (1, 1024),
    "d_bg": (1, 1024),
    "bg_latent_stride": (1, 1024),
    "bg_block": (1, 1024),
    "bg_static_grid": (0, 512),
    "bg_static_points": (0, 200_000),
    "bg_static_pose_dims": (0, 64),
    "patch_gaussians": (1, 64),
    "patch_base": (0, 64),
    "patch_channels": (0, 1024),
    "patch_hidden": (0, 4096),
    "refine_steps": (0, 16),
    "refine_hidden": (1, 4096),
    "refine_keep": (0, 1 << 16),
    "token_dim": (1, 2048),
    "transformer_layers": (0, 64),
    "transformer_heads": (1, 64),
    "sh_degree": (0, 3),
    "batch_size": (1, 4096),
    "target_views": (0, 64),
    "steps": (1, 10**9),
    "log_every": (1, 10**9),
    "val_every": (1, 10**9),
    "val_scenes": (1, 10**6),
    "ckpt_every": (1, 10**9),
    "seed": (0, 2**63 - 1),
    "num_threads": (0, 1024),
    "cache_scenes": (0, 10**6),
}


@dataclass
class ModelConfig:
    """Architecture and renderer-side hyperparameters (documented in ``assets/recipe.yaml``). Flat for code
    (``cfg.bg_block``); a config file and a checkpoint hold it nested (:data:`MODEL_GROUPS`). Fields in the order
    the nested form lists them: the top-level keys, then each group's."""

    resolution: int = 64
    particles_per_view: int = 8
    offset_bound: float = 0.15
    scale_logit_bound: float = 1.5
    channels: int = 32
    d_obj: int = 64
    sh_degree: int = 0
    d_min: float = 1.0
    d_max: float = 7.0
    s_min: float = 0.2
    s_max: float = 0.8
    fg_evidence: bool = False
    canonical_frame: bool = False
    # keypoints:
    kp_patch: int = 4
    kp_min_separation: float = 0.25
    glimpse_ratio: float = 0.15
    glimpse_size: int = 16
    # background:
    bg_per_view: bool = False
    d_bg: int = 5
    bg_latent_stride: int = 64
    bg_block: int = 2
    bg_static_grid: int = 72
    bg_static_extent: float = 2.25
    bg_static_points: int = 0
    bg_static_pose: str = ""
    bg_static_pose_dims: int = 0
    bg_mask_threshold: float = 0.2
    bg_colour_from_views: bool = False
    bg_hidden_from_views: bool = False
    bg_support_map: bool = False
    bg_opaque_under_objects: bool = False
    bg_min_width: float = 0.0
    # patch:
    patch_gaussians: int = 16
    patch_base: int = 4
    patch_channels: int = 64
    patch_hidden: int = 256
    patch_colour_anchor: bool = False
    # support:
    support_clamp: bool = False
    support_cut: float = -1.0
    # refine:
    refine_steps: int = 1
    refine_hidden: int = 256
    refine_scale: float = 1.0
    refine_keep: int = 0
    refine_static: RefineStatic = "render"
    # transformer:
    token_dim: int = 64
    transformer_layers: int = 2
    transformer_heads: int = 4
    # prior: (prior table, RLBench column)
    prior_offset_std: float = 0.2
    prior_scale_mean: float = 0.15
    prior_scale_std: float = 0.3
    prior_depth_mean: float = 0.0
    prior_depth_std: float = 1.0
    prior_extent_mean: float = 0.3
    prior_extent_std: float = 0.3
    prior_t_a: float = 0.01
    prior_t_b: float = 0.01

    def validate(self, where: str = "model") -> None:
        need = _checker(self, where, model_key)
        need(self.resolution >= 16 and self.resolution % 16 == 0, "resolution", "must be a multiple of 16, >= 16")
        need(self.particles_per_view >= 1, "particles_per_view", "must be >= 1")
        need(
            self.kp_patch >= 2 and self.resolution % self.kp_patch == 0,
            "kp_patch",
            "must be >= 2 and divide the resolution",
        )
        need(
            (self.resolution // self.kp_patch) ** 2 >= self.particles_per_view,
            "particles_per_view",
            "must not exceed the number of keypoint proposals (resolution/keypoints.patch)^2",
        )
        need(0.0 < self.glimpse_ratio < 1.0, "glimpse_ratio", "must be in (0, 1)")
        need(self.kp_min_separation >= 0.0, "kp_min_separation", "must be >= 0")
        need(self.offset_bound > 0.0, "offset_bound", "must be > 0")
        need(self.scale_logit_bound > 0.0, "scale_logit_bound", "must be > 0")
        need(self.glimpse_size >= 4 and self.glimpse_size % 4 == 0, "glimpse_size", "must be a multiple of 4")
        need(self.channels >= 4, "channels", "must be >= 4")
        need(self.d_obj >= 1, "d_obj", "must be >= 1")
        need(self.d_bg >= 1, "d_bg", "must be >= 1")
        for key in ("bg_latent_stride", "bg_block"):
            v = getattr(self, key)
            need(v >= 1 and self.resolution % v == 0, key, "must divide the resolution")
        need(self.bg_static_grid >= 0, "bg_static_grid", "must be >= 0 (0 = no static background layer)")
        need(self.bg_static_extent > 0.0, "bg_static_extent", "must be > 0 (metres)")
        need(self.bg_static_points >= 0, "bg_static_points", "must be >= 0 (0 = no workspace layer)")
        need(
            self.bg_static_grid == 0 or self.bg_static_points == 0,
            "bg_static_points",
            "the static layer is either the floor grid (background.static_grid) or the workspace points; set one to 0",
        )
        need(
            (self.bg_static_pose == "") == (self.bg_static_pose_dims == 0),
            "bg_static_pose",
            "and background.static_pose_dims go together: a scene.json key and the length of its list ('' and 0: off)",
        )
        need(
            self.bg_static_pose == "" or self.bg_static_points > 0 or self.fg_evidence,
            "bg_static_pose",
            "moves the workspace layer: it needs background.static_points > 0 (or fg_evidence, which reads the "
            "robot state)",
        )
        need(
            not self.fg_evidence or (self.bg_per_view and self.bg_latent_stride == self.bg_block),
            "fg_evidence",
            "needs the per-view background (background.per_view: true) with background.latent_stride equal to "
            "background.block (its anchors are per block)",
        )
        need(
            not self.bg_opaque_under_objects or (self.fg_evidence and self.bg_hidden_from_views),
            "bg_opaque_under_objects",
            "needs fg_evidence and background.hidden_from_views (it draws the table under an object in the colour "
            "hidden_from_views gives it)",
        )
        need(
            self.bg_min_width == 0.0 or self.fg_evidence,
            "bg_min_width",
            "bounds the anchored background's Gaussians: it needs fg_evidence",
        )
        need(
            self.bg_per_view or self.has_static_background,
            "bg_per_view",
            "false needs a static background layer (background.static_grid or background.static_points > 0): "
            "nothing would draw the background",
        )
        need(self.support_cut < 1.0, "support_cut", "must be < 1 (metres below the support surface; < 0 = off)")
        need(self.patch_gaussians >= 1, "patch_gaussians", "must be >= 1")
        base = self.patch_base or self.patch_gaussians
        ratio = self.patch_gaussians // base if self.patch_base >= 0 and base > 0 else 0
        need(
            self.patch_base >= 0 and ratio >= 1 and base * ratio == self.patch_gaussians and ratio & (ratio - 1) == 0,
            "patch_base",
            "must be 0 (= patch.gaussians) or patch.gaussians divided by a power of 2",
        )
        need(self.patch_channels == 0 or self.patch_channels >= 4, "patch_channels", "must be 0 (= channels) or >= 4")
        need(self.patch_hidden >= 0, "patch_hidden", "must be >= 0 (0: twice the patch channels)")
        need(self.refine_steps >= 0, "refine_steps", "must be >= 0 (0: no refinement)")
        need(
            self.refine_steps == 0 or self.glimpse_size % 8 == 0,
            "glimpse_size",
            "must be a multiple of 8 with refine.steps > 0 (the refiner's glimpse)",
        )
        need(self.refine_hidden >= 1, "refine_hidden", "must be >= 1")
        need(0.0 < self.refine_scale <= 1.0, "refine_scale", "must be in (0, 1]")
        need(self.refine_keep >= 0, "refine_keep", "must be >= 0 (0: every Gaussian)")
        need(self.refine_static in get_args(RefineStatic), "refine_static", "must be render or behind")
        need(
            self.refine_static == "render" or (self.has_static_background and not self.bg_per_view),
            "refine_static",
            "behind needs a static layer (background.static_grid or background.static_points > 0) and no per-view "
            "background (background.per_view: false)",
        )
        need(
            (self.resolution * self.refine_scale).is_integer() and self.resolution * self.refine_scale >= 8,
            "refine_scale",
            f"resolution x refine.scale must be a whole number of pixels, at least 8 (resolution {self.resolution})",
        )
        need(self.token_dim % self.transformer_heads == 0, "token_dim", "must be divisible by transformer.heads")
        need(self.transformer_layers >= 0, "transformer_layers", "must be >= 0")
        need(self.sh_degree in (0, 1), "sh_degree", "must be 0 or 1")
        need(0.0 < self.d_min < self.d_max, "d_min", "need 0 < d_min < d_max")
        need(0.0 < self.s_min < self.s_max, "s_min", "need 0 < s_min < s_max")
        need(0.0 <= self.bg_mask_threshold <= 1.0, "bg_mask_threshold", "must be in [0, 1]")
        need(
            self.bg_min_width == 0.0 or self.s_min <= self.bg_min_width < self.s_max,
            "bg_min_width",
            f"must be 0 (off) or in [s_min, s_max) = [{self.s_min}, {self.s_max})",
        )
        for key in ("prior_scale_mean", "prior_extent_mean"):
            need(0.0 < getattr(self, key) < 1.0, key, "is a sigmoid-space mean, must be in (0, 1)")
        for key in (
            "prior_offset_std",
            "prior_scale_std",
            "prior_depth_std",
            "prior_extent_std",
            "prior_t_a",
            "prior_t_b",
        ):
            need(getattr(self, key) > 0.0, key, "must be > 0")

    @property
    def has_static_background(self) -> bool:
        """A background layer shared by every scene: the floor grid or the workspace points."""
        return self.bg_static_grid > 0 or self.bg_static_points > 0

    @property
    def gaussians_per_particle(self) -> int:
        """2 S²: a front and a back Gaussian per cell of the S x S patch."""
        return 2 * self.patch_gaussians**2

    def render_keys(self, particles_key: str = "model.particles_per_view") -> str:
        """The keys that size this model's renders, with their values, for memory messages: ``model.resolution 64,
        model.particles_per_view 8, model.patch_gaussians 16`` (its pixels, particles and Gaussians a particle; with
        the refinement, ``model.refine_scale``). ``particles_key``: where the particle count comes from (training
        may take ``train.particles_per_view``)."""
        keys = f"model.resolution {self.resolution}, {particles_key} {self.particles_per_view}, "
        keys += f"model.patch_gaussians {self.patch_gaussians}"
        return keys + (f", model.refine_scale {self.refine_scale:g}" if self.refine_steps > 0 else "")

    @property
    def particle_decoder_channels(self) -> int:
        """Channels of the particle decoder's feature grid: ``patch.channels``, else ``channels``."""
        return self.patch_channels or self.channels

    @property
    def particle_decoder_hidden(self) -> int:
        """Width of the particle decoder's hidden layer (z_f -> hidden -> base grid): ``patch.hidden``, else
        twice :attr:`particle_decoder_channels`."""
        return self.patch_hidden or 2 * self.particle_decoder_channels

    def depth_of(self, logit):
        """Planar depth (metres) of a depth logit (tensor): d_min + σ(logit)(d_max − d_min)."""
        return self.d_min + logit.sigmoid() * (self.d_max - self.d_min)

    def depth_logit(self, depth):
        """The logit whose :meth:`depth_of` is ``depth`` (tensor, metres, inside (d_min, d_max))."""
        return ((depth - self.d_min) / (self.d_max - self.d_min)).logit()

    @property
    def logit_prior_scale(self) -> float:
        return math.log(self.prior_scale_mean / (1.0 - self.prior_scale_mean))

    @property
    def logit_prior_extent(self) -> float:
        return math.log(self.prior_extent_mean / (1.0 - self.prior_extent_mean))


@dataclass
class TrainConfig:
    """Optimisation, loss and data-sampling settings (documented in ``assets/recipe.yaml``)."""

    batch_size: int = 4
    context_views: list[int] = field(default_factory=lambda: [2])
    target_views: int = 2
    steps: int = 40000
    lr: float = 0.0004
    lr_background: float = 0.01
    lr_final: float = 0.05
    grad_clip: float = 1.0
    beta_kl: float = 0.02
    beta_f: float = 1.0
    beta_reg: float = 0.1
    beta_fg: float = 0.4
    beta_fg_until: float = 1.0
    fg_threshold: float = 0.02
    fg_outside: float = 1.0
    beta_rec_ctx: float = 1.0
    beta_rec_tgt: float = 1.0
    lambda_depth: float = 0.5
    gap_warmup: float = 0.1
    refine_start: float = 0.5
    particles_per_view: int = 4
    kp_min_separation: float = 0.35
    log_every: int = 10
    val_every: int = 500
    val_scenes: int = 12
    ckpt_every: int = 50
    seed: int = 42
    num_threads: int = 2
    adapt_threads: bool = True
    cache_scenes: int = 1100

    def fg_weight(self, step: int) -> float:
        """The foreground term's weight at ``step``: ``beta_fg`` before ``beta_fg_until`` of the steps, then 0."""
        return self.beta_fg if step < self.beta_fg_until * self.steps else 0.0

    def validate(self, where: str = "train") -> None:
        need = _checker(self, where, str)
        need(self.batch_size >= 1, "batch_size", "must be >= 1")
        need(
            isinstance(self.context_views, list)
            and len(self.context_views) > 0
            and all(v in (1, 2) for v in self.context_views),
            "context_views",
            "must be a list of 1s and 2s",
        )
        need(self.target_views >= 0, "target_views", "must be >= 0")
        need(self.steps >= 1, "steps", "must be >= 1")
        need(self.lr > 0, "lr", "must be > 0")
        need(self.lr_background > 0, "lr_background", "must be > 0")
        need(0.0 <= self.lr_final <= 1.0, "lr_final", "must be in [0, 1]")
        need(0.0 <= self.gap_warmup <= 1.0, "gap_warmup", "must be in [0, 1]")
        need(self.particles_per_view >= 0, "particles_per_view", "must be >= 0 (0: the model's)")
        need(self.kp_min_separation >= 0.0, "kp_min_separation", "must be >= 0 (0: the model's)")
        need(0.0 <= self.refine_start <= 1.0, "refine_start", "must be in [0, 1] (a fraction of the steps)")
        need(0.0 <= self.beta_fg_until <= 1.0, "beta_fg_until", "must be in [0, 1] (a fraction of the steps)")
        need(self.cache_scenes >= 0, "cache_scenes", "must be >= 0")
        for key in ("log_every", "val_every", "ckpt_every"):
            need(getattr(self, key) >= 1, key, "must be >= 1")
        for key in (
            "beta_kl",
            "beta_f",
            "beta_reg",
            "beta_fg",
            "fg_threshold",
            "fg_outside",
            "beta_rec_ctx",
            "beta_rec_tgt",
            "lambda_depth",
            "grad_clip",
        ):
            need(getattr(self, key) >= 0, key, "must be >= 0")


def _from_dict(cls, data: Any, where: str):
    """``cls`` (ModelConfig or TrainConfig) from a flat dict of its fields; errors name ``where`` and the key (a
    model key by its nested path)."""
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError(f"{where}: expected a mapping, got {type(data).__name__}")
    path: Callable[[str], str] = model_key if cls is ModelConfig else str
    known = {f.name: f for f in fields(cls)}
    unknown = sorted(one_line(k, 40) for k in set(data) - set(known))
    if unknown:
        listed = list(_top_level_keys()) + list(MODEL_GROUPS) if cls is ModelConfig else list(known)
        raise ConfigError(
            f"{where}: unknown key(s) {one_line(', '.join(unknown[:5]), 200)} (known: {', '.join(listed)})"
        )
    out = cls()
    for k, v in data.items():
        name = path(k)
        default = getattr(out, k)
        if isinstance(default, (bool, list, str)):
            ok = isinstance(v, type(default))
        elif isinstance(default, float):
            ok = isinstance(v, (int, float)) and not isinstance(v, bool)
            v = float(v) if ok else v
        elif isinstance(default, int):
            ok = isinstance(v, int) and not isinstance(v, bool)
        else:
            ok = True
        if not ok:
            hint = ""
            if isinstance(default, float) and isinstance(v, str):
                try:
                    float(v)
                    hint = " (text, not a number: write it without quotes, e.g. 1.0e-4 or 0.0001)"
                except ValueError:
                    pass
            raise ConfigError(f"{where}.{name}: expected {type(default).__name__}, got {short_repr(v)}{hint}")
        if isinstance(v, float) and not math.isfinite(v):
            raise ConfigError(f"{where}.{name}: must be a finite number (got {v})")
        if isinstance(v, float) and float32_problem(v) is not None:  # the model computes in float32
            raise ConfigError(f"{where}.{name}: {float32_problem(v)} (got {v:g})")
        if k in INT_RANGES and isinstance(v, int) and not isinstance(v, bool):
            lo, hi = INT_RANGES[k]
            if not lo <= v <= hi:
                raise ConfigError(f"{where}.{name}: must be in [{lo}, {hi}] (got {short_repr(v)})")
        if isinstance(v, list) and len(v) > 64:
            raise ConfigError(f"{where}.{name}: a list of at most 64 entries (got {len(v)})")
        setattr(out, k, v)
    out.validate(where)
    return out


def _top_level_keys() -> list[str]:
    """The model keys outside every group, in field order."""
    return [f.name for f in fields(ModelConfig) if f.name not in _PATH_OF]


def nested_model_dict(flat: dict[str, Any]) -> dict[str, Any]:
    """The nested form of a flat model config dict (fields as keys, e.g. ``asdict(cfg)``): its top-level keys,
    then one mapping per group of :data:`MODEL_GROUPS` (a group none of whose fields is in ``flat`` is left out).
    What ``config.yaml`` and checkpoints hold; :func:`flat_model_dict` reads it back."""
    out = {k: v for k, v in flat.items() if k not in _PATH_OF}
    for group, keys in MODEL_GROUPS.items():
        inner = {name: flat[f] for name, f in keys.items() if f in flat}
        if inner:
            out[group] = inner
    return out


def flat_model_dict(data: Any, where: str) -> Any:
    """A model config dict, nested (``background: {block: 2}``), flat (``bg_block: 2``, as configs and
    checkpoints were written before the groups) or both, with every key as its ModelConfig field. A key given
    twice (flat and nested) is a ConfigError naming ``where`` and both spellings; a group that is not a mapping
    or holds an unknown key is one naming the group. Anything else (unknown top-level keys, the keys of removed
    branches, a non-mapping ``data``) passes through for the checks after it."""
    if not isinstance(data, dict):
        return data
    out: dict[Any, Any] = {}
    given: dict[Any, str] = {}

    def put(key: Any, spelled: str, value: Any) -> None:
        if key in out:
            raise ConfigError(
                f"{where}: {one_line(given[key], 60)} and {one_line(spelled, 60)} are the same key "
                f"({model_key(key)}); give it once"
            )
        out[key], given[key] = value, spelled

    for k, v in data.items():
        if isinstance(k, str) and k in MODEL_GROUPS:
            keys = MODEL_GROUPS[k]
            if not isinstance(v, dict):
                raise ConfigError(
                    f"{where}.{k}: expected a mapping of {k} keys ({', '.join(keys)}), got {type(v).__name__}"
                )
            unknown = sorted(one_line(n, 40) for n in set(v) - set(keys))
            if unknown:
                raise ConfigError(
                    f"{where}.{k}: unknown key(s) {one_line(', '.join(unknown[:5]), 200)} (known: {', '.join(keys)})"
                )
            for name, value in v.items():
                put(keys[name], f"{k}.{name}", value)
        else:
            put(model_field(k) if isinstance(k, str) else k, k if isinstance(k, str) else repr(k), v)
    return out


def config_to_dict(cfg: ModelConfig | TrainConfig) -> dict:
    """A config as written (``config.yaml``, checkpoints): a model config nested (:func:`nested_model_dict`), a
    train config flat."""
    return nested_model_dict(asdict(cfg)) if isinstance(cfg, ModelConfig) else asdict(cfg)


# Keys of experiment branches the recipes do not use; the code behind them is gone. Checkpoints and configs
# written before (the shipped assets/model.pt among them) still hold them: each maps to the value that turned its
# branch off, which is what the code now always does (ANY: it only tuned a removed branch, so any value reads as
# off). Removed keys were only ever written flat.
ANY = object()
REMOVED_KEYS: dict[str, dict[str, Any]] = {
    "model": {
        "kp_selection": "residual",
        "kp_cross_view": False,
        "bg_detail": 0,
        "bg_detail_threshold": ANY,
        "bg_copy_input": False,
        "patch_refine": 0,
        "patch_cell_mlp": 0,
        "patch_copy_input": False,
        "patch_copy_threshold": ANY,
        "particle_depth_scale": "cell",
        "refine_glimpse": 0,
        # black behind the Gaussians instead of the learned colour
        "learned_background": True,
        # a patch without its back layer
        "patch_back": True,
    },
    "train": {
        "beta_coarse": ANY,
        "fg_band": 0,
        "depth_dropout": 0.0,
        "bg_off_steps": 0,
        "freeze": [],
    },
}


def without_removed_keys(data: Any, section: str, where: str) -> Any:
    """A stored ``section`` ("model" or "train") config dict without the keys of removed branches (see
    :data:`REMOVED_KEYS`) that hold their "off" value. Raises ConfigError naming ``where`` and the key when one
    holds a value that switched its branch on: this version cannot build that model."""
    if not isinstance(data, dict):
        return data
    removed = REMOVED_KEYS[section]
    out = {}
    for k, v in data.items():
        if k not in removed:
            out[k] = v
            continue
        off = removed[k]
        if off is not ANY and not (v == off and isinstance(v, bool) == isinstance(off, bool)):
            raise ConfigError(
                f"{where}.{k}: {v!r} switches on a branch this version no longer has (only "
                f"{off!r}, off, can be read); use the version of ParticleSplat that wrote it"
            )
    return out


def model_config_from_dict(data: Any, where: str = "model") -> ModelConfig:
    """A validated ModelConfig from a nested or flat dict (:func:`flat_model_dict`); errors name ``where``."""
    return _from_dict(ModelConfig, flat_model_dict(data, where), where)


def train_config_from_dict(data: Any, where: str = "train") -> TrainConfig:
    return _from_dict(TrainConfig, data, where)


def stored_model_config(data: Any, where: str) -> ModelConfig:
    """The ``model`` config a checkpoint or a config file holds, nested or flat, through the dataclass: a key
    added since it was written takes its default, a removed one that held its "off" value is dropped
    (:func:`without_removed_keys`); errors name ``where``."""
    return model_config_from_dict(without_removed_keys(flat_model_dict(data, where), "model", where), where)


def stored_train_config(data: Any, where: str) -> TrainConfig:
    """The ``train`` config a checkpoint or a config file holds (as :func:`stored_model_config`)."""
    return train_config_from_dict(without_removed_keys(data, "train", where), where)


def load_config(path: str | PathLike) -> tuple[ModelConfig, TrainConfig]:
    """Read a YAML file with top-level ``model:`` and ``train:`` mappings (the model section nested or flat; keys
    of removed branches at their "off" value are dropped, so a run's old ``config.yaml`` still reads)."""
    path = Path(path)
    try:
        data = read_yaml(path, "config")
    except YamlError as e:
        raise ConfigError(str(e)) from None
    except OSError as e:
        raise ConfigError(f"{path}: cannot read config ({e.strerror or e})") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a mapping with 'model' and 'train' keys")
    unknown = sorted(one_line(k, 40) for k in set(data) - {"model", "train"})
    if unknown:
        raise ConfigError(
            f"{path}: unknown top-level key(s) {one_line(', '.join(unknown[:5]), 200)} (known: model, train)"
        )
    return (
        stored_model_config(data.get("model"), f"{path}: model"),
        stored_train_config(data.get("train"), f"{path}: train"),
    )


def with_overrides(model: ModelConfig, train: TrainConfig, changes: dict[str, Any]) -> tuple[ModelConfig, TrainConfig]:
    """The configs with ``SECTION.KEY: value`` changes (``{"train.steps": 200, "model.refine.steps": 0}``, as
    ``particlesplat train`` takes them after its options; a model key by its nested path or its flat name,
    ``model.refine_steps``), each checked as a config file's key is (known key, type, range, the section's
    consistency). ConfigError naming the change (``override train.steps: expected int, got 'x'``)."""
    sections: dict[str, dict[str, Any]] = {"model": {}, "train": {}}
    for name, value in changes.items():
        section, dot, key = name.partition(".")
        if not dot or section not in sections or not key:
            raise ConfigError(f"override {one_line(name, 60)}: expected model.KEY=VALUE or train.KEY=VALUE")
        sections[section][key] = value
    return (
        _from_dict(
            ModelConfig, {**asdict(model), **flat_model_dict(sections["model"], "override model")}, "override model"
        )
        if sections["model"]
        else model,
        _from_dict(TrainConfig, {**asdict(train), **sections["train"]}, "override train")
        if sections["train"]
        else train,
    )
