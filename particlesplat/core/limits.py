"""Limits every command checks before it works: one memory budget per job, and numbers representable in float32.

Memory: a command estimates what it will hold (frames x pixels of the scenes it reads, the weights a config
builds, Gaussians x views, context views) **before** it allocates it, and :func:`check_memory` refuses an
estimate above :func:`memory_limit` with one line naming the input and the estimate. A reader sizes everything a
file will make it hold from its headers (file size, zip directory, image headers, the sum of a manifest's parts)
and holds that as one reservation while it reads (:func:`reserve_memory`): reservations of one job add up, and
every check made while they are held counts them, so pieces that each fit cannot pass together. The limit is
``PARTICLESPLAT_MEMORY_LIMIT`` (bytes, or with a unit: ``512M``, ``16G``) when set; otherwise half the machine's
memory, and never more than what this process may still map (its ``RLIMIT_AS``, e.g. ``ulimit -v``).

Numbers: values read from files are float64 in Python and float32 in torch; :func:`float32_problem` says what is
wrong with a value that is not finite, or so large (or, for a positive value, so small) that float32 arithmetic
on it (squares, products with other coordinates) overflows or underflows.
"""

from __future__ import annotations

import math
import os
import re
import resource
from collections.abc import Iterator
from contextlib import contextmanager
from contextvars import ContextVar

from particlesplat.core.errors import UserError

MEMORY_ENV = "PARTICLESPLAT_MEMORY_LIMIT"
MACHINE_SHARE = 0.5  # the default limit: this share of the machine's memory
# float32 reaches 3.4e38: a value at most 1e18 keeps its square (and a product of two) finite, and a positive
# value at least 1e-18 keeps its reciprocal's square finite
FLOAT32_MAX_ABS = 1e18
FLOAT32_MIN_POSITIVE = 1e-18
# world positions and depths a scene may hold: float32 keeps about 8 mm at 1e5 m (6 cm at ECEF's 4e6 m, where
# objects vanish between representable values); a scene far from the origin is translated near it first
WORLD_MAX_METRES = 1e5
MIN_DISTANCE_METRES = 1e-3  # a framing distance below a millimetre is a unit error, not a camera
_UNITS = {"": 1, "K": 1 << 10, "M": 1 << 20, "G": 1 << 30, "T": 1 << 40}


class BudgetError(UserError):
    """A job whose estimated memory exceeds the limit; the message names the input, the estimate and the limit."""


def parse_bytes(text: str, where: str = MEMORY_ENV) -> int:
    """``"16G"`` -> 17179869184 (units K, M, G, T of 1024; a trailing ``B`` or ``iB`` is allowed)."""
    m = re.fullmatch(r"\s*([0-9]+(?:\.[0-9]*)?)\s*([KMGT]?)(?:I?B)?\s*", str(text).upper())
    if not m or float(m.group(1)) <= 0:
        raise UserError(f"{where}: expected a positive size such as 8G or 512M, got {str(text)[:40]!r}")
    return int(float(m.group(1)) * _UNITS[m.group(2)])


def _machine_bytes() -> int:
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return 8 << 30


def _mapped_bytes() -> int:
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmSize:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return 0


def memory_limit() -> tuple[int, str]:
    """(bytes a job may hold, where that number comes from, for messages)."""
    text = os.environ.get(MEMORY_ENV)
    if text:
        return parse_bytes(text), f"{MEMORY_ENV}={text.strip()[:20]}"
    limit, source = int(_machine_bytes() * MACHINE_SHARE), "half the machine's memory"
    soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    if soft != resource.RLIM_INFINITY:
        room = max(soft - _mapped_bytes(), 0)
        if room < limit:
            limit, source = room, "the address space this process may still map (ulimit -v)"
    return limit, source


def format_bytes(n: float) -> str:
    """``1.5e9`` -> ``'1.4 GiB'``."""
    for unit, size in (("GiB", 1 << 30), ("MiB", 1 << 20), ("KiB", 1 << 10)):
        if n >= size:
            return f"{n / size:.1f} {unit}"
    return f"{int(n)} bytes"


_RESERVED: ContextVar[float] = ContextVar("particlesplat_reserved_memory", default=0.0)


def reserved_memory() -> float:
    """Bytes the job holds reserved now (:func:`reserve_memory` blocks being run); 0 outside them."""
    return _RESERVED.get()


def check_memory(estimate: float, what: str) -> None:
    """BudgetError unless ``estimate`` bytes, on top of what the job has reserved (:func:`reserved_memory`), fit in
    :func:`memory_limit`; ``what`` names the input and how the estimate was made (e.g. ``"scene/transforms.json:
    200 frames, 3.4e9 pixels"``)."""
    limit, source = memory_limit()
    held = reserved_memory()
    if estimate + held > limit:
        also = f" on top of the {format_bytes(held)} this job holds" if held > 0 else ""
        raise BudgetError(
            f"{what}: needs about {format_bytes(estimate)}{also}, more than the memory limit of "
            f"{format_bytes(limit)} ({source}; set {MEMORY_ENV}, e.g. {MEMORY_ENV}=32G, to raise it)"
        )


@contextmanager
def reserve_memory(estimate: float, what: str) -> Iterator[None]:
    """Hold ``estimate`` bytes of the job's memory limit while the block runs: :func:`check_memory` first (what is
    held already counts), then every check and reservation inside the block counts it too. A reader sizes all it
    will hold from headers, reserves the sum once, then reads with bounds (never more than it reserved)."""
    check_memory(estimate, what)
    token = _RESERVED.set(reserved_memory() + float(estimate))
    try:
        yield
    finally:
        _RESERVED.reset(token)


def check_option_range(value: float | None, flag: str, lo: float, hi: float, low_open: bool = False) -> None:
    """OptionError naming ``flag`` unless ``value`` (None: not given) is a finite number in [lo, hi] (``low_open``:
    above ``lo``): a NaN threshold would compare false everywhere and render an empty scene in silence."""
    if value is None:
        return
    from particlesplat.core.errors import OptionError

    ok = math.isfinite(value) and (value > lo if low_open else value >= lo) and value <= hi
    if not ok:
        raise OptionError(f"{flag} must be in {'(' if low_open else '['}{lo:g}, {hi:g}], got {value!r}")


def rigid_problem(m: object, tol: float = 1e-3, max_metres: float | None = WORLD_MAX_METRES) -> str | None:
    """What keeps ``m`` from being a rigid pose in the world (None when nothing does): a 4 x 4 array of finite
    numbers within +-:data:`FLOAT32_MAX_ABS`, an orthonormal rotation with determinant +1 (no scale, skew or
    mirror; within ``tol``), the last row 0 0 0 1 and a translation within ``max_metres`` (None: any; default
    :data:`WORLD_MAX_METRES`). Camera poses and the robot's base are held to it."""
    import numpy as np

    try:
        a = np.asarray(m, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        return "must be a 4x4 list of numbers"
    if a.shape != (4, 4):
        return f"must be 4x4, got shape {a.shape}"
    if not np.isfinite(a).all():
        return "has non-finite values"
    if np.abs(a).max() > FLOAT32_MAX_ABS:
        return f"has values beyond +-{FLOAT32_MAX_ABS:g} (float32 arithmetic on them overflows)"
    R = a[:3, :3]
    err = max(float(np.abs(R.T @ R - np.eye(3)).max()), float(np.abs(a[3] - [0, 0, 0, 1]).max()))
    det = float(np.linalg.det(R))
    if err > tol or det <= 0:
        return (
            "is not a rigid transform (rotation must be orthonormal with det +1 and the last row 0 0 0 1; "
            f"error {err:.3g}, det {det:.3g})"
        )
    far = float(np.abs(a[:3, 3]).max())
    if max_metres is not None and far > max_metres:
        return (
            f"is {far:.3g} m from the origin, beyond the {max_metres:g} m where float32 keeps millimetres; "
            "translate the scene near the origin"
        )
    return None


def float32_problem(value: float, positive: bool = False) -> str | None:
    """What is wrong with ``value`` as a float32 quantity (None when nothing is): not finite, beyond
    :data:`FLOAT32_MAX_ABS` in size, or (``positive``) not positive or below :data:`FLOAT32_MIN_POSITIVE`."""
    try:
        x = float(value)
    except (TypeError, ValueError, OverflowError):
        return "not a number"
    if not math.isfinite(x):
        return "not finite"
    if abs(x) > FLOAT32_MAX_ABS:
        return f"beyond +-{FLOAT32_MAX_ABS:g} (float32 arithmetic on it overflows)"
    if positive and x <= 0:
        return "not positive"
    if positive and x < FLOAT32_MIN_POSITIVE:
        return f"below {FLOAT32_MIN_POSITIVE:g} (float32 arithmetic on it underflows)"
    return None
