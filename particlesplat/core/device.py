"""The one check of a ``--device`` option, for every command."""

from __future__ import annotations

import re
from typing import TYPE_CHECKING

from particlesplat.core.errors import OptionError

if TYPE_CHECKING:
    import torch

DEVICE_HELP = "cpu, cuda or cuda:N (none = cuda when present, else cpu)"


def resolve_device(text: str | None, option: str = "--device") -> torch.device:
    """The torch device ``text`` names (``cpu``, ``cuda``, ``cuda:N``, ``mps``; None = cuda when present, else
    cpu). OptionError naming ``option`` for a typo or a device this machine does not have."""
    import torch  # here, not above: a command's --help and argument errors come before torch loads

    if text is None or str(text).strip() == "":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    name = str(text).strip().lower()
    m = re.fullmatch(r"(cpu|cuda|mps)(?::(\d{1,3}))?", name)
    if not m:
        raise OptionError(f"{option} {str(text)[:40]!r}: expected cpu, cuda or cuda:N")
    kind, index = m.group(1), m.group(2)
    if kind == "cpu":
        if index not in (None, "0"):
            raise OptionError(f"{option} {name}: there is one cpu device (cpu)")
        return torch.device("cpu")
    if kind == "mps":
        mps = getattr(torch.backends, "mps", None)
        if mps is None or not mps.is_available():
            raise OptionError(f"{option} {name}: no Apple MPS device is available on this machine")
        return torch.device(name)
    if not torch.cuda.is_available():
        raise OptionError(f"{option} {name}: no CUDA device is available on this machine (use --device cpu)")
    count = torch.cuda.device_count()
    if index is not None and int(index) >= count:
        raise OptionError(f"{option} {name}: this machine has {count} CUDA device(s) (cuda:0..cuda:{count - 1})")
    return torch.device(name)
