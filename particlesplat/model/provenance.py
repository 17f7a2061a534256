"""Provenance of a training run, stored in every checkpoint it writes and printed by ``particlesplat eval``.

A checkpoint's ``provenance`` dict holds: the data folder and a SHA-256 of its training scene list, the init
source (None for a run from random initialisation), wall-clock and CPU hours spent so far (summed over
resumes), the torch version, the git commit of the code (None outside a git checkout) and the host's
device. The resolved config and the step sit beside it in the checkpoint (``config``, ``train``, ``step``).
"""

from __future__ import annotations

import hashlib
import subprocess
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import torch


def scene_list_hash(split: Path) -> str:
    """SHA-256 (hex) of the sorted scene folder names under ``split`` (one name per line)."""
    names = sorted(p.name for p in split.iterdir() if p.is_dir() and not p.name.startswith("."))
    return hashlib.sha256("".join(n + "\n" for n in names).encode()).hexdigest()


def git_commit(where: Path | None = None) -> str | None:
    """The commit checked out where the code lives (``-dirty`` appended with uncommitted changes), or None."""
    where = where or Path(__file__).resolve().parent
    try:
        rev = subprocess.run(["git", "rev-parse", "HEAD"], cwd=where, capture_output=True, text=True, timeout=5)
        if rev.returncode != 0:
            return None
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=where,
            capture_output=True,
            text=True,
            timeout=5,
        )
        return rev.stdout.strip() + ("-dirty" if dirty.stdout.strip() else "")
    except (OSError, subprocess.SubprocessError):
        return None


@dataclass
class Provenance:
    """Where a run's weights come from. Hours are cumulative over every invocation of the run."""

    data: str
    train_scenes: int
    scene_list_sha256: str
    init: str | None
    wall_hours: float
    cpu_hours: float
    torch: str
    git_commit: str | None
    device: str

    @classmethod
    def start(cls, data: Path, init: Path | None, device: str) -> Provenance:
        split = data / "train"
        n = sum(1 for p in split.iterdir() if p.is_dir() and not p.name.startswith("."))
        return cls(
            data=str(data.resolve()),
            train_scenes=n,
            scene_list_sha256=scene_list_hash(split),
            init=None if init is None else str(init),
            wall_hours=0.0,
            cpu_hours=0.0,
            torch=str(torch.__version__),
            git_commit=git_commit(),
            device=device,
        )

    def to_dict(self) -> dict:
        return asdict(self)


class RunClock:
    """Wall-clock and process CPU time since it was made, added to what earlier invocations spent."""

    def __init__(self, wall_hours: float = 0.0, cpu_hours: float = 0.0):
        self.base_wall, self.base_cpu = wall_hours, cpu_hours
        self.t0, self.c0 = time.monotonic(), time.process_time()

    def hours(self) -> tuple[float, float]:
        """(wall, cpu) hours so far."""
        return (
            self.base_wall + (time.monotonic() - self.t0) / 3600.0,
            self.base_cpu + (time.process_time() - self.c0) / 3600.0,
        )


PROVENANCE_TEXT = ("data", "scene_list_sha256", "init", "torch", "git_commit", "device", "derived")
PROVENANCE_NUMBERS = ("train_scenes", "wall_hours", "cpu_hours")
MAX_PROVENANCE_TEXT = 4096  # characters of one text field


def provenance_problem(prov: object) -> str | None:
    """What is wrong with a checkpoint's ``provenance`` (None when nothing is): a mapping whose text fields
    (:data:`PROVENANCE_TEXT`) are text or null, at most :data:`MAX_PROVENANCE_TEXT` characters, and whose
    counts and hours (:data:`PROVENANCE_NUMBERS`) are finite non-negative numbers or null. Other keys are ignored."""
    import math

    if not isinstance(prov, dict):
        return f"expected a mapping, got {type(prov).__name__}"
    for key in PROVENANCE_TEXT:
        v = prov.get(key)
        if v is not None and (not isinstance(v, str) or len(v) > MAX_PROVENANCE_TEXT):
            what = type(v).__name__ if not isinstance(v, str) else f"{len(v):,} characters"
            return f"{key}: expected text of at most {MAX_PROVENANCE_TEXT} characters or null, got {what}"
    for key in PROVENANCE_NUMBERS:
        v = prov.get(key)
        if v is None:
            continue
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
            return f"{key}: expected a finite non-negative number or null, got {str(v)[:40]!r}"
    return None


def describe(prov: dict | None) -> str:
    """One line for ``particlesplat eval``: the run's init, data, cost and code."""
    if not prov:
        return "provenance: none recorded (checkpoint written before provenance was kept)"
    init = prov.get("init") or "random initialisation"
    commit = prov.get("git_commit") or "unknown commit"
    wall, cpu = prov.get("wall_hours"), prov.get("cpu_hours")
    cost = (
        f"{wall:.2f} h wall, {cpu:.2f} CPU h"
        if isinstance(wall, (int, float)) and isinstance(cpu, (int, float))
        else "hours not recorded"
    )
    derived = f"; {prov['derived']}" if prov.get("derived") else ""  # a shipped copy that changed the run's checkpoint
    return (
        f"provenance: from {init}; data {prov.get('data')} ({prov.get('train_scenes')} training scenes, "
        f"list sha256 {str(prov.get('scene_list_sha256'))[:12]}); {cost} on {prov.get('device')}; "
        f"torch {prov.get('torch')}; code {commit}{derived}"
    )
