"""``particlesplat synth``: write a scene dataset (train/ val/ test/ scene folders) of a scene family."""

from __future__ import annotations

import argparse
from pathlib import Path

from particlesplat.core.errors import OptionError
from particlesplat.data.folders import SPLITS


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "Generate a scene dataset (docs/dataset.md): OUT/{train,val,test}/scene_NNNNN "
        "folders with RGB, planar 16-bit depth and instance masks for 21 views, of the tabletop family "
        "(the default) or the robot-workspace family (MuJoCo + robosuite's assets; test scenes carry "
        "ground-truth edits). The robot family's wide world (--world wide: robosuite's frame, randomised objects, "
        "colours, textures, lights, grippers, arm poses and cameras) also has a held-out split, OUT/heldout, drawn "
        "outside its training ranges. Deterministic for a seed; re-running resumes and skips finished scenes."
    )
    parser.add_argument("--family", choices=("tabletop", "robot"), default="tabletop", help="scene family")
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
    parser.add_argument(
        "--world",
        choices=("narrow", "wide"),
        default="narrow",
        help="robot: the narrow world the shipped robot model was trained on (robot at +y, Panda gripper, six "
        "objects, fixed look), or the wide, randomised one in robosuite's frame (robot at -x; docs/dataset.md)",
    )
    parser.add_argument(
        "--arm",
        choices=("home", "still", "random"),
        default="home",
        help="robot: arm pose: home with joint offsets of up to 0.12 rad, exactly home (still; otherwise the same "
        "scenes as home), or a random collision-free pose (the wide world draws its own poses)",
    )


def run(args: argparse.Namespace) -> int:
    counts = {"train": args.train, "val": args.val, "test": args.test, "heldout": args.heldout}
    if args.split is not None:
        counts = {split: (n if split == args.split else 0) for split, n in counts.items()}
    if counts["heldout"] and (args.family != "robot" or args.world != "wide"):
        raise OptionError("--heldout: only the robot family's wide world (--family robot --world wide) has one")
    import numpy as np

    from particlesplat.data.synth import generate

    # errors follow the one policy (particlesplat.core.errors.run_command): bad input, one line, exit 2
    if args.family == "robot":
        from particlesplat.data.families.robot import RobotSceneConfig
        from particlesplat.data.families.robot_synth import generate as generate_robot

        config = RobotSceneConfig(args.res, args.res, cameras=args.cameras, arm=args.arm, world=args.world)
        times = [t["total"] for t in generate_robot(args.out, counts, args.seed, config, args.workers)]
    else:
        counts.pop("heldout")
        times = generate(args.out, counts, args.seed, args.res, args.workers)
    if times:
        print(f"wrote {len(times)} scenes to {args.out}, {np.mean(times):.2f} s per scene per worker")
    else:
        print(f"nothing to do: all {sum(counts.values())} scenes already exist in {args.out}")
    return 0
