"""``particlesplat policy collect``: record a scripted expert's demonstrations of a robot task
(docs/policy-benchmark.md)."""

from __future__ import annotations

import argparse
from pathlib import Path

from particlesplat.policy.options import DEFAULT_TASK, SPLITS, TASK_NAMES, check_collect_options


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "Closed-loop policies in the robot world (docs/policy-benchmark.md): MuJoCo tasks with robosuite's assets, "
        "seen by two fixed RGB-D cameras. Needs the sim extra: pip install -e '.[sim]' && pip install --no-deps "
        "robosuite==1.5.2."
    )
    sub = parser.add_subparsers(dest="action", required=True, metavar="ACTION")
    collect = sub.add_parser(
        "collect",
        help="record the scripted expert's demonstrations of a task",
        description="Record the scripted expert's demonstrations of a task into OUT: one .npz per episode (both "
        "views' RGB-D, cameras, joint angles, gripper, the keypose taken and the objects' states at each decision; "
        "docs/policy-benchmark.md), deterministic for a seed. Running it again resumes: only missing episodes "
        "are recorded. Every episode is kept; its meta says whether the expert succeeded.",
    )
    collect.add_argument(
        "--task",
        choices=TASK_NAMES,
        default=DEFAULT_TASK,
        help="place: pick the object in the goal pad's colour and place it on the pad; stack: stack the small box "
        "on the wide one",
    )
    collect.add_argument("--episodes", type=int, default=100, help="episodes 0..N-1 (those in OUT are kept)")
    collect.add_argument("--seed", type=int, default=0, help="seed (>= 0): episode i is the same for a seed")
    collect.add_argument(
        "--split",
        choices=SPLITS,
        default="train",
        help="train, or heldout: object colours from hue bands training never draws, and one more distractor",
    )
    collect.add_argument("--out", type=Path, required=True, help="output folder (created; resumed when it exists)")
    collect.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    check_collect_options(args.task, args.episodes, args.seed, args.split)  # before torch and MuJoCo load
    from particlesplat.policy.collect import collect

    summary = collect(args.out, args.task, args.episodes, args.seed, args.split, progress=not args.quiet)
    line = f"{args.out}: {summary.episodes} episodes, the expert succeeded in {summary.successes}"
    line += f" ({100 * summary.success_rate:.1f} %)"
    if summary.seconds:
        line += f"; recorded {summary.new} now, {sum(summary.seconds) / len(summary.seconds):.2f} s each"
    print(line)
    return 0
