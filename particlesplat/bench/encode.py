"""``particlesplat bench encode``: encode + decode time of one or more checkpoints on the same scenes.

Checkpoints take turns round by round (each round encodes and decodes every scene once with each checkpoint,
in order), so a machine whose speed drifts (a shared host, another job) slows them alike; the report gives
each checkpoint's median round and its ratio to the first checkpoint's. The scenes and context views are
those ``particlesplat eval`` uses (the same seed), the time is the encode of the context views and the decode
of all Gaussians, as in ``eval``.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path
from typing import Any

import torch

from particlesplat.bench.render import machine_line
from particlesplat.core.atomic import atomic_write
from particlesplat.core.device import DEVICE_HELP, resolve_device
from particlesplat.core.errors import OptionError
from particlesplat.data.families import checkpoint_help
from particlesplat.data.scene_meta import default_checkpoint, scene_pose


def time_rounds(models: list, items: list[dict], rounds: int) -> list[list[tuple[float, float]]]:
    """Per model, per round: mean (encode, decode) milliseconds over ``items`` (SceneDataset items with
    ``poses``: per model, the scene's pose or None); on a GPU each phase ends when its work is done."""
    from particlesplat.analysis.evaluate import _cameras, _ms

    out: list[list[tuple[float, float]]] = [[] for _ in models]
    for _ in range(rounds):
        for k, model in enumerate(models):
            device = next(model.parameters()).device
            enc = dec = 0.0
            for it in items:
                cams = _cameras(it["context_K"], it["context_c2w"], model.config.resolution)
                t0 = time.perf_counter()
                particles = model.encode(it["context_rgb"], it["context_depth"], cams, it["poses"][k])
                enc += _ms(t0, device)
                t0 = time.perf_counter()
                model.decode(particles)
                dec += _ms(t0, device)
            out[k].append((enc / len(items), dec / len(items)))
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="particlesplat bench encode", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--checkpoint", nargs="+", help=f"one or more: {checkpoint_help()}")
    parser.add_argument("--data", required=True, help="a folder of scene folders, e.g. data/robot/test")
    parser.add_argument("--scenes", type=int, default=16, help="scenes per round, the first of the folder (default 16)")
    parser.add_argument("--rounds", type=int, default=3, help="rounds; the median round counts (default 3)")
    parser.add_argument("--context", type=int, choices=(1, 2), default=2, help="context views (default 2)")
    parser.add_argument("--threads", type=int, default=0, help="torch CPU threads (0: torch's default)")
    parser.add_argument("--device", default=None, help=DEVICE_HELP)
    parser.add_argument("--json", help="also write the rows to this JSON file")
    args = parser.parse_args(argv)
    from particlesplat.core.outputs import guard_outputs

    paths = [Path(p) for p in (args.checkpoint or [default_checkpoint(Path(args.data))])]  # the default is read too
    guard_outputs([("--json", args.json)], [("--data", args.data), *[("--checkpoint", p) for p in paths]])
    if args.scenes < 1 or args.rounds < 1:
        raise OptionError(f"--scenes and --rounds must be >= 1, got {args.scenes} and {args.rounds}")
    if args.threads < 0:
        raise OptionError(f"--threads must be >= 0, got {args.threads}")
    if args.threads:
        from particlesplat.core.threads import bounded_threads

        torch.set_num_threads(bounded_threads(args.threads, "--threads"))
    from particlesplat.data import SceneDataset
    from particlesplat.model.io import load_model

    device = resolve_device(args.device)
    models = [load_model(p, device=device) for p in paths]
    sizes = {m.config.resolution for m in models}
    if len(sizes) > 1:
        raise OptionError(f"--checkpoint: the models need one image size, got {sorted(sizes)}")
    ds = SceneDataset(
        args.data,
        resolution=sizes.pop(),
        mode="multi" if args.context == 2 else "single",
        deterministic=True,
        seed=0,
        progress=1.0,
    )
    items: list[dict[str, Any]] = [ds[i] for i in range(min(args.scenes, len(ds)))]
    for i, it in enumerate(items):  # each model's pose of each scene (bg_static_pose), read before the timing
        it["poses"] = [
            scene_pose(ds.scenes[i], m.config.bg_static_pose, m.config.bg_static_pose_dims, m.input_ranges)
            for m in models
        ]
    time_rounds(models, items[:1], 1)  # warm-up: first-call allocations and kernels
    times = time_rounds(models, items, args.rounds)
    print(
        f"{machine_line()}; {device}; {len(items)} scenes of {args.data}, {args.context} context view(s), "
        f"{args.rounds} rounds"
    )
    rows: list[dict[str, Any]] = []
    for path, per_round in zip(paths, times, strict=True):
        totals = [e + d for e, d in per_round]
        i = totals.index(statistics.median_low(totals))
        rows.append(
            {
                "checkpoint": str(path),
                "encode_ms": per_round[i][0],
                "decode_ms": per_round[i][1],
                "total_ms": totals[i],
                "rounds_ms": totals,
            }
        )
    first = rows[0]["total_ms"]
    print(f"{'checkpoint':<48} {'encode':>8} {'decode':>8} {'total':>8} {'ratio':>6}  rounds (ms)")
    for r in rows:
        rounds = ", ".join(f"{t:.0f}" for t in r["rounds_ms"])
        r["ratio"] = r["total_ms"] / first
        print(
            f"{r['checkpoint'][-48:]:<48} {r['encode_ms']:8.1f} {r['decode_ms']:8.1f} {r['total_ms']:8.1f} "
            f"{r['ratio']:6.2f}  {rounds}"
        )
    if args.json:
        with atomic_write(args.json, "w") as f:
            json.dump({"machine": machine_line(), "data": str(args.data), "rows": rows}, f, indent=2)
        print(f"wrote {args.json}")
    return 0
