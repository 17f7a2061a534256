"""``particlesplat bench startup``: how long a command takes to answer before any work, and to stop on Ctrl-C.

Each case runs ``python -m particlesplat.cli ARGS`` in a fresh process ``--repeat`` times and reports the median
wall seconds to its exit: ``--help`` of every command, and the one-line errors of a path that does not exist (both
answered before torch loads). The Ctrl-C case starts ``particlesplat eval`` on the demo scenes, sends SIGINT once
the command has printed its first line (the model is loaded and the work has begun) and reports the seconds from
the signal to the exit. Nothing is written but to a temporary folder.
"""

from __future__ import annotations

import argparse
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from particlesplat.core.bundled import bundled_assets
from particlesplat.core.errors import OptionError

TARGET_S = 1.0  # the promise: an answer (help, a path error) or a stop (Ctrl-C) within a second


def cases(tmp: Path) -> list[tuple[str, list[str]]]:
    """(label, arguments of ``particlesplat``) of each start-up case."""
    missing = str(tmp / "missing")
    out = [(f"{c} --help", [c, "--help"]) for c in ("train", "eval", "render", "encode", "curve", "synth")]
    out += [
        ("eval --data MISSING", ["eval", "--data", missing]),
        ("render --scene MISSING", ["render", "--scene", missing, "--out", str(tmp / "x.png")]),
        ("encode --data MISSING", ["encode", "--data", missing, "--out", str(tmp / "enc")]),
        ("train --data MISSING", ["train", "--data", missing, "--out", str(tmp / "run")]),
        ("render --mode typo", ["render", "--mode", "typo", "--out", str(tmp / "x.png")]),
    ]
    return out


def time_command(args: list[str]) -> tuple[float, int]:
    """(wall seconds, exit code) of ``python -m particlesplat.cli ARGS`` in a fresh process."""
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "particlesplat.cli", *args], capture_output=True)
    return time.perf_counter() - t0, proc.returncode


def time_interrupt(tmp: Path) -> tuple[float, int]:
    """(seconds from SIGINT to exit, exit code) of ``particlesplat eval`` on the demo scenes, interrupted once it
    printed its first line."""
    scenes = bundled_assets() / "scenes"
    cmd = [sys.executable, "-m", "particlesplat.cli", "eval", "--data", str(scenes), "--json", str(tmp / "e.json")]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    assert proc.stdout is not None
    proc.stdout.readline()  # the checkpoint line: the model is loaded, the scenes come next
    time.sleep(0.5)
    t0 = time.perf_counter()
    proc.send_signal(signal.SIGINT)
    try:
        code = proc.wait(timeout=30)
    except subprocess.TimeoutExpired:
        proc.kill()
        code = proc.wait()
    return time.perf_counter() - t0, code


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="particlesplat bench startup", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--repeat", type=int, default=3, help="runs of each case (the median is reported)")
    parser.add_argument("--no-interrupt", action="store_true", help="skip the Ctrl-C case")
    args = parser.parse_args(argv)
    if not 1 <= args.repeat <= 100:
        raise OptionError(f"--repeat must be in [1, 100], got {args.repeat}")
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"python {sys.version.split()[0]}, {os.cpu_count()} cores, load average {load:.2f}")
    print("| case | median s | exit code | within 1 s |")
    print("|---|---|---|---|")
    worst = 0.0
    with tempfile.TemporaryDirectory() as folder:
        tmp = Path(folder)
        rows = [(label, [time_command(a) for _ in range(args.repeat)]) for label, a in cases(tmp)]
        if not args.no_interrupt:
            rows.append(("eval, Ctrl-C to exit", [time_interrupt(tmp) for _ in range(args.repeat)]))
        for label, runs in rows:
            s = statistics.median(t for t, _ in runs)
            worst = max(worst, s)
            print(f"| {label} | {s:.2f} | {runs[0][1]} | {'yes' if s < TARGET_S else 'no'} |")
    print(f"slowest case: {worst:.2f} s (target {TARGET_S:g} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
