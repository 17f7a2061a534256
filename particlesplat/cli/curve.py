"""``particlesplat curve``: plot the validation curves of one to three runs (PSNR and FG-ARI against step) to a PNG."""

from __future__ import annotations

import argparse
from pathlib import Path

from particlesplat.core.atomic import atomic_path
from particlesplat.core.errors import OptionError
from particlesplat.training.curve import RUN_COLOURS, plot_curves, read_validation


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
    runs = []
    for folder in args.run:
        path = Path(folder) / "metrics.jsonl"
        if not path.is_file():
            raise FileNotFoundError(f"{path}: no metrics log (is {folder} a run folder?)")
        runs.append((Path(folder).name if len(args.run) > 1 else "", read_validation(path)))
    with atomic_path(args.out) as tmp:
        plot_curves(runs, args.title).save(tmp, format="PNG")
    for folder, (_, rows) in zip(args.run, runs, strict=True):
        last = f"; last: step {rows[-1][0]}, PSNR {rows[-1][1]:.2f} dB, FG-ARI {rows[-1][2]:.3f}" if rows else ""
        print(f"{folder}: {len(rows)} validation point(s){last}")
    print(f"wrote {args.out}")
    return 0
