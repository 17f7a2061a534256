"""``particlesplat train``: train a model on a folder of scenes (the trainer: :mod:`particlesplat.training.trainer`).

Torch loads only after the arguments, the recipe and its overrides were checked: a typo is one quick line."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from particlesplat.core.bundled import recipe_path
from particlesplat.core.device import DEVICE_HELP
from particlesplat.core.errors import OptionError
from particlesplat.core.options import parse_key_values
from particlesplat.data.folders import check_file
from particlesplat.model.config import (
    ConfigError,
    ModelConfig,
    TrainConfig,
    load_config,
    stored_model_config,
    stored_train_config,
    with_overrides,
)
from particlesplat.rendering.choice import add_rasterizer_option, apply_rasterizer_option


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--config",
        default=None,
        help="YAML with 'model:' and 'train:' sections (default: the recipe the shipped "
        "architecture is trained with, assets/recipe.yaml, which documents every key; with --resume, the run's "
        "own OUT/config.yaml; with --init, the checkpoint's own model config and its run's train section)",
    )
    parser.add_argument("--data", required=True, help="dataset folder holding train/ and val/ scene folders")
    parser.add_argument(
        "--out", required=True, help="run folder: checkpoints (last.pt, step_*.pt, best.pt), metrics.jsonl, config.yaml"
    )
    parser.add_argument("--resume", action="store_true", help="continue exactly from OUT/last.pt")
    parser.add_argument(
        "--init",
        default=None,
        metavar="CHECKPOINT",
        help="start from this checkpoint's weights (fine-tuning, e.g. assets/robot/model.pt on your own scenes): "
        "every weight whose name and shape the --config model shares is copied, the rest start at random; the "
        "step, optimiser and schedule start afresh, and the run's provenance names the source",
    )
    parser.add_argument("--device", default=None, help=f"{DEVICE_HELP}; under torchrun, one process per device")
    add_rasterizer_option(parser)
    parser.add_argument(
        "--overwrite",
        action="store_true",
        help="train into a non-empty --out that is not resumed (its files are replaced)",
    )
    parser.add_argument(
        "--stop-after",
        type=int,
        default=None,
        help="run at most this many steps (>= 1) in this invocation, checkpoint, and exit (continue with --resume)",
    )
    parser.add_argument(
        "overrides",
        nargs="*",
        metavar="SECTION.KEY=VALUE",
        help="change keys of the recipe, checked as the file's are: a smoke test is 'train.steps=200 "
        "train.val_every=50'; the run's config.yaml records the result",
    )


def init_config(path: Path) -> tuple[ModelConfig, TrainConfig]:
    """``--init`` without ``--config``: the checkpoint's own model config (a fine-tune keeps the architecture of its
    weights) and the train section of the run that wrote it, or the bundled recipe's where it records none."""
    from particlesplat.model import read_checkpoint

    ckpt = read_checkpoint(path)
    cfg = stored_model_config(ckpt["config"], f"{path}: config")
    train = ckpt.get("train")
    if isinstance(train, dict):
        tc = stored_train_config(train, f"{path}: train")
        source = f"{path}"
    else:
        tc, source = load_config(recipe_path())[1], str(recipe_path())
    print(
        f"--init without --config: the model config of {path}, the train section of {source} ({tc.steps} steps; "
        "a --config with the same model section sets a fine-tune's own steps and schedule)",
        file=sys.stderr,
    )
    return cfg, tc


def checkpoint_config(path: Path) -> tuple[ModelConfig, TrainConfig]:
    """The model and train config a run's checkpoint stores (a resume whose config.yaml is gone)."""
    from particlesplat.model import read_checkpoint

    ckpt = read_checkpoint(path)
    cfg = stored_model_config(ckpt["config"], f"{path}: config")
    if not isinstance(ckpt.get("train"), dict):
        raise ConfigError(f"{path}: stores no train section and the run has no config.yaml: give --config")
    return cfg, stored_train_config(ckpt["train"], f"{path}: train")


def run(args: argparse.Namespace) -> int:
    changes = parse_key_values(args.overrides, "train", "train.steps=200")  # before torch: quick errors
    data = Path(args.data)
    if not (data / "train").is_dir():
        raise FileNotFoundError(f"--data {data}: no training split ({data / 'train'})")
    check_file(args.config, "--config")
    check_file(args.init, "--init", shipped=True)
    apply_rasterizer_option(args)
    from particlesplat.core.outputs import guard_outputs

    guard_outputs(
        [],
        [("--config", args.config), ("--data", args.data), ("--init", args.init)],
        [("--out", args.out)] if args.overwrite else [],
    )
    if args.stop_after is not None and args.stop_after < 1:
        raise OptionError(f"--stop-after must be >= 1 step (a run checkpoints when it stops), got {args.stop_after}")
    run_config, last = Path(args.out) / "config.yaml", Path(args.out) / "last.pt"
    source = f"--config {args.config}"
    if args.config is None and args.init is not None:
        cfg, tc = init_config(Path(args.init))
        source = f"--init {args.init}"
    elif args.config is None and args.resume and run_config.is_file():
        cfg, tc = load_config(run_config)  # the run goes on as it was started
        source = str(run_config)
        print(f"--resume without --config: the run's own {run_config}", file=sys.stderr)
    elif args.config is None and args.resume and last.is_file():
        cfg, tc = checkpoint_config(last)  # no config.yaml: the config the checkpoint stores
        source = str(last)
        print(f"--resume without --config and without {run_config}: the config stored in {last}", file=sys.stderr)
    else:
        cfg, tc = load_config(args.config or recipe_path())
        source = f"--config {args.config}" if args.config else f"the recipe {recipe_path()}"
    cfg, tc = with_overrides(cfg, tc, changes)
    if changes:
        print("train: recipe changed by " + ", ".join(f"{k}={v}" for k, v in changes.items()), file=sys.stderr)
        source += " with " + " ".join(f"{k}={v}" for k, v in changes.items())
    import torch

    from particlesplat.core.device import resolve_device
    from particlesplat.training.trainer import Trainer

    device = str(resolve_device(args.device))  # a typo or a missing device is one line before anything is read
    if args.device is None and device != "cpu":
        print(f"train: on {device}, which torch found (--device cpu trains on the CPU)", file=sys.stderr)
    if tc.num_threads > 0:
        from dataclasses import replace

        from particlesplat.core.threads import bounded_threads

        tc = replace(tc, num_threads=bounded_threads(tc.num_threads, "train.num_threads"))
        torch.set_num_threads(tc.num_threads)
    if device.startswith("cuda") and int(os.environ.get("WORLD_SIZE", "1")) > 1:
        device = f"cuda:{int(os.environ.get('LOCAL_RANK', '0'))}"
    init = None if args.init is None else Path(args.init)
    trainer = Trainer(
        cfg, tc, data, Path(args.out), device, args.resume, overwrite=args.overwrite, init=init, config_source=source
    )
    code = trainer.run(args.stop_after)
    if code == 0 and trainer.rank == 0:
        out = Path(args.out)
        best = f", the best validation score's weights in {out / 'best.pt'}" if (out / "best.pt").is_file() else ""
        if trainer.step < tc.steps:
            print(
                f"particlesplat train: stopped at step {trainer.step} of {tc.steps}: {out / 'last.pt'} (continue "
                f"with --resume){best}"
            )
        else:
            print(f"particlesplat train: done, step {trainer.step} of {tc.steps}: {out / 'last.pt'}{best}")
    return code
