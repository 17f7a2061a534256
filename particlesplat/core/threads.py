"""CPU threads that fit the cores other processes leave free.

OpenMP threads that wait for each other either spin (torch's default) or sleep (``OMP_WAIT_POLICY=PASSIVE``).
Measured on the robot recipe (2 threads, 2 cores, 2026-11-26): on free cores a training step takes 1.54 s
spinning and 2.57 s sleeping; with one core busy with other work, 4.74 s spinning, 2.52 s sleeping, and
2.36 s with one thread (no waits at all). So long jobs spin and drop threads while other processes keep cores
busy (:class:`ThreadGovernor`), and other commands started on a busy machine sleep (:func:`wait_policy_for_load`).
Busy cores are read from Linux's ``/proc/stat``; elsewhere nothing adapts.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

PROC_STAT = Path("/proc/stat")
IDLE_MARGIN = 0.3  # cores: other processes using less than this leave a core free (shells, monitors)
LOAD_WINDOW = 0.1  # seconds a command samples the load for before it loads torch
BUSY_LOAD = 0.5  # cores other processes use from which a command's OpenMP threads wait passively


def usable_cores() -> int:
    """Cores this process may run on (its CPU affinity where the platform has one)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def bounded_threads(requested: int, where: str) -> int:
    """A requested CPU thread count bounded by the cores this process may use (:func:`usable_cores`): more threads
    than cores only wait for each other (``train.num_threads: 1024`` on 2 cores: 120 s a step instead of 0.1 s) and
    thousands abort OpenMP's runtime. A larger request is lowered with a warning naming ``where``."""
    cores = usable_cores()
    if requested > cores:
        from particlesplat.core.errors import warn_input

        warn_input(f"{where}: {requested} threads on {cores} usable cores; using {cores}")
        return cores
    return requested


THREAD_VARIABLES = ("OMP_NUM_THREADS", "MKL_NUM_THREADS")


def bound_thread_variables() -> None:
    """Lower ``OMP_NUM_THREADS`` / ``MKL_NUM_THREADS`` above the usable cores to the cores, with a warning on
    stderr (called before torch loads its OpenMP runtime, which reads them once)."""
    import sys

    cores = usable_cores()
    for name in THREAD_VARIABLES:
        text = os.environ.get(name, "").strip()
        if text.isdigit() and int(text) > cores:
            print(f"warning: {name}={text[:12]}: {cores} usable cores; using {cores}", file=sys.stderr)
            os.environ[name] = str(cores)


def busy_seconds(stat: Path = PROC_STAT) -> float | None:
    """CPU-seconds all processes have run since boot (every core: user, nice, system, irq, softirq, steal), from
    ``/proc/stat``; None where it cannot be read."""
    try:
        fields = stat.read_text().split("\n", 1)[0].split()
        ticks = [int(v) for v in fields[1:9]]
    except (OSError, ValueError, IndexError):
        return None
    if fields[0] != "cpu" or len(ticks) < 8:
        return None
    user, nice, system, _idle, _iowait, irq, softirq, steal = ticks
    return (user + nice + system + irq + softirq + steal) / os.sysconf("SC_CLK_TCK")


def threads_for(maximum: int, cores: int, others: float) -> int:
    """Threads to run: the cores ``others`` (cores' worth of other processes' CPU) leave free, at least 1 and at most
    ``maximum``. Load under :data:`IDLE_MARGIN` of a core counts as none."""
    free = cores - max(0.0, others - IDLE_MARGIN)
    return max(1, min(maximum, int(free + 1e-9)))


class _Sample:
    """When it was taken (monotonic seconds), CPU-seconds every process had run and this process's own; None
    fields where ``/proc/stat`` cannot be read."""

    def __init__(self, stat: Path):
        self.wall, self.busy, self.own = time.monotonic(), busy_seconds(stat), time.process_time()

    def others_since(self, earlier: _Sample) -> float | None:
        """Cores' worth of CPU other processes used between ``earlier`` and this sample (None if unknown)."""
        if self.busy is None or earlier.busy is None or self.wall <= earlier.wall:
            return None
        return max(0.0, (self.busy - earlier.busy) - (self.own - earlier.own)) / (self.wall - earlier.wall)


class ThreadGovernor:
    """Keeps torch's thread count at the cores other processes leave free, up to ``maximum``.

    Call :meth:`update` now and then (a training run: every few steps): it measures the CPU other processes used
    since the last call (all busy time minus this process's own) and sets ``torch.set_num_threads``. Returns the
    thread count, unchanged where ``stat`` (default ``/proc/stat``) is unreadable.
    """

    def __init__(self, maximum: int, stat: Path | None = None):
        import torch

        self.maximum = max(1, maximum)
        self.cores = usable_cores()
        self.stat = stat or PROC_STAT
        self.threads = torch.get_num_threads()
        self._last = _Sample(self.stat)

    def update(self) -> int:
        import torch

        now = _Sample(self.stat)
        others, self._last = now.others_since(self._last), now
        if others is None:
            return self.threads
        threads = threads_for(self.maximum, self.cores, others)
        if threads != self.threads:
            torch.set_num_threads(threads)
            self.threads = threads
        return threads


def other_load(window: float = LOAD_WINDOW, stat: Path | None = None) -> float | None:
    """Cores' worth of CPU other processes use, sampled over ``window`` seconds (this process sleeps through it)
    from ``stat`` (default ``/proc/stat``); None where it cannot be read."""
    stat = stat or PROC_STAT
    first = _Sample(stat)
    time.sleep(window)
    return _Sample(stat).others_since(first)


def wait_policy_for_load() -> str | None:
    """``"PASSIVE"`` when other processes keep at least half a core busy now (OpenMP threads that spin there wait
    for threads that cannot run), else None (the runtime's default: spin briefly, then sleep)."""
    others = other_load()
    return "PASSIVE" if others is not None and others >= BUSY_LOAD else None
