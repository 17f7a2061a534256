"""``particlesplat bench render``: speed against error of the tiled renderer.

Each case runs in a fresh subprocess so that its peak resident memory is its own. For every
N and image size: forward ms, forward+backward ms, peak memory, max abs error against a float64
dense brute force (where it fits), and the same timings of the naive dense all-pairs renderer
(where it fits) with the speed ratio.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import statistics
import subprocess
import sys
import time

import torch

from particlesplat.core.camera import Camera
from particlesplat.core.gaussians import Gaussians
from particlesplat.core.machine import cpu_model
from particlesplat.rendering.api import render
from particlesplat.rendering.choice import rasterizer_list
from particlesplat.rendering.dense import render_dense
from particlesplat.rendering.measured import timing_scene as bench_scene

DENSE_MAX_PAIRS = 5e7  # pixels × Gaussians above which the dense fwd+bwd does not fit (~1 KB per pair)
REFERENCE_MAX_PAIRS = 1e9  # the float64 brute force runs in pixel chunks; above this it takes minutes


def _time(fn, repeats: int) -> float:
    fn()  # warm-up (twice: first calls initialise lazily)
    fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return 1000.0 * statistics.median(times)


def _fwd_bwd(renderer, g: Gaussians, cam: Camera):
    means, quats, scales, opacities, sh = (
        t.detach().requires_grad_() for t in (g.means, g.quats, g.scales, g.opacities, g.sh)
    )
    gg = Gaussians(means, quats, scales, opacities, sh, g.owner)

    def step():
        out = renderer(gg, cam)
        rgb, alpha, depth = (out.rgb, out.alpha, out.depth) if hasattr(out, "rgb") else out
        (rgb.sum() + alpha.sum() + depth.sum()).backward()

    return step


def run_case(n: int, size: int, repeats: int, rasterizer: str = "auto") -> dict:
    """Measure one case in this process (called in a subprocess by :func:`main`)."""
    from particlesplat.rendering.choice import resolve_rasterizer, set_default_rasterizer

    set_default_rasterizer(rasterizer)
    g, cam = bench_scene(n, size)
    base_rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    with torch.no_grad():
        fwd = _time(lambda: render(g, cam), repeats)
    fwd_bwd = _time(_fwd_bwd(render, g, cam), repeats)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    row: dict[str, object] = {
        "rasterizer": resolve_rasterizer(None, torch.device("cpu")),
        "n": n,
        "size": size,
        "fwd_ms": fwd,
        "fwd_bwd_ms": fwd_bwd,
        "peak_mb": peak / 1024,
        "peak_over_base_mb": (peak - base_rss) / 1024,
    }
    pairs = n * size * size
    if pairs <= REFERENCE_MAX_PAIRS:
        with torch.no_grad():
            out = render(g, cam)
            ref = render_dense(
                g.to(dtype=torch.float64), cam.to(dtype=torch.float64), pixel_chunk=max(1, int(2e7 // n))
            )
        err = torch.cat(
            [
                (a.double() - b).abs().reshape(size, size, -1)
                for a, b in zip((out.rgb, out.alpha, out.depth), ref, strict=True)
            ],
            dim=-1,
        ).amax(-1)  # (H, W)
        row["max_abs_err"] = float(err.max())
        row["pixels_over_1e-5"] = int((err > 1e-5).sum())
    if pairs <= DENSE_MAX_PAIRS:
        dense = _time(_fwd_bwd(render_dense, g, cam), max(1, repeats // 3))
        row["dense_fwd_bwd_ms"] = dense
        row["speedup"] = dense / fwd_bwd
    return row


def machine_line() -> str:
    """The machine a benchmark ran on: cores, the CPU's model (:func:`particlesplat.core.machine.cpu_model`), torch,
    threads and Python."""
    return (
        f"machine: {os.cpu_count()} cores ({cpu_model()}), torch {torch.__version__}, "
        f"{torch.get_num_threads()} threads, python {platform.python_version()}"
    )


def _fmt(row: dict, key: str, spec: str) -> str:
    return format(row[key], spec) if key in row else "n/a"


# bytes a benchmark Gaussian holds with its gradient and the projection's per-Gaussian intermediates (23 values of
# 4 bytes, an int64 owner, twice over for the gradients, and the projected means, conics, colours and depths)
BENCH_BYTES_PER_GAUSSIAN = 400.0


def check_cases(counts: list[int], sizes: list[int], repeats: int) -> None:
    """OptionError naming the option for a case no machine can run (counts and sizes below 1, images beyond the
    renderer's largest) and BudgetError for one whose Gaussians and render would not fit the memory limit, before
    any case starts."""
    from particlesplat.core.errors import OptionError
    from particlesplat.core.limits import check_memory
    from particlesplat.rendering.budget import BYTES_PER_PAIR, BYTES_PER_PIXEL
    from particlesplat.rendering.rasterize import TILE

    if min(counts) < 1 or repeats < 1:
        raise OptionError(f"--n and --repeats must be >= 1, got {min(counts)} and {repeats}")
    if not all(1 <= s <= MAX_BENCH_SIDE for s in sizes):
        raise OptionError(f"--sizes must be in [1, {MAX_BENCH_SIDE}], got {sizes}")
    for n in counts:
        for s in sizes:  # the scene's Gaussians cover a few pixels each: a tile or four a Gaussian, estimated at 4
            pairs = 4.0 * n * max(1.0, (s / 128.0) ** 2 / TILE)
            check_memory(
                n * BENCH_BYTES_PER_GAUSSIAN + 2 * (pairs * BYTES_PER_PAIR + s * s * BYTES_PER_PIXEL),
                f"--n {n} --sizes {s}: {n:,} Gaussians rendered forward and backward at {s}x{s}",
            )


MAX_BENCH_SIDE = 8192  # pixels, as render --width


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="particlesplat bench render", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--n", type=int, nargs="+", default=[2000, 10000, 50000], help="Gaussian counts")
    parser.add_argument("--sizes", type=int, nargs="+", default=[64, 128, 512], help="square image sizes")
    parser.add_argument("--repeats", type=int, default=5, help="timed repeats per case (median)")
    parser.add_argument(
        "--rasterizer",
        default="auto",
        help="comma-separated rasterizers to compare, each case run with each in turn (torch, fused, auto; "
        "default: auto, the fused kernels on the CPU)",
    )
    parser.add_argument("--json", help="also write the rows to this JSON file")
    parser.add_argument("--case", nargs=2, type=int, metavar=("N", "SIZE"), help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    rasterizers = rasterizer_list(args.rasterizer)
    from particlesplat.core.outputs import guard_outputs

    guard_outputs([("--json", args.json)], [])
    check_cases(args.n, args.sizes, args.repeats)
    if args.case:
        print(json.dumps(run_case(args.case[0], args.case[1], args.repeats, rasterizers[0])))
        return 0
    print(machine_line())
    header = (
        "| N | size | rasterizer | fwd ms | fwd+bwd ms | peak RSS MB (over start) | max abs err vs f64 brute force | "
        "pixels > 1e-5 | dense fwd+bwd ms | speed-up vs dense |"
    )
    print(header)
    print("|---" * (header.count("|") - 1) + "|")
    rows = []
    for n, size, rasterizer in [(n, s, r) for n in args.n for s in args.sizes for r in rasterizers]:
        cmd = [sys.executable, "-m", "particlesplat.bench.render", "--case", str(n), str(size)]
        cmd += ["--repeats", str(args.repeats), "--rasterizer", rasterizer]
        proc = subprocess.run(cmd, capture_output=True, text=True)
        if proc.returncode != 0:
            print(f"case N={n} size={size} rasterizer={rasterizer} failed:\n{proc.stderr}", file=sys.stderr)
            return 1
        row = json.loads(proc.stdout.strip().splitlines()[-1])  # checked: our own child process's last line
        rows.append(row)
        print(
            f"| {n} | {size}² | {row['rasterizer']} | {row['fwd_ms']:.1f} | {row['fwd_bwd_ms']:.1f} | "
            f"{row['peak_mb']:.0f} ({row['peak_over_base_mb']:.0f}) | {_fmt(row, 'max_abs_err', '.1e')} | "
            f"{_fmt(row, 'pixels_over_1e-5', 'd')} | "
            f"{_fmt(row, 'dense_fwd_bwd_ms', '.0f')} | {_fmt(row, 'speedup', '.1f')} |",
            flush=True,
        )
    if args.json:
        from particlesplat.core.atomic import atomic_write

        with atomic_write(args.json, "w") as f:
            json.dump({"machine": machine_line(), "rows": rows}, f, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
