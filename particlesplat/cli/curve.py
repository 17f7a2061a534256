"""``particlesplat curve``: plot a run's validation curve (PSNR and FG-ARI against step) to a small PNG."""

from __future__ import annotations

import argparse
from pathlib import Path

from particlesplat.core.atomic import atomic_path
from particlesplat.training.curve import plot_curve, read_validation


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run", help="run folder holding metrics.jsonl (from 'particlesplat train')")
    parser.add_argument("--out", required=True, help="PNG to write")
    parser.add_argument("--title", default="", help="text above the plot")


def run(args: argparse.Namespace) -> int:
    path = Path(args.run) / "metrics.jsonl"
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no metrics log (is {args.run} a run folder?)")
    rows = read_validation(path)
    with atomic_path(args.out) as tmp:
        plot_curve(rows, args.title).save(tmp, format="PNG")
    last = f"; last: step {rows[-1][0]}, PSNR {rows[-1][1]:.2f} dB, FG-ARI {rows[-1][2]:.3f}" if rows else ""
    print(f"wrote {args.out}: {len(rows)} validation point(s){last}")
    return 0
