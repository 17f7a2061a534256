"""Fixed-size float tuples from tensors, arrays and sequences: the ``(x, y, z)`` points, offsets and colours and
the ``(w, x, y, z)`` quaternions that dataclasses, scene files and edit files hold as plain Python floats."""

from __future__ import annotations

from collections.abc import Iterable
from typing import SupportsFloat


def float3(values: Iterable[SupportsFloat]) -> tuple[float, float, float]:
    """The 3 numbers of ``values`` (a (3,) tensor or array, or a sequence) as Python floats."""
    x, y, z = (float(v) for v in values)
    return x, y, z


def float4(values: Iterable[SupportsFloat]) -> tuple[float, float, float, float]:
    """The 4 numbers of ``values`` (a (4,) tensor or array, or a sequence) as Python floats."""
    w, x, y, z = (float(v) for v in values)
    return w, x, y, z
