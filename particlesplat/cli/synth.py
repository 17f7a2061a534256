"""``particlesplat synth``: write a scene dataset (train/ val/ test/ scene folders) of a scene family."""

from __future__ import annotations

import argparse
from pathlib import Path

from particlesplat.core.errors import OptionError
from particlesplat.data.families import DEFAULT_FAMILY, families, family_names, get_family
from particlesplat.data.folders import SPLITS


def add_arguments(parser: argparse.ArgumentParser) -> None:
    kinds = [f"{f.name} ({'the default: ' if f.name == DEFAULT_FAMILY else ''}{f.summary})" for f in families()]
    parser.description = (
        "Generate a scene dataset (docs/dataset.md): OUT/{train,val,test}/scene_NNNNN "
        "folders with RGB, planar 16-bit depth and instance masks for 21 views, of one scene family: "
        f"{', '.join(kinds[:-1])}{' or ' if len(kinds) > 1 else ''}{kinds[-1]}. "
        "The robot family's wide world (--world wide: robosuite's frame, randomised objects, "
        "colours, textures, lights, grippers, arm poses and cameras) also has a held-out split, OUT/heldout, drawn "
        "outside its training ranges. Deterministic for a seed; re-running resumes and skips finished scenes."
    )
    parser.add_argument("--family", choices=family_names(), default=DEFAULT_FAMILY, help="scene family")
    parser.add_argument("out", type=Path, help="output folder (created)")
    parser.add_argument("--train", type=int, default=1000, help="number of training scenes")
    parser.add_argument("--val", type=int, default=32, help="number of validation scenes")
    parser.add_argument("--test", type=int, default=32, help="number of test scenes")
    parser.add_argument(
        "--heldout",
        type=int,
        default=0,
        help="robot, --world wide: number of held-out scenes (outside the "
        "training ranges; they carry ground-truth edits like test scenes)",
    )
    parser.add_argument(
        "--split",
        choices=SPLITS,
        help="write only this split (its count from its option, e.g. --split heldout --heldout 32); the others "
        "are left as they are",
    )
    parser.add_argument("--seed", type=int, default=0, help="dataset seed (>= 0)")
    parser.add_argument("--res", type=int, default=128, help="image width and height in pixels")
    parser.add_argument("--workers", type=int, default=2, help="worker processes (1 = in this process)")
    parser.add_argument(
        "--cameras", choices=("arc", "rlbench"), default="arc", help="robot: 21 views on an arc, or 4 RLBench-style"
    )
    models = [f"{f.name}: {f.model_world}" for f in families() if f.model_world]
    parser.add_argument(
        "--world",
        choices=("narrow", "wide"),
        default=None,
        help="robot: the wide, randomised world in robosuite's frame (robot at -x), which the shipped robot model "
        "was trained on, or the narrow one (robot at +y, Panda gripper, six objects, fixed look; docs/dataset.md); "
        f"default: the world of the family's shipped model ({', '.join(models)}), else narrow",
    )
    parser.add_argument(
        "--arm",
        choices=("home", "still", "random"),
        default="home",
        help="robot, --world narrow: arm pose: home with joint offsets of up to 0.12 rad, exactly home (still; "
        "otherwise the same scenes as home), or a random collision-free pose (the wide world draws its own poses)",
    )


def run(args: argparse.Namespace) -> int:
    counts = {"train": args.train, "val": args.val, "test": args.test, "heldout": args.heldout}
    if args.split is not None:
        counts = {split: (n if split == args.split else 0) for split, n in counts.items()}
    family = get_family(args.family)
    if args.world is None:  # the world the family's shipped model was trained on
        args.world = family.model_world or "narrow"
    if counts["heldout"] and args.world not in family.heldout_worlds:
        worlds = [
            f"the {f.name} family's {w} world (--family {f.name} --world {w})"
            for f in families()
            for w in f.heldout_worlds
        ]
        raise OptionError(f"--heldout: only {' or '.join(worlds) or 'no family'} has one")
    import numpy as np

    # errors follow the one policy (particlesplat.core.errors.run_command): bad input, one line, exit 2
    times = family.generate(args.out, counts, args.seed, args)
    if times:
        print(f"wrote {len(times)} scenes to {args.out}, {np.mean(times):.2f} s per scene per worker")
    else:
        print(f"nothing to do: all {sum(counts.values())} scenes already exist in {args.out}")
    return 0
