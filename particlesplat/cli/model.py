"""``particlesplat model``: what a checkpoint is (``info``), and a copy of it with inference keys changed
(``set``), e.g. a cheaper refinement pass."""

from __future__ import annotations

import argparse

from particlesplat.core.choices import INFERENCE_KEYS
from particlesplat.core.options import parse_key_values


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from particlesplat.cli.main import HelpFormatter

    sub = parser.add_subparsers(dest="action", required=True, metavar="{info,set}")
    info = sub.add_parser(
        "info",
        help="describe a checkpoint: its family, resolution, particles, training (steps, hours, data), the "
        "validation scores it records, inference keys and provenance",
        formatter_class=HelpFormatter,
    )
    info.add_argument("checkpoint", help="a .pt checkpoint (from 'particlesplat train' or assets/)")
    keys = "; ".join(f"{k}: {v}" for k, v in INFERENCE_KEYS.items())
    change = sub.add_parser(
        "set",
        help="write a copy of a checkpoint with inference keys changed (no retraining)",
        description=f"Write a copy of CHECKPOINT with model keys changed. Keys (a key's flat name, e.g. "
        f"refine_steps, works too): {keys}.",
        formatter_class=HelpFormatter,
    )
    change.add_argument("checkpoint", help="the checkpoint to copy (left unchanged)")
    change.add_argument("changes", nargs="+", metavar="KEY=VALUE", help="e.g. refine.scale=0.5 refine.keep=128")
    change.add_argument("--out", required=True, help="the .pt to write (not the input)")
    change.add_argument("--note", default="", help="why, recorded in the copy's provenance")


def run(args: argparse.Namespace) -> int:
    if args.action == "set":
        from particlesplat.model.config import model_value
        from particlesplat.model.derive import write_derived

        changes = parse_key_values(args.changes, "model set", "refine.scale=0.5")
        cfg = write_derived(args.checkpoint, args.out, changes, args.note)
        print(f"wrote {args.out}: " + ", ".join(f"{k} {model_value(cfg, k)}" for k in INFERENCE_KEYS))
        return 0
    from particlesplat.model.io import model_from_checkpoint, read_checkpoint, shipped_model_name
    from particlesplat.model.summary import summarize

    ckpt = read_checkpoint(args.checkpoint)
    model = model_from_checkpoint(ckpt, args.checkpoint)
    weights = sum(v.numel() for v in model.state_dict().values())
    refine = "off" if model.refiner is None else ("on" if model.refine_enabled else "not yet trained (off)")
    print("\n".join(summarize(ckpt, model.config, weights, refine, shipped_model_name(args.checkpoint))))
    return 0
