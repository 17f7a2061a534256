"""``particlesplat eval``: metrics of a model on a folder of scenes (the work: :mod:`particlesplat.analysis`)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from particlesplat.core.atomic import check_writable
from particlesplat.core.choices import (
    DEFAULT_FIT,
    EVAL_PROTOCOLS,
    FITTED,
    PAPER_CONTEXT_FRAMES,
    PAPER_TARGET_FRAMES,
    check_protocol,
)
from particlesplat.core.device import DEVICE_HELP
from particlesplat.core.errors import OptionError
from particlesplat.data.families import checkpoint_help
from particlesplat.data.folders import (
    DEFAULT_EVAL_SPLITS,
    EVAL_SPLITS,
    check_file,
    check_split_folder,
    choose_splits,
    dataset_splits,
    skipped_splits_note,
)
from particlesplat.rendering.choice import add_rasterizer_option, apply_rasterizer_option

MAX_FIT_LR = 10.0  # --fit-lr: Adam's step on the latents; past this the fit diverges at once


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--checkpoint",
        default=None,
        help=checkpoint_help(),
    )
    parser.add_argument(
        "--data",
        required=True,
        help="a folder of scene folders (e.g. data/tabletop/test), or a dataset folder of split folders (e.g. "
        "data/robot-wide): then each split --splits names in turn, one table row a split",
    )
    parser.add_argument(
        "--splits",
        default=None,
        help=f"with a dataset folder: the comma-separated splits to evaluate, of {','.join(EVAL_SPLITS)} (default: "
        f"those of {','.join(DEFAULT_EVAL_SPLITS)} it has; a line names the others and why they are left out)",
    )
    parser.add_argument("--context", type=int, choices=(1, 2), default=2, help="number of context views")
    parser.add_argument(
        "--protocol",
        choices=EVAL_PROTOCOLS,
        default="sampled",
        help="which views are encoded and scored: sampled (the validation sampler's: two context views 5-20 frames "
        "apart, four targets between them; with --context 1 the front frame and two targets), paper (the paper's: "
        f"context frames {' and '.join(map(str, PAPER_CONTEXT_FRAMES))}, targets "
        f"{', '.join(map(str, PAPER_TARGET_FRAMES))}; scenes need 15 frames), inputs (the context views redrawn at "
        "their own cameras: how well the model redraws what it was given)",
    )
    parser.add_argument("--no-depth", action="store_true", help="encode the context views without depth")
    parser.add_argument(
        "--json",
        default=None,
        help='write per-scene and mean metrics to this JSON file (a dataset folder: one entry a split, under "splits")',
    )
    parser.add_argument(
        "--figures",
        default=None,
        help="write PNG grids of a few scenes to this folder (a dataset folder: a folder per split, DIR/<split>)",
    )
    parser.add_argument("--num-figures", type=int, default=4, help="how many scenes get a figure")
    parser.add_argument("--limit", type=int, default=None, help="evaluate only the first N scenes (of each split)")
    parser.add_argument(
        "--prune",
        action="store_true",
        help="also report PSNR, FG-ARI, Gaussian count and render time at several z_t/opacity thresholds and with "
        "each particle's most opaque 1/2, 1/4, 1/8, 1/16 of its Gaussians",
    )
    parser.add_argument(
        "--fit-steps",
        type=int,
        default=0,
        help="after encoding, fit the particle latents to the context views for N Adam steps "
        "(a quality mode: seconds a scene; 0 = off)",
    )
    parser.add_argument("--fit-lr", type=float, default=0.02, help="learning rate of --fit-steps")
    parser.add_argument(
        "--fit-latents",
        default=",".join(DEFAULT_FIT),
        help=f"comma-separated latents --fit-steps moves, of {','.join(FITTED)} (default: "
        f"{','.join(DEFAULT_FIT)}, which keeps the particles in place)",
    )
    parser.add_argument(
        "--z-t-threshold",
        type=float,
        default=None,
        help="draw the particles with z_t at or above this (default: the model's background.mask_threshold, "
        "as the viewer and particlesplat render draw them; 0 = every particle)",
    )
    parser.add_argument(
        "--turn",
        type=float,
        default=0.0,
        metavar="DEG",
        help="turn every scene's world frame by DEG degrees about z first (cameras, robot base and object centres; "
        "images unchanged): a model that reads its workspace from the views scores the same (default: 0)",
    )
    parser.add_argument("--device", default=None, help=DEVICE_HELP)
    add_rasterizer_option(parser)


def run(args: argparse.Namespace) -> int:
    latents = tuple(k.strip() for k in args.fit_latents.split(","))
    if args.fit_steps < 0 or not args.fit_lr > 0 or not set(latents) <= set(FITTED):
        raise OptionError(
            f"--fit-steps must be >= 0, --fit-lr > 0 and --fit-latents some of {','.join(FITTED)}; got "
            f"{args.fit_steps}, {args.fit_lr:g}, {','.join(latents)[:80]}"
        )
    check_protocol(args.protocol, args.context)
    from particlesplat.core.outputs import guard_outputs

    inputs = [("--checkpoint", args.checkpoint), ("--data", args.data)]
    guard_outputs([("--json", args.json), ("--figures", args.figures)], inputs)
    from particlesplat.core.limits import check_option_range

    check_option_range(args.fit_lr, "--fit-lr", 0.0, MAX_FIT_LR, low_open=True)
    check_option_range(args.z_t_threshold, "--z-t-threshold", 0.0, 1.0)  # z_t is a probability
    check_option_range(args.turn, "--turn", -360.0, 360.0)
    if args.json:
        check_writable(args.json)  # before the work, not after it
    figures = Path(args.figures) if args.figures else None
    if figures and args.num_figures > 0:
        check_writable(figures / "figure.png")
    splits = _splits(args)  # before torch loads: a typo is one quick line
    # a dataset folder's figures go to a folder per split, DIR/<split>; a split folder's to DIR itself
    figure_dirs = {s: figures / s for s in splits} if figures else {}
    guard_outputs([("--figures", d) for d in figure_dirs.values()], inputs)
    if args.num_figures > 0:
        for folder in figure_dirs.values():
            check_writable(folder / "figure.png")
    check_file(args.checkpoint, "--checkpoint", shipped=True)
    apply_rasterizer_option(args)
    from particlesplat.analysis.eval_summary import detail_lines, split_table, summary_line
    from particlesplat.analysis.evaluate import evaluate_dataset, json_safe
    from particlesplat.core.atomic import atomic_write
    from particlesplat.core.device import resolve_device
    from particlesplat.data.scene_meta import default_checkpoint
    from particlesplat.model import load_model, read_checkpoint
    from particlesplat.model.provenance import describe

    device = resolve_device(args.device)
    path = args.checkpoint or default_checkpoint(args.data)  # the shipped model of the data's family
    if not args.checkpoint:  # the shipped model it chose is an input too
        guard_outputs([("--json", args.json), ("--figures", args.figures)], [("the shipped model", str(path))])
    model = load_model(path, device=device)
    ckpt = read_checkpoint(path)
    print(f"{path}: step {ckpt['step']}; {describe(ckpt.get('provenance'))}")

    from particlesplat.rendering.budget import render_budget

    def evaluate(data: str | Path, figure_dir: Path | None) -> dict:
        with render_budget(f"{path} ({model.config.render_keys()})"):  # every render pass priced before it runs
            return evaluate_dataset(
                model,
                data,
                context=args.context,
                limit=args.limit,
                figures=figure_dir,
                num_figures=args.num_figures,
                prune=args.prune,
                use_depth=not args.no_depth,
                fit_steps=args.fit_steps,
                fit_lr=args.fit_lr,
                fit_latents=latents,
                z_t_threshold=args.z_t_threshold,
                turn=args.turn,
                protocol=args.protocol,
            )

    fit = bool(args.fit_steps)
    if not splits:  # a split folder
        out = evaluate(args.data, figures)
        print(summary_line(out, args.context, fit))
        for line in detail_lines(out):
            print(line)
    else:  # a dataset folder: its splits one after the other, the same model and options
        outs = {s: evaluate(Path(args.data) / s, figure_dirs.get(s)) for s in splits}
        print(
            f"{args.data}: {args.context} context view(s), protocol {args.protocol}, the mean over each split's scenes"
        )
        note = None if args.splits else skipped_splits_note(args.data, dataset_splits(args.data), splits)
        if note:
            print(note)
        for line in split_table(outs, fit):
            print(line)
        for split, res in outs.items():
            lines = detail_lines(res)
            if lines:
                print(f"{split}:")
                for line in lines:
                    print("  " + line)
        out = {
            "data": str(args.data),
            "context": args.context,
            "depth": not args.no_depth,
            "protocol": args.protocol,
            "splits": outs,
        }
    if args.json:
        with atomic_write(args.json, "w") as f:
            json.dump(json_safe(out), f, indent=2, allow_nan=False)
    return 0


def _splits(args: argparse.Namespace) -> list[str]:
    """The splits of a dataset folder ``--data`` to evaluate (:func:`choose_splits`); [] for a split folder.
    One-line errors for a path that is neither, a split that is not there, or --splits with a split folder."""
    have = dataset_splits(args.data)
    if have:
        return choose_splits(args.data, have, args.splits, "--splits")
    check_split_folder(args.data, "--data")
    if args.splits is not None:
        raise OptionError(
            f"--splits: --data {args.data} is a split folder (it holds scene folders); --splits chooses among a "
            "dataset folder's splits"
        )
    return []
