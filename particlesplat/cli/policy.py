"""``particlesplat policy collect|train|eval``: record a scripted expert's demonstrations of a robot task, train a
keypose policy on them with one of four inputs, and evaluate it in closed loop (docs/policy-benchmark.md)."""

from __future__ import annotations

import argparse
from pathlib import Path

from particlesplat.policy.options import (
    DEFAULT_TASK,
    INPUT_NAMES,
    SPLITS,
    TASK_NAMES,
    TRAIN_STEPS,
    check_collect_options,
    check_eval_options,
    check_train_options,
)

INPUT_HELP = (
    "particles: the shipped robot model's particles of the two views; images: the RGB-D views through a small "
    "CNN; state: the true objects' boxes, colours and shapes; robot: the robot's state alone (every input has it)"
)


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

    tr = sub.add_parser(
        "train",
        help="train a keypose policy on demonstrations (behaviour cloning)",
        description="Train a keypose policy (one small transformer over tokens) on the successful demonstrations "
        "in DEMOS, with one of four inputs; the same sizes and training budget for every input.",
    )
    tr.add_argument("--task", choices=TASK_NAMES, default=DEFAULT_TASK, help="the demonstrations' task")
    tr.add_argument("--input", choices=INPUT_NAMES, required=True, help=INPUT_HELP)
    tr.add_argument("--demos", type=Path, required=True, help="a folder written by 'policy collect'")
    tr.add_argument("--out", type=Path, required=True, help="the policy file to write (.pt)")
    tr.add_argument("--episodes", type=int, help="learn from the first N successful demonstrations (default: all)")
    tr.add_argument("--steps", type=int, default=TRAIN_STEPS, help="training steps")
    tr.add_argument("--batch", type=int, default=32, help="decisions a step")
    tr.add_argument("--lr", type=float, default=3e-4, help="AdamW's learning rate (cosine to zero)")
    tr.add_argument("--seed", type=int, default=0, help="training seed (>= 0)")
    tr.add_argument(
        "--checkpoint",
        help="particles: the ParticleSplat model that encodes the views (default: the shipped robot model)",
    )
    tr.add_argument(
        "--particles",
        type=Path,
        help="particles: a folder to keep each decision's particle arrays "
        "in (the .npz 'particlesplat encode' writes), read back on the next run",
    )
    tr.add_argument("--quiet", action="store_true", help="no progress bar")

    ev = sub.add_parser(
        "eval",
        help="evaluate a policy in closed loop",
        description="Run a policy in freshly drawn episodes of its task (rollout i is episode i of --seed: the "
        "same episodes for every input) and report its success, from the simulator's state.",
    )
    ev.add_argument("--policy", type=Path, required=True, help="a policy file written by 'policy train'")
    ev.add_argument("--task", choices=TASK_NAMES, help="the task (default: the policy's)")
    ev.add_argument("--rollouts", type=int, default=50, help="rollouts")
    ev.add_argument("--seed", type=int, default=1000, help="evaluation seed; use one the demonstrations did not")
    ev.add_argument(
        "--split", choices=SPLITS, default="train", help="train, or heldout (held-out colours, one more distractor)"
    )
    ev.add_argument("--checkpoint", help="particles: the encoding model (default: the one it was trained with)")
    ev.add_argument("--json", type=Path, help="also write the results (per rollout) as JSON here")
    ev.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    if args.action == "train":
        return _train(args)
    if args.action == "eval":
        return _eval(args)
    check_collect_options(args.task, args.episodes, args.seed, args.split)  # before torch and MuJoCo load
    from particlesplat.policy.collect import collect

    summary = collect(args.out, args.task, args.episodes, args.seed, args.split, progress=not args.quiet)
    line = f"{args.out}: {summary.episodes} episodes, the expert succeeded in {summary.successes}"
    line += f" ({100 * summary.success_rate:.1f} %)"
    if summary.seconds:
        line += f"; recorded {summary.new} now, {sum(summary.seconds) / len(summary.seconds):.2f} s each"
    print(line)
    return 0


def _train(args: argparse.Namespace) -> int:
    check_train_options(args.episodes, args.steps, args.batch, args.seed, args.lr)
    if not args.demos.is_dir():
        raise FileNotFoundError(f"--demos {args.demos}: no such folder")
    from particlesplat.core.outputs import guard_outputs

    guard_outputs([("--out", args.out)], [("--demos", args.demos), ("--checkpoint", args.checkpoint)])
    from tqdm import tqdm

    from particlesplat.policy.learn import TrainSettings
    from particlesplat.policy.runs import train_run

    bars: dict = {}

    def progress(stage: str, done: int, total: int) -> None:
        if args.quiet:
            return
        bar = bars.get(stage)
        if bar is None:
            bar = bars[stage] = tqdm(
                total=total, desc=f"{stage} {args.input}", unit="step" if stage == "train" else "decision"
            )
        bar.update(done - bar.n)

    settings = TrainSettings(steps=args.steps, batch=args.batch, lr=args.lr, seed=args.seed)
    try:
        log = train_run(
            args.task,
            args.input,
            args.demos,
            args.out,
            settings,
            args.episodes,
            args.checkpoint,
            args.particles,
            progress,
        )
    finally:
        for bar in bars.values():
            bar.close()
    print(
        f"{args.out}: a {args.input} policy of {args.task}, {args.steps} steps, final loss {log.losses[-1]:.4f}, "
        f"{log.seconds[-1]:.0f} s"
    )
    return 0


def _eval(args: argparse.Namespace) -> int:
    check_eval_options(args.rollouts, args.seed)
    if not args.policy.is_file():
        raise FileNotFoundError(f"--policy {args.policy}: no such file")
    from particlesplat.core.outputs import guard_outputs

    guard_outputs([("--json", args.json)], [("--policy", args.policy), ("--checkpoint", args.checkpoint)])
    from tqdm import tqdm

    from particlesplat.policy.runs import eval_run, write_json

    bar = None  # started once the policy and its encoder are loaded (a bad file is one line, no bar)
    wins = 0

    def start() -> None:
        nonlocal bar
        bar = tqdm(total=args.rollouts, desc="eval", unit="rollout", disable=args.quiet)

    def progress(i: int, success: bool) -> None:
        nonlocal wins
        wins += success
        assert bar is not None  # eval_run starts before the first rollout
        bar.set_postfix(success=f"{wins}/{i + 1}")
        bar.update(1)

    try:
        result = eval_run(
            args.policy, args.task, args.rollouts, args.seed, args.split, args.checkpoint, progress, start
        )
    finally:
        if bar is not None:
            bar.close()
    seconds = sum(result.wall_seconds) / len(result.wall_seconds)
    decision = sum(result.decision_seconds) / len(result.decision_seconds)
    low, high = result.success_interval
    print(
        f"{args.policy}: {result.input} on {result.task} ({result.split}, seed {result.seed}): success "
        f"{100 * result.success_rate:.1f} % of {len(result.success)} rollouts (95 % interval {100 * low:.0f}-"
        f"{100 * high:.0f} %), {seconds:.1f} s a rollout, "
        f"{1000 * decision:.0f} ms a decision (observed, encoded, acted on)"
    )
    if args.json is not None:
        write_json(args.json, result.to_json())
    return 0
