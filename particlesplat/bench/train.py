"""``particlesplat bench train``: the cost of a training step of a recipe, by phase and thread count.

Each thread count runs in a fresh subprocess (the thread count of a process is set once). A case builds the
trainer of ``--config`` on ``--data`` in a temporary folder, from random initialisation or, with ``--run``,
from a copy of that run's ``last.pt`` (its weights, optimiser and step: steps grow dearer as training grows
the Gaussians, and a run that has begun its refinement pays for it). It runs ``--warmup`` steps, then times
``--steps`` steps: the median wall seconds of each phase (data: a batch, with scenes read from disk the first
time; forward: the model and the losses' renders; backward; update: the optimiser) and the process's CPU
seconds a step. The run folder is only read.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import torch

from particlesplat.bench.render import machine_line
from particlesplat.core.device import DEVICE_HELP, resolve_device
from particlesplat.core.errors import OptionError, is_user_error, one_line, run_command
from particlesplat.rendering.choice import rasterizer_list

PHASES = ("data", "forward", "backward", "update")


def run_case(
    config: Path, data: Path, run: Path | None, steps: int, warmup: int, threads: int, device: str, rasterizer: str
) -> dict:
    """Time ``steps`` training steps after ``warmup`` in this process (called in a subprocess by :func:`main`)."""
    from particlesplat.model import load_config
    from particlesplat.rendering.choice import resolve_rasterizer, set_default_rasterizer
    from particlesplat.training.trainer import Trainer

    torch.set_num_threads(threads)
    set_default_rasterizer(rasterizer)
    cfg, tc = load_config(config)
    with tempfile.TemporaryDirectory(prefix="particlesplat-bench-train-") as tmp:
        out = Path(tmp) / "run"
        if run is not None:
            out.mkdir()
            shutil.copyfile(run / "last.pt", out / "last.pt")
        try:
            trainer = Trainer(cfg, tc, data, out, device, resume=run is not None)
        except Exception as e:  # the temporary copy is the user's --run: name that, not the copy
            if not is_user_error(e) or run is None:
                raise
            raise OptionError(one_line(e).replace(str(out), f"--run {run}")) from None
        start = trainer.step
        try:
            for _ in range(warmup):
                trainer.train_step()
            rows: list[dict[str, float]] = []
            for _ in range(steps):
                timings: dict[str, float] = {}
                cpu0, t0 = time.process_time(), time.perf_counter()
                trainer.train_step(timings)
                timings["step"] = time.perf_counter() - t0
                timings["cpu"] = time.process_time() - cpu0
                rows.append(timings)
        finally:
            trainer.lock.release()
    median = {k: statistics.median(r.get(k, 0.0) for r in rows) for k in (*PHASES, "step", "cpu")}
    return {
        "threads": threads,
        "rasterizer": resolve_rasterizer(rasterizer, torch.device(device)),
        "start_step": start,
        "recipe_steps": tc.steps,
        "batch_size": tc.batch_size,
        "resolution": cfg.resolution,
        **{f"{k}_s": v for k, v in median.items()},
    }


def _threads(text: str) -> list[int]:
    try:
        values = [int(t) for t in text.split(",") if t.strip()]
    except ValueError:
        raise OptionError(f"--threads: a comma-separated list of thread counts, got {text!r}") from None
    if not values or min(values) < 1:
        raise OptionError(f"--threads: thread counts must be >= 1, got {text!r}")
    from particlesplat.core.threads import bounded_threads

    return list(dict.fromkeys(bounded_threads(v, "--threads") for v in values))


def check_arguments(args: argparse.Namespace) -> tuple[Path, Path, Path | None]:
    """The config, data and run folder the options name, checked before any case starts (OptionError)."""
    run = Path(args.run) if args.run else None
    if run is not None and not (run / "last.pt").is_file():
        raise OptionError(f"--run {run}: no last.pt (a run folder written by 'particlesplat train')")
    if args.config:
        config = Path(args.config)
    elif run is not None:
        config = run / "config.yaml"
    else:
        from particlesplat.core.bundled import recipe_path

        config = recipe_path()
    if not config.is_file():
        raise OptionError(f"--config {config}: no such file")
    data = Path(args.data)
    if not (data / "train").is_dir():
        raise OptionError(f"--data {data}: no train/ folder (a dataset written by 'particlesplat synth')")
    from particlesplat.core.outputs import guard_outputs

    guard_outputs([("--json", args.json)], [("--data", data), ("--config", config), ("--run", run)])
    if run is not None:  # read here, so that a bad checkpoint is one line naming --run, before any case runs
        from particlesplat.model import read_checkpoint

        read_checkpoint(run / "last.pt")
    if args.steps < 1 or args.warmup < 0:
        raise OptionError(f"--steps must be >= 1 and --warmup >= 0, got {args.steps} and {args.warmup}")
    return config, data, run


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="particlesplat bench train", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--data", required=True, help="dataset folder holding train/ (the recipe's data)")
    parser.add_argument(
        "--config", help="recipe YAML (default: the --run's config.yaml, else the shipped recipe assets/recipe.yaml)"
    )
    parser.add_argument("--run", help="start from a copy of this run folder's last.pt (default: random initialisation)")
    parser.add_argument("--steps", type=int, default=10, help="timed steps per case (median)")
    parser.add_argument("--warmup", type=int, default=2, help="untimed steps first")
    parser.add_argument("--threads", default="1,2", help="comma-separated torch thread counts, one case each")
    parser.add_argument("--device", default=None, help=DEVICE_HELP)
    parser.add_argument(
        "--rasterizer",
        default="auto",
        help="comma-separated rasterizers to compare, one case each, in turns (torch, fused, auto; default: auto)",
    )
    parser.add_argument("--json", help="also write the rows to this JSON file")
    parser.add_argument("--case", type=int, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    config, data, run = check_arguments(args)
    device = str(resolve_device(args.device))
    rasterizers = rasterizer_list(args.rasterizer)
    if args.case:  # one case, in its own process: a user error is one line on stderr, exit 2

        def case() -> int:
            print(json.dumps(run_case(config, data, run, args.steps, args.warmup, args.case, device, rasterizers[0])))
            return 0

        return run_command("particlesplat bench train", case)
    threads = _threads(args.threads)
    print(machine_line())
    print(f"OpenMP wait policy: {os.environ.get('OMP_WAIT_POLICY') or 'the runtime default (spin, then sleep)'}")
    print(f"recipe {config}, data {data}, {'from ' + str(run / 'last.pt') if run else 'random initialisation'}")
    header = (
        "| threads | rasterizer | s/step | data | forward | backward | update | CPU s/step | steps/s | "
        "recipe hours at this rate |"
    )
    print(header)
    print("|---" * (header.count("|") - 1) + "|")
    rows = []
    for n, rasterizer in [(n, r) for n in threads for r in rasterizers]:
        cmd = [sys.executable, "-m", "particlesplat.bench.train", "--case", str(n), "--data", str(data)]
        cmd += ["--config", str(config), "--steps", str(args.steps), "--warmup", str(args.warmup)]
        cmd += ["--device", device, "--rasterizer", rasterizer] + (["--run", str(run)] if run else [])
        proc = subprocess.run(cmd, capture_output=True, text=True)
        if proc.returncode != 0:  # a user error is its one line; a bug keeps its traceback
            lines = proc.stderr.strip().splitlines() or ["(no message)"]
            text = lines[-1] if proc.returncode == 2 else proc.stderr.strip()
            print(
                f"particlesplat bench train: case threads={n} rasterizer={rasterizer} failed: {text}", file=sys.stderr
            )
            return proc.returncode if proc.returncode == 2 else 1
        row = json.loads(proc.stdout.strip().splitlines()[-1])  # checked: our own child process's last line
        rows.append(row)
        step = row["step_s"]
        left = (row["recipe_steps"] - row["start_step"]) * step / 3600
        print(
            f"| {n} | {row['rasterizer']} | {step:.3f} | "
            + " | ".join(f"{row[p + '_s']:.3f}" for p in PHASES)
            + f" | {row['cpu_s']:.2f} | "
            f"{1 / step:.2f} | {row['recipe_steps'] * step / 3600:.1f} (steps {row['start_step']}-"
            f"{row['recipe_steps']}: {left:.1f}) |",
            flush=True,
        )
    print(
        f"(step {rows[0]['start_step']}, batch {rows[0]['batch_size']}, {rows[0]['resolution']} px; the data phase "
        "reads each scene from disk the first time, a long run from its scene cache)"
    )
    if args.json:
        from particlesplat.core.atomic import atomic_write

        with atomic_write(args.json, "w") as f:
            json.dump({"machine": machine_line(), "config": str(config), "rows": rows}, f, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
