"""Which rasterizer a render uses: the fused CPU kernels or their pure-torch twin.

``auto`` (the default) takes the torch twin off the CPU (CUDA: the twin is the reference and the GPU path) and, on
the CPU, the one measured faster on this machine, for renders with gradients and without
(:mod:`particlesplat.rendering.measured`: timed once, then cached per CPU model, cores, torch and numba). The process
default can be set once (the CLI's ``--rasterizer``), for a block of code (:func:`use_rasterizer`), or by the
environment (``PARTICLESPLAT_RASTERIZER=torch|fused|auto``); a render's own ``rasterizer=`` argument wins over all of
them.
"""

from __future__ import annotations

import argparse
import os
from collections.abc import Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING

from particlesplat.core.errors import OptionError

if TYPE_CHECKING:  # commands add the option before torch loads (their --help and argument errors stay fast)
    import torch

RASTERIZERS = ("torch", "fused")
CHOICES = ("auto", *RASTERIZERS)
ENV = "PARTICLESPLAT_RASTERIZER"
RASTERIZER_HELP = (
    "fused (numba kernels) or torch (the pure-torch twin, the CUDA path); auto takes torch off the CPU and, on the "
    "CPU, the one measured faster on this machine (timed once, a few seconds, then cached in the user's cache "
    f"folder) (default: auto, or what {ENV} says)"
)

_default: str | None = None


def _check(name: str, where: str) -> str:
    if name not in CHOICES:
        raise ValueError(f"{where}: unknown rasterizer {name!r}; use one of {', '.join(CHOICES)}")
    return name


def rasterizer_list(text: str) -> list[str]:
    """The rasterizers of a comma-separated option value (``--rasterizer torch,fused``), checked (OptionError)."""
    names = [t.strip() for t in text.split(",") if t.strip()]
    if not names or any(n not in CHOICES for n in names):
        raise OptionError(f"--rasterizer: one or more of {', '.join(CHOICES)}, comma-separated; got {text!r}")
    return names


def add_rasterizer_option(parser: argparse.ArgumentParser) -> None:
    """The commands' ``--rasterizer`` option; :func:`apply_rasterizer_option` applies it."""
    parser.add_argument("--rasterizer", choices=CHOICES, default=None, help=RASTERIZER_HELP)


def apply_rasterizer_option(args: argparse.Namespace) -> None:
    """Make a command's ``--rasterizer`` the process default (no option: the environment's, or auto)."""
    set_default_rasterizer(getattr(args, "rasterizer", None))


def set_default_rasterizer(name: str | None) -> None:
    """Set the process-wide choice (None: back to the environment's, or auto)."""
    global _default
    _default = None if name is None else _check(name, "rasterizer")


@contextmanager
def use_rasterizer(name: str | None) -> Iterator[None]:
    """Renders inside the block use ``name`` unless they name one themselves."""
    global _default
    before = _default
    set_default_rasterizer(name)
    try:
        yield
    finally:
        _default = before


def resolve_rasterizer(name: str | None, device: torch.device, grad: bool = False) -> str:
    """'fused' or 'torch' for a render on ``device`` (``grad``: one that carries gradients): ``name``, else the
    process default, else ``$PARTICLESPLAT_RASTERIZER``, else auto (on the CPU:
    :func:`particlesplat.rendering.measured.measured_choice`). Asking for the fused kernels on a non-CPU device is
    a ValueError."""
    chosen = name or _default or _check(os.environ.get(ENV) or "auto", ENV)
    chosen = _check(chosen, "rasterizer")
    if chosen == "auto":
        if device.type != "cpu":
            return "torch"
        from particlesplat.rendering.measured import measured_choice

        return measured_choice(grad)
    if chosen == "fused" and device.type != "cpu":
        raise ValueError(f"the fused rasterizer runs on the CPU, not on {device.type}; use --rasterizer torch")
    return chosen


def rasterizer_note(device: torch.device, grad: bool) -> str:
    """What a command says of the rasterizer its renders on ``device`` use (``grad``: training's): the name, and
    whether ``auto`` chose it by measurement."""
    chosen = resolve_rasterizer(None, device, grad)
    how = _default or os.environ.get(ENV) or "auto"
    if how == "auto" and device.type == "cpu":
        return f"{chosen} (auto: measured the faster {'for training' if grad else 'for renders'} on this CPU)"
    return chosen
