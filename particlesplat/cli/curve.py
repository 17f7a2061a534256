"""``particlesplat curve``: plot the validation curves of one to three runs (PSNR and FG-ARI against step) to a PNG."""

from __future__ import annotations

import argparse
from pathlib import Path

from particlesplat.core.atomic import atomic_path
from particlesplat.core.errors import OptionError
from particlesplat.training.curve import RUN_COLOURS, plot_curves, read_curves


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "run",
        nargs="+",
        help=f"run folder(s) holding metrics.jsonl (from 'particlesplat train'); up to {len(RUN_COLOURS)} on one plot",
    )
    parser.add_argument("--out", required=True, help="PNG to write")
    parser.add_argument("--title", default="", help="text above the plot")


def run(args: argparse.Namespace) -> int:
    if len(args.run) > len(RUN_COLOURS):
        raise OptionError(f"curve: at most {len(RUN_COLOURS)} runs on one plot, got {len(args.run)}")
    from particlesplat.core.outputs import guard_outputs

    guard_outputs([("--out", args.out)], [("RUN", Path(folder) / "metrics.jsonl") for folder in args.run])
    runs, training, counts = [], [], []
    for folder in args.run:
        path = Path(folder) / "metrics.jsonl"
        if not path.is_file():
            raise FileNotFoundError(f"{path}: no metrics log (is {folder} a run folder?)")
        rows, losses, logged = read_curves(path)
        runs.append((Path(folder).name if len(args.run) > 1 else "", rows))
        training.append(losses)
        counts.append(logged)
    with atomic_path(args.out) as tmp:
        plot_curves(runs, args.title, training).save(tmp, format="PNG")
    for folder, (_, rows), losses, logged in zip(args.run, runs, training, counts, strict=True):
        loss = f"; training loss to step {losses[-1][0]}: {_records(logged, Path(folder))}" if losses else ""
        if rows:
            last = f"; last: step {rows[-1][0]}, PSNR {rows[-1][1]:.2f} dB, FG-ARI {rows[-1][2]:.3f}"
            print(f"{folder}: {len(rows)} validation point(s){last}{loss}")
        else:
            print(f"{folder}: no validation yet ({_first_validation(Path(folder))}){loss}")
    print(f"wrote {args.out}")
    return 0


def _records(logged: int, run: Path) -> str:
    """What the log's ``logged`` training records are: a running mean every ``train.log_every`` steps (from the run's
    config.yaml, where readable), not one a step."""
    count = f"{logged} record{'s' if logged != 1 else ''}"
    from particlesplat.model.config import load_config

    try:
        every = load_config(run / "config.yaml")[1].log_every
    except (OSError, ValueError):
        return f"{count} of the running mean"
    return f"{count}, the running mean logged every {every} step{'s' if every != 1 else ''}"


def _first_validation(run: Path) -> str:
    """When the run's first validation comes, from its config.yaml (``train.val_every``), for the message."""
    from particlesplat.model.config import load_config

    try:
        every = load_config(run / "config.yaml")[1].val_every
    except (OSError, ValueError):
        return "the first comes at the recipe's train.val_every"
    return f"the first comes at step {every}, train.val_every of {run / 'config.yaml'}"
