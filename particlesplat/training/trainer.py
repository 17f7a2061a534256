"""``particlesplat train``: optimise the multi-view ELBO on a folder of scenes, with exact resume and DDP."""

from __future__ import annotations

import json
import math
import os
import re
import shutil
import signal
import sys
import threading
import time
import weakref
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

import torch
import torch.distributed as dist
from torch.nn.parallel import DistributedDataParallel
from tqdm import tqdm

from particlesplat.core.atomic import atomic_path, atomic_write, stale_temporaries
from particlesplat.core.device import resolve_device
from particlesplat.core.errors import Interrupted, OptionError, UserError, one_line, short_repr
from particlesplat.core.gaussians import BadGaussiansError
from particlesplat.core.runlock import LOCK_NAME, RunLock
from particlesplat.core.threads import ThreadGovernor
from particlesplat.data.dataset import TrainingBatch
from particlesplat.data.pose_ranges import check_ranges, record_range
from particlesplat.model import ModelConfig, ParticleSplat, TrainConfig, read_checkpoint, save_checkpoint
from particlesplat.model.config import (
    ConfigError,
    config_to_dict,
    model_key,
    stored_model_config,
    stored_train_config,
)
from particlesplat.model.io import check_model_memory
from particlesplat.model.provenance import Provenance, RunClock
from particlesplat.model.static_background import WorkspaceBackground
from particlesplat.training.eta import StepTimes
from particlesplat.training.loss import training_loss
from particlesplat.training.runlog import LogReader, read_log
from particlesplat.training.schedules import gap_progress, lr_factor, training_selection
from particlesplat.training.step_budget import check_step_renders

LAST = "last.pt"
STEP_FILE = re.compile(r"^step_\d+\.pt$")
WORKSPACE_SCENES = 40  # training scenes the workspace layer's start is found in
THREAD_CHECK_STEPS = 10  # steps between checks of the cores other processes keep busy (train.adapt_threads)
# train keys a --resume may change (with a warning): when and how the run reports, checkpoints and uses the CPU, and
# its length (extending a finished run); any other key would make the resumed run another run than the one started
RESUME_MAY_CHANGE = (
    "steps",
    "log_every",
    "val_every",
    "val_scenes",
    "ckpt_every",
    "num_threads",
    "adapt_threads",
    "cache_scenes",
)
MAX_SKIPPED = 20  # steps in a row with non-finite loss or gradients before the run stops as diverged


class _Laps:
    """Seconds between calls, summed per phase name into ``timings`` (None: does nothing)."""

    def __init__(self, timings: dict[str, float] | None):
        self.timings = timings
        self.last = time.perf_counter()

    def __call__(self, phase: str) -> None:
        if self.timings is not None:
            now = time.perf_counter()
            self.timings[phase] = self.timings.get(phase, 0.0) + now - self.last
            self.last = now


class TrainingDiverged(UserError):
    """Non-finite gradients or weights that skipping steps did not cure; nothing was saved."""


def _is_checkpoint(name: str) -> bool:
    """A run's checkpoint (last.pt, best.pt, step_*.pt) or a temporary of one (a run killed while saving)."""
    if name == "best.pt.tmp":
        return True
    tmp = re.match(r"^\.(.+)\.\d+\.[0-9a-f]{8}\.tmp", name)
    name = tmp.group(1) if tmp else name
    return name in (LAST, "best.pt") or bool(STEP_FILE.match(name))


RUN_FILES = ("config.yaml", "metrics.jsonl")  # what a run writes besides checkpoints


def _run_without_checkpoint(out: Path, held: list[Path]) -> bool:
    """Whether ``held`` (the files of a run folder) are only what a run that stopped before its first checkpoint
    left: its log and, from earlier versions, its ``config.yaml`` (a mapping of ``model`` and ``train`` only, not a
    user's own file of that name)."""
    if not held or any(p.name not in RUN_FILES or not p.is_file() for p in held):
        return False
    if not (out / "config.yaml").is_file():
        return True
    from particlesplat.core.yamlsafe import YamlError, read_yaml

    try:
        data = read_yaml(out / "config.yaml", "config")
    except (YamlError, OSError):
        return False
    return (
        isinstance(data, dict) and set(data) == {"model", "train"} and all(isinstance(v, dict) for v in data.values())
    )


class Trainer:
    """Holds the model, optimiser, datasets and RNG; one instance per process."""

    def __init__(
        self,
        cfg: ModelConfig,
        tc: TrainConfig,
        data: Path,
        out: Path,
        device: str,
        resume: bool,
        overwrite: bool = False,
        init: Path | None = None,
        config_source: str = "--config",
    ):
        self.cfg, self.tc, self.out = cfg, tc, out
        self.config_source = config_source  # where cfg and tc come from, in messages
        self.device = device if isinstance(device, torch.device) else resolve_device(device)
        # the folder is owned by this process before anything in it is read or deleted (a folder that does not
        # exist yet is locked when run() creates it)
        self.lock = RunLock(out)
        self._release = weakref.finalize(self, self.lock.release)
        if int(os.environ.get("RANK", "0")) == 0 and out.is_dir():
            self.lock.acquire()
        try:
            self._setup(data, resume, overwrite, init)
        except BaseException:
            self.lock.release()
            raise

    def _setup(self, data: Path, resume: bool, overwrite: bool, init: Path | None) -> None:
        cfg, tc, out = self.cfg, self.tc, self.out
        self.resumed = resume
        if init is not None and resume:
            raise UserError(
                f"--init {init}: --init starts a run from a checkpoint's weights and --resume continues one "
                "(which keeps the init it started from); pass one of them"
            )
        if out.exists() and not out.is_dir():
            raise FileExistsError(f"{out}: --out is a file, not a folder")
        held = [p for p in out.iterdir() if p.name != LOCK_NAME] if out.is_dir() else []
        has_run = any(_is_checkpoint(p.name) for p in held)
        if not resume and not overwrite and held:
            raise FileExistsError(
                f"{out}: --out is not empty; pass --resume to continue the run in it, "
                "--overwrite to replace it, or choose another folder"
            )
        if overwrite and not resume and held and not has_run and not _run_without_checkpoint(out, held):
            raise FileExistsError(
                f"{out}: --overwrite replaces a training run, and this folder holds none (no last.pt, best.pt or "
                f"step_*.pt; it holds {', '.join(sorted(p.name for p in held)[:3])}{', ...' if len(held) > 3 else ''}"
                "); choose another --out"
            )
        replace(cfg, particles_per_view=tc.particles_per_view or cfg.particles_per_view).validate(
            "train.particles_per_view with the model"
        )
        self.provenance = Provenance.start(data, None, str(self.device))  # --init names its source below
        self.clock = RunClock()
        if tc.beta_fg > 0 and not (cfg.has_static_background or cfg.fg_evidence):
            raise ConfigError(
                f"train.beta_fg: the foreground term compares with the static background layer or with the "
                f"foreground evidence of depth; set model.background.static_grid or model.background.static_points "
                f"> 0, or model.fg_evidence, or beta_fg to 0 (got {tc.beta_fg})"
            )
        self.distributed = int(os.environ.get("WORLD_SIZE", "1")) > 1
        if self.distributed:
            dist.init_process_group("gloo" if self.device.type == "cpu" else "nccl")
        self.rank = dist.get_rank() if self.distributed else 0
        self.world = dist.get_world_size() if self.distributed else 1
        from particlesplat.core.limits import memory_limit
        from particlesplat.data import SceneDataset
        from particlesplat.data.dataset import CACHE_SHARE

        # the scene caches count in the job's memory: one share of the limit, divided among the datasets
        cache_bytes = int(memory_limit()[0] * CACHE_SHARE / len(set(tc.context_views)))
        self.train_sets = {
            c: SceneDataset(
                data / "train",
                resolution=cfg.resolution,
                mode="multi" if c == 2 else "single",
                num_targets=tc.target_views,
                flip=False,
                cache_size=tc.cache_scenes,
                cache_bytes=cache_bytes,
                pose_key=cfg.bg_static_pose,
                pose_dims=cfg.bg_static_pose_dims,
            )
            for c in sorted(set(tc.context_views))
        }
        self.val_dir = data / "val"
        if self.rank == 0 and self.val_dir.is_dir():
            self._check_val_scenes()
        self.skipped = 0  # steps skipped for non-finite loss or gradients, this invocation
        torch.manual_seed(tc.seed + 1000 * self.rank)
        self.gen = torch.Generator().manual_seed(tc.seed * 7919 + self.rank)
        check_model_memory(cfg, f"{self.config_source}: model", copies=4)  # before the weights are allocated
        self.model = ParticleSplat(cfg).to(self.device)
        copied = self._init_from(init) if init is not None else set()
        if not resume and cfg.bg_static_points > 0 and not any(n.startswith("static_bg.") for n in copied):
            self._start_workspace()
        if not resume and self.model.follows_pose and "static_bg.pose_mean" not in copied:
            self._set_pose_mean()
        elif not resume and (self.model.follows_pose or (cfg.fg_evidence and cfg.bg_static_pose)):
            # --init kept its pose mean, or the model reads the robot state: the range is this run's scenes'
            ds = next(iter(self.train_sets.values()))
            self.model.input_ranges = {self.cfg.bg_static_pose: record_range([ds.pose(i) for i in range(len(ds))])}
        # the learned background colour and the static background layer move at lr_background
        is_bg = lambda n: n == "background_logit" or n.startswith("static_bg.")  # noqa: E731
        trained = list(self.model.named_parameters())
        bg = [p for n, p in trained if is_bg(n)]
        rest = [p for n, p in trained if not is_bg(n)]
        groups: list[dict[str, Any]] = [{"params": rest, "lr": tc.lr}]  # torch's parameter groups
        if bg:
            groups.append({"params": bg, "lr": tc.lr_background})
        # the names of the weights each optimiser group moves: a resume with another layout (weights frozen or
        # grouped otherwise) is refused, not continued with Adam moments of other weights
        self.layout = [[n for n, p in trained if not is_bg(n)]] if rest else []
        self.layout += [[n for n, p in trained if is_bg(n)]] if bg else []
        self.base_lrs: list[float] = [g["lr"] for g in groups]  # each group's lr before the cosine factor
        self.opt = torch.optim.Adam(groups, lr=tc.lr, betas=(0.9, 0.999), eps=1e-6)
        self.step = 0
        self.best = -math.inf
        self.run_avg: dict[str, float] = {}  # running means of the logged losses (kept across --resume)
        if resume and (out / LAST).is_file():
            self._load(out / LAST)
        elif resume and held and _run_without_checkpoint(out, held):
            raise FileNotFoundError(
                f"{out / LAST}: nothing to resume: the run stopped before its first checkpoint (the folder holds "
                f"{', '.join(sorted(p.name for p in held))}); start it again with --overwrite"
            )
        elif resume:
            raise FileNotFoundError(f"{out / LAST}: nothing to resume")
        elif (out / LAST).is_file() and not overwrite:
            raise FileExistsError(
                f"{out / LAST}: this run already exists; pass --resume to continue it or choose another --out"
            )
        check_step_renders(self.model, self.cfg, self.tc, self.train_sets, self.device, self.config_source)
        # (before --overwrite deletes anything)
        # steps before refine_start leave the refiner's weights without gradients
        unused = cfg.refine_steps > 0 and tc.refine_start > 0
        self.ddp = (
            DistributedDataParallel(self.model, find_unused_parameters=unused) if self.distributed else self.model
        )
        if overwrite and not resume and self.rank == 0 and out.is_dir():
            self._clear_run()

    def _start_workspace(self) -> None:
        """Start the workspace layer (``model.background.static_points``) at the voxels most of the first
        ``WORKSPACE_SCENES`` training scenes share (:func:`particlesplat.data.workspace_points.workspace_points`;
        no labels are read). Deterministic: the same data gives the same start."""
        from particlesplat.data.workspace_points import workspace_points

        scenes = next(iter(self.train_sets.values())).scenes[:WORKSPACE_SCENES]
        found = workspace_points(scenes, self.cfg.bg_static_points)
        layer = self.model.static_bg
        if not isinstance(layer, WorkspaceBackground):
            raise RuntimeError(
                f"background.static_points is {self.cfg.bg_static_points} but the model has no workspace layer"
            )
        layer.initialise(*(torch.from_numpy(a) for a in (found.points, found.colours, found.sizes)))
        if self.rank == 0:
            print(
                f"workspace layer: {len(found.points)} of {self.cfg.bg_static_points} Gaussians placed from "
                f"{len(scenes)} training scenes",
                file=sys.stderr,
            )

    def _set_pose_mean(self) -> None:
        """The workspace layer follows each scene's pose (``model.background.static_pose``) about the mean pose of the
        training scenes (each must record one)."""
        ds = next(iter(self.train_sets.values()))
        layer = self.model.static_bg
        if not isinstance(layer, WorkspaceBackground):
            raise RuntimeError("background.static_pose is set but the model has no workspace layer")
        poses = [ds.pose(i) for i in range(len(ds))]
        layer.set_pose_mean(torch.tensor(poses))
        self.model.input_ranges = {self.cfg.bg_static_pose: record_range(poses)}  # saved with every checkpoint
        if self.rank == 0:
            print(
                f"workspace layer: follows {self.cfg.bg_static_pose} about its mean over {len(ds)} training scenes",
                file=sys.stderr,
            )

    def _init_from(self, path: Path) -> set[str]:
        """``--init``: copy every weight of the checkpoint at ``path`` whose name and shape this model shares; the
        others keep their random initialisation (a module the checkpoint lacks, such as a per-view background
        added to a model trained without one). The step, optimiser, schedule and RNG start afresh. Returns the
        names copied; the run's provenance records the source."""
        ckpt = read_checkpoint(path)
        own = self.model.state_dict()
        theirs = ckpt["state_dict"]
        copied = {n for n, v in theirs.items() if n in own and tuple(v.shape) == tuple(own[n].shape)}
        if not copied:
            raise UserError(
                f"{path}: --init: none of its {len(theirs)} weights has a name and shape of this model's; "
                "is it a ParticleSplat checkpoint of this architecture?"
            )
        self.model.load_state_dict({**own, **{n: theirs[n] for n in copied}})
        self.provenance.init = f"{path} (step {ckpt['step']})"
        if self.rank == 0:
            lines = [f"--init {path} (step {ckpt['step']}): {len(copied)} of this model's {len(own)} weights copied"]
            reshaped = [n for n in theirs if n in own and n not in copied]
            for what, names in (
                ("started at random (not in the checkpoint)", [n for n in own if n not in theirs]),
                ("started at random (another shape in the checkpoint)", reshaped),
                ("in the checkpoint but not in this model, left out", [n for n in theirs if n not in own]),
            ):
                if names:
                    modules = sorted({n.rsplit(".", 1)[0] for n in names})
                    more = ", ..." if len(modules) > 8 else ""
                    lines.append(f"  {what}: {len(names)} in {', '.join(modules[:8])}{more}")
            print("\n".join(lines), file=sys.stderr)
        return copied

    def _clear_run(self) -> None:
        """--overwrite: remove the earlier run's own files (log, config, checkpoints) once every check has passed,
        so its log is not continued and its step files do not mix with the new run's. Other files stay."""
        for path in [
            *self.out.glob("step_*.pt"),
            *(self.out / n for n in ("metrics.jsonl", "config.yaml", LAST, "best.pt")),
        ]:
            if path.is_file():
                path.unlink()

    # ------------------------------------------------------------------ state
    def _rng_state(self) -> dict:
        return {"torch": torch.get_rng_state(), "gen": self.gen.get_state()}

    def _check_val_scenes(self) -> None:
        """Read the validation scenes once now: a corrupt one is found at the start, not at the first validation
        (and not again on every resume)."""
        from particlesplat.data.dataset import SceneDataset
        from particlesplat.data.scene import read_scene

        ds = SceneDataset(self.val_dir)
        need = max(self.tc.context_views) + 1
        for folder in ds.scenes[: self.tc.val_scenes]:
            raw = read_scene(folder)
            if raw.num_frames < need:
                raise UserError(
                    f"{folder}: validation scene has {raw.num_frames} frame(s); validation needs at "
                    f"least {need} (targets apart from the context views)"
                )

    def _check_finite(self) -> None:
        """TrainingDiverged (nothing is saved) unless every weight is finite."""
        for n, p in self.model.named_parameters():
            if not bool(torch.isfinite(p.detach()).all()):
                raise TrainingDiverged(
                    f"{self.out}: step {self.step}: weight '{n}' is not finite; stopped without "
                    f"saving (the last checkpoint in {self.out} is kept)"
                )

    def _clean_temporaries(self) -> None:
        """Remove temporary files a killed run left in the run folder (``.NAME.PID.XXXXXXXX.tmp*`` of a process
        that no longer runs, and ``best.pt.tmp``)."""
        for p in stale_temporaries(self.out):
            p.unlink(missing_ok=True)
        (self.out / "best.pt.tmp").unlink(missing_ok=True)

    def _save(self, path: Path) -> None:
        self._check_finite()
        states: list[dict | None] = [self._rng_state()]
        if self.distributed:
            states = [None] * self.world
            dist.all_gather_object(states, self._rng_state())
        if self.rank != 0:
            return
        save_checkpoint(
            path,
            self.model,
            self.step,
            {
                "optimizer": self.opt.state_dict(),
                "optimizer_layout": self.layout,
                "rng": states,
                "train": config_to_dict(self.tc),
                "best": float(self.best),
                "run_avg": {k: float(v) for k, v in self.run_avg.items()},
                "provenance": self.provenance_now(),
            },
        )
        if not getattr(self, "_config_written", False):
            self._write_config()

    def _write_config(self) -> None:
        """``config.yaml`` (every key, resolved), written beside the run's first checkpoint and never before: a
        folder holding it holds a run to resume."""
        import yaml

        with atomic_write(self.out / "config.yaml", "w") as f:
            yaml.safe_dump({"model": config_to_dict(self.cfg), "train": config_to_dict(self.tc)}, f, sort_keys=False)
        self._config_written = True

    def provenance_now(self) -> dict:
        """The run's provenance with the hours spent up to now."""
        wall, cpu = self.clock.hours()
        return {**self.provenance.to_dict(), "wall_hours": round(wall, 6), "cpu_hours": round(cpu, 6)}

    def _load(self, path: Path) -> None:
        ckpt = read_checkpoint(path)
        stored = stored_model_config(ckpt["config"], f"{path}: config")
        if stored != self.cfg:
            have, want = asdict(stored), asdict(self.cfg)
            key = next(k for k in want if have.get(k) != want[k])
            raise ConfigError(
                f"{path}: model.{model_key(key)}: the run was trained with {short_repr(have.get(key))}, "
                f"{self.config_source} gives {short_repr(want[key])}; resume with the run's config (leave --config out)"
            )
        if isinstance(ckpt.get("train"), dict):
            self._compare_train(path, stored_train_config(ckpt["train"], f"{path}: train"))
        self.model.load_state_dict(ckpt["state_dict"])
        self.model.input_ranges = check_ranges(ckpt.get("input_ranges"), str(path))
        if "optimizer" in ckpt:
            self._check_layout(path, ckpt)
            try:
                self.opt.load_state_dict(ckpt["optimizer"])
            except (ValueError, KeyError, TypeError, RuntimeError) as e:
                raise UserError(f"{path}: optimizer: does not fit this run's optimiser ({one_line(e, 160)})") from None
        self.step = int(ckpt["step"])
        self.best = float(ckpt.get("best", -math.inf))
        run_avg = ckpt.get("run_avg")
        if isinstance(run_avg, dict):  # the logged running means continue as if the run had not stopped
            self.run_avg = {
                str(k): float(v) for k, v in run_avg.items() if isinstance(v, (int, float)) and math.isfinite(v)
            }
        prov = ckpt.get("provenance")
        if isinstance(prov, dict):  # the run keeps its origin and adds this invocation's hours to its own
            if prov.get("scene_list_sha256") not in (None, self.provenance.scene_list_sha256):
                print(
                    f"warning: {path}: trained on another scene list ({prov.get('data')}); "
                    f"continuing on {self.provenance.data}"
                )
            self.provenance.init = prov.get("init")
            self.clock = RunClock(float(prov.get("wall_hours", 0.0)), float(prov.get("cpu_hours", 0.0)))
        self._drop_log_after(self.step)
        states = ckpt.get("rng")
        if "optimizer" not in ckpt or states is None:  # a step_*.pt or best.pt copied over last.pt to roll back
            if self.rank == 0:
                print(
                    f"warning: {path}: no optimizer or RNG state (a step_*.pt or best.pt?): Adam's moments start "
                    "afresh and the data order is reseeded from the step; the resume is not bit-exact",
                    file=sys.stderr,
                )
            torch.manual_seed(self.tc.seed + 1000 * self.rank + 7 * self.step)
            self.gen.manual_seed(self.tc.seed * 7919 + self.rank + 104729 * self.step)
            return
        if len(states) != self.world:
            raise UserError(f"{path}: saved by {len(states)} process(es), resuming with {self.world}")
        torch.set_rng_state(states[self.rank]["torch"])
        self.gen.set_state(states[self.rank]["gen"])

    def _compare_train(self, path: Path, stored: TrainConfig) -> None:
        """--resume: the run continues exactly only with the train section it was started with. Keys that change
        when and how it reports (:data:`RESUME_MAY_CHANGE`) are taken with a warning; another value of any other
        key is refused naming the key and both values."""
        have, want = config_to_dict(stored), config_to_dict(self.tc)
        changed = [k for k in want if have.get(k) != want[k]]
        refused = [k for k in changed if k not in RESUME_MAY_CHANGE]
        if refused:
            k = refused[0]
            more = f" (and {', '.join(refused[1:4])}{', ...' if len(refused) > 4 else ''})" if len(refused) > 1 else ""
            raise ConfigError(
                f"{path}: train.{k}: the run was started with {short_repr(have.get(k))}, {self.config_source} gives "
                f"{short_repr(want[k])}{more}; a resumed run continues exactly only with its own train section "
                f"(leave --config out to use the run's config.yaml; these may change: {', '.join(RESUME_MAY_CHANGE)})"
            )
        if changed and self.rank == 0:
            detail = ", ".join(f"{k} {short_repr(have.get(k))} -> {short_repr(want[k])}" for k in changed)
            note = " (the learning-rate schedule follows the new steps)" if "steps" in changed else ""
            print(f"warning: {path}: train: resumed with {detail}{note}", file=sys.stderr)

    def _check_layout(self, path: Path, ckpt: dict) -> None:
        """UserError unless the checkpoint's optimiser moved the weights this run's optimiser moves, in the same
        groups (its ``optimizer_layout``; older checkpoints: each Adam moment's shape against its weight's)."""
        layout = ckpt.get("optimizer_layout")
        if layout is not None:
            if layout != self.layout:
                have = {n for g in layout for n in g} if isinstance(layout, list) else set()
                want = {n for g in self.layout for n in g}
                diff = sorted(have ^ want)[:3]
                raise UserError(
                    f"{path}: optimizer_layout: the run trained other weights than this run would, e.g. "
                    f"{', '.join(diff) or 'in other groups'}; resume it with the version and config that started it"
                )
            return
        params = [p for g in self.opt.param_groups for p in g["params"]]
        state = ckpt["optimizer"].get("state", {}) if isinstance(ckpt["optimizer"], dict) else {}
        groups = ckpt["optimizer"].get("param_groups", []) if isinstance(ckpt["optimizer"], dict) else []
        ids = [i for g in groups if isinstance(g, dict) for i in g.get("params", [])]
        if len(ids) != len(params) or any(
            isinstance(state.get(i), dict)
            and isinstance(state[i].get("exp_avg"), torch.Tensor)
            and tuple(state[i]["exp_avg"].shape) != tuple(p.shape)
            for i, p in zip(ids, params, strict=False)
        ):
            raise UserError(
                f"{path}: optimizer: the run trained other weights than this run would (its Adam moments do not "
                "fit them); resume it with the version and config that started it"
            )

    # ------------------------------------------------------------------ loop
    def batch(self) -> TrainingBatch:
        ctx = self.tc.context_views[int(torch.randint(len(self.tc.context_views), (1,), generator=self.gen))]
        ds = self.train_sets[ctx]
        ds.set_progress(gap_progress(self.step, self.tc))
        idx = torch.randint(len(ds), (self.tc.batch_size,), generator=self.gen).tolist()
        batch = TrainingBatch.collate([ds[i] for i in idx])
        torch.rand((), generator=self.gen)  # one draw per step keeps a seed's batches those of the recorded runs
        return batch.to(self.device)

    def train_step(self, timings: dict[str, float] | None = None) -> dict[str, float]:
        """One optimiser step. ``timings``: filled with the seconds of its phases (data, forward, backward,
        update), for ``particlesplat bench train``."""
        lap = _Laps(timings)
        batch = self.batch()
        lap("data")
        self.ddp.train()
        self.model.refine_enabled = self.step >= self.tc.refine_start * self.tc.steps
        try:
            with training_selection(self.model.config, self.tc):
                parts, _ = training_loss(
                    self.ddp, batch, self.tc, self.cfg.resolution, self.cfg, self.tc.fg_weight(self.step)
                )
        except BadGaussiansError:  # the forward pass diverged before the loss: skipped as a non-finite loss is
            self.opt.zero_grad(set_to_none=True)
            self.step += 1
            return {"skipped": 1.0}
        lap("forward")
        self.opt.zero_grad(set_to_none=True)
        parts["loss"].backward()
        lap("backward")
        grads = [p.grad for p in self.model.parameters() if p.grad is not None]
        if grads and not bool(torch.stack([torch.isfinite(g).all() for g in grads]).all()):
            # one NaN gradient would become all-NaN after clipping: skip the update, keep the weights
            self.opt.zero_grad(set_to_none=True)
            self.step += 1
            return {"skipped": 1.0}
        factor = lr_factor(self.step, self.tc)
        for g, base in zip(self.opt.param_groups, self.base_lrs, strict=False):
            g["lr"] = base * factor
        if self.tc.grad_clip > 0:
            torch.nn.utils.clip_grad_norm_(self.model.parameters(), self.tc.grad_clip)
        self.opt.step()
        self.step += 1
        out = {k: float(v.detach()) for k, v in parts.items()}
        lap("update")
        return out

    def validate(self) -> dict[str, float]:
        from particlesplat.analysis.evaluate import evaluate_dataset
        from particlesplat.rendering.budget import render_budget

        self.model.eval()
        with render_budget(f"{self.config_source}: validation ({self.cfg.render_keys()})"):
            res = evaluate_dataset(
                self.model,
                self.val_dir,
                context=max(self.tc.context_views),
                limit=self.tc.val_scenes,
                progress_bar=False,
            )
        self.model.train()
        return res["mean"]

    def _drop_log_after(self, step: int) -> None:
        """On resume: forget metrics.jsonl records of steps after the checkpoint (they will be logged again)."""
        path = self.out / "metrics.jsonl"
        if self.rank != 0 or not path.is_file():
            return

        # streamed twice (a 1 GB log is never held whole): what to drop, then the kept lines rewritten
        def later(r: dict) -> bool:
            return isinstance(r.get("step"), int) and r["step"] > step

        dropped, note = read_log(path, keep=later)  # a torn last line (disk full, crash) is reported, left out
        if note:
            print(f"warning: {note}", file=sys.stderr)
        if note or dropped:
            reader = LogReader(path)
            with atomic_write(path, "w") as f:
                for _, r in reader:
                    if not later(r):
                        f.write(json.dumps(r) + "\n")

    def log(self, record: dict) -> None:
        if self.rank == 0:
            path = self.out / "metrics.jsonl"
            try:
                with open(path, "a") as f:
                    f.write(json.dumps(record) + "\n")
            except OSError as e:  # a full disk: name the file (a torn last line is repaired on --resume)
                raise OSError(e.errno, f"{path}: cannot append to the log ({e.strerror or e})") from None

    def run(self, stop_after: int | None = None) -> int:
        """Train until ``steps`` (or for at most ``stop_after`` more steps, then checkpoint and return)."""
        try:
            return self._run(stop_after)
        finally:
            self.lock.release()

    def _run(self, stop_after: int | None) -> int:
        tc = self.tc
        if self.resumed and self.step > tc.steps:
            raise UserError(
                f"{self.out / LAST}: the run is at step {self.step}, beyond train.steps {tc.steps}; "
                "raise train.steps in --config to train further"
            )
        if self.resumed and self.step == tc.steps:
            print(f"{self.out / LAST}: the run is complete (step {self.step} of {tc.steps}); nothing to train")
            return 0
        if stop_after is not None and stop_after < 1:
            raise OptionError(f"--stop-after must be >= 1 step (a run checkpoints when it stops), got {stop_after}")
        end = tc.steps if stop_after is None else min(tc.steps, self.step + stop_after)
        if self.rank == 0:
            if self.lock.owner is None and int(os.environ.get("RANK", "0")) == 0:
                self.lock.acquire()  # a new folder: owned from its creation
            self._clean_temporaries()
            from particlesplat.rendering.choice import rasterizer_note

            print(f"rasterizer: {rasterizer_note(self.device, grad=True)}", file=sys.stderr)
        stop = {"signum": 0}

        def on_signal(signum, frame):  # finish the step, save, exit; a second signal stops at once
            if stop["signum"]:
                raise KeyboardInterrupt
            stop["signum"] = signum

        handlers = {}
        if threading.current_thread() is threading.main_thread():
            handlers = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
        try:
            self._loop(end, stop)
            if self.distributed:
                self._leave_group()
            if stop["signum"] and self.step < end:
                raise Interrupted(
                    f"saved {self.out / LAST} at step {self.step}; continue with --resume", stop["signum"]
                )
        finally:
            if getattr(self, "_bar", None) is not None:
                self._bar.close()  # ends the bar's line: an error message gets a line of its own
            for sig, handler in handlers.items():
                signal.signal(sig, handler)
        return 0

    def _leave_group(self) -> None:
        """Leave the process group with every rank, once rank 0 has written ``last.pt``.

        A rank that exits at once can abort (SIGABRT): gloo's worker threads may still hold the last
        ``all_gather_object``'s tensors, and freeing a Python-owned tensor from a C++ thread while the interpreter
        finalises ends the process (pytorch/pytorch#190489). DDP keeps the group alive past
        ``destroy_process_group``, so its threads are not joined there.
        """
        dist.barrier()
        dist.destroy_process_group()

    def _loop(self, end: int, stop: dict | None = None) -> None:
        tc = self.tc
        stop = stop if stop is not None else {}
        self._bar = bar = tqdm(  # time left: the median of the recent steps (particlesplat.training.eta)
            total=tc.steps,
            initial=self.step,
            desc="train",
            disable=self.rank != 0,
            dynamic_ncols=True,
            bar_format="{l_bar}{bar}| {n_fmt}/{total_fmt} [{elapsed}, {postfix}]",
        )
        step_times = StepTimes()
        run_avg = self.run_avg
        skipped_in_a_row = 0
        governor = None
        if tc.adapt_threads and self.device.type == "cpu" and not self.distributed:
            governor = ThreadGovernor(tc.num_threads or torch.get_num_threads())
        while self.step < end:
            t0 = time.perf_counter()
            parts = self.train_step()
            step_times.add(time.perf_counter() - t0)
            bar.update(1)
            if governor is not None and self.step % THREAD_CHECK_STEPS == 0:
                governor.update()
            if "skipped" in parts:
                self.skipped += 1
                skipped_in_a_row += 1
                tqdm.write(f"warning: step {self.step}: non-finite loss or gradients; update skipped")
                if skipped_in_a_row >= MAX_SKIPPED:
                    raise TrainingDiverged(
                        f"{self.out}: steps {self.step - MAX_SKIPPED + 1}-{self.step}: non-finite "
                        "loss or gradients at every step; stopped without saving (the last "
                        f"checkpoint in {self.out} is kept)"
                    )
            else:
                skipped_in_a_row = 0
                for k in [k for k in run_avg if k not in parts]:  # a term switched off by its schedule
                    del run_avg[k]
                for k, v in parts.items():
                    run_avg[k] = v if k not in run_avg else 0.9 * run_avg[k] + 0.1 * v
            if run_avg:
                bar.set_postfix(
                    left=step_times.eta(tc.steps - self.step),
                    s_step=f"{step_times.median():.2f}",
                    loss=f"{run_avg['loss']:.1f}",
                    psnr=f"{run_avg['psnr']:.2f}",
                    active=f"{run_avg['active']:.1f}",
                    **({"threads": governor.threads} if governor is not None else {}),
                )
            if self.step % tc.log_every == 0 and run_avg:
                self.log(
                    {
                        "step": self.step,
                        **{k: round(v, 5) for k, v in run_avg.items()},
                        **({"skipped": self.skipped} if self.skipped else {}),
                    }
                )
            if self.step % tc.val_every == 0 or self.step == tc.steps:
                self._check_finite()
                if self.rank == 0 and self.val_dir.is_dir():
                    try:
                        m = self.validate()
                    except BaseException:
                        if not self.distributed:  # the steps since the last checkpoint are not lost
                            self._save(self.out / LAST)
                        raise
                    self.log({"step": self.step, "val": m})
                    tqdm.write(
                        f"step {self.step}: val PSNR {m['psnr']:.2f} dB, FG-ARI {m['fg_ari']:.3f}, "
                        f"mIoU {m['miou']:.3f}, active {m['active_particles']:.1f}"
                    )
                    save_checkpoint(
                        self.out / f"step_{self.step:06d}.pt",
                        self.model,
                        self.step,
                        {"val": m, "train": config_to_dict(self.tc), "provenance": self.provenance_now()},
                    )
                    score = m["psnr"] / 30.0 + (m["fg_ari"] if math.isfinite(m["fg_ari"]) else 0.0)
                    if score > self.best:
                        self.best = score
                        with atomic_path(self.out / "best.pt") as tmp:
                            shutil.copyfile(self.out / f"step_{self.step:06d}.pt", tmp)
                if self.distributed:
                    dist.barrier()
            if self.step % tc.ckpt_every == 0 or self.step == end or stop.get("signum"):
                self._save(self.out / LAST)  # after validation: it holds the best score
            if stop.get("signum"):
                break
        bar.close()
