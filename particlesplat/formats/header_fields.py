"""Typed readers of the fields of a JSON format header (a ``.sog``'s ``meta.json``, a bundle's ``manifest.json``).

Each reader takes the parsed JSON, the file the message names (``where``: ``x.sog: meta.json``) and the path of
keys (and list indices) down to the field, and returns the value as the program uses it, or raises
:class:`SplatFileError` in one line naming the file and the field (``'shN.bands'``) and what was found. A bool is
never a number (JSON's ``true`` is not ``1``), a list never a whole number, a number never text.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from particlesplat.core.errors import short_repr
from particlesplat.formats.splat_arrays import SplatFileError


def _name(keys: tuple[str | int, ...]) -> str:
    return ".".join(str(k) for k in keys)


def field(node: object, where: str, *keys: str | int) -> Any:
    """The value at ``keys`` (dict keys, list indices); SplatFileError naming the first one missing."""
    for i, key in enumerate(keys):
        if isinstance(key, int) and isinstance(node, list) and 0 <= key < len(node):
            node = node[key]
        elif isinstance(key, str) and isinstance(node, dict) and key in node:
            node = node[key]
        else:
            raise SplatFileError(f"{where}: missing '{_name(keys[: i + 1])}'")
    return node


def is_number(value: object) -> bool:
    """A JSON number (int or float, never a bool), finite as a float64."""
    if not isinstance(value, (int, float)) or isinstance(value, bool):
        return False
    try:
        return math.isfinite(value)
    except OverflowError:  # an integer beyond float64
        return False


def whole_number(node: object, where: str, *keys: str | int, lo: int = 0, hi: int | None = None) -> int:
    """The whole number at ``keys``, in [lo, hi] (hi None: no upper bound); a bool, a float, text, a list or a
    dict is refused."""
    value = field(node, where, *keys)
    if isinstance(value, int) and not isinstance(value, bool) and value >= lo and (hi is None or value <= hi):
        return value
    span = f">= {lo}" if hi is None else f"in {lo}..{hi}"
    raise SplatFileError(f"{where}: '{_name(keys)}' must be a whole number {span}, got {short_repr(value)}")


def numbers(node: object, where: str, *keys: str | int, length: int | None = None) -> np.ndarray:
    """(length,) float64: the list of finite numbers at ``keys`` (of ``length`` entries when given)."""
    value = field(node, where, *keys)
    if isinstance(value, list) and (length is None or len(value) == length) and all(map(is_number, value)):
        return np.asarray(value, dtype=np.float64).reshape(len(value))
    want = f"{length} finite numbers" if length is not None else "a list of finite numbers"
    raise SplatFileError(f"{where}: '{_name(keys)}': expected {want}, got {short_repr(value)}")


def text(node: object, where: str, *keys: str | int, max_length: int = 255) -> str:
    """The text at ``keys``, at most ``max_length`` characters."""
    value = field(node, where, *keys)
    if isinstance(value, str) and len(value) <= max_length:
        return value
    raise SplatFileError(f"{where}: '{_name(keys)}' must be text of at most {max_length} characters")


def text_list(node: object, where: str, *keys: str | int, min_length: int = 1) -> list[str]:
    """The list of at least ``min_length`` texts (file names) at ``keys``."""
    value = field(node, where, *keys)
    if isinstance(value, list) and len(value) >= min_length and all(isinstance(v, str) for v in value):
        return value
    raise SplatFileError(
        f"{where}: '{_name(keys)}' must list {min_length} file name(s) or more, got {short_repr(value)}"
    )
