"""Particle edits: particle index -> absolute values of editable attributes, and the version 1 edit file that
holds them (read by :func:`particlesplat.editing.editor.load_edit_file`; this version writes version 2).

File format (``version: 1``)::

    version: 1
    particles:
      3:
        z_p: [0.12, -0.40]   # image-plane position (x, y) in [-1, 1] of the particle's view
        z_d: [0.8]           # depth logit
      5:
        z_t: [0.0]           # transparency (0 hides the particle)

Optional informational keys (``model``, ``scene``) are kept but not interpreted. Values are
the attribute values to set, with the widths of :data:`particlesplat.model.particles.EDITABLE`
(a bare number is accepted for width-1 attributes).
"""

from __future__ import annotations

import math
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np

from particlesplat.core.errors import UserError, one_line, short_repr
from particlesplat.core.yamlsafe import YamlError, read_yaml
from particlesplat.model.particles import EDITABLE, Particles

FORMAT_VERSION = 1
FLOAT32_MAX = float(np.finfo(np.float32).max)  # edited values are stored as float32

Edits = dict[int, dict[str, tuple[float, ...]]]


class EditsError(UserError):
    """An edits file or mapping is invalid; the message names the file and the field."""


def as_float(v: int | float) -> float:
    """``float(v)``, inf for an integer beyond float64 (instead of OverflowError)."""
    try:
        return float(v)
    except OverflowError:
        return math.inf


def finite_float32(v: int | float) -> bool:
    """True when ``v`` stays finite as float32 (the particles' dtype): a value finite in float64 but beyond
    float32 would become inf and make the particle vanish."""
    return abs(as_float(v)) <= FLOAT32_MAX


def validate_edits(data: Any, where: str = "edits") -> Edits:
    """Check a parsed edits document (or a bare ``particles`` mapping) and normalise it."""
    if isinstance(data, dict) and "particles" in data:
        version = data.get("version", FORMAT_VERSION)
        if version != FORMAT_VERSION:
            raise EditsError(f"{where}: version: expected {FORMAT_VERSION}, got {short_repr(version)}")
        unknown = set(data) - {"version", "particles", "model", "scene"}
        if unknown:
            raise EditsError(
                f"{where}: unknown key(s) {short_repr(sorted(map(str, unknown)))} "
                "(expected version, particles, model, scene)"
            )
        data = data["particles"]
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise EditsError(
            f"{where}: particles: expected a mapping of particle index -> attributes, got {type(data).__name__}"
        )
    out: Edits = {}
    for key, attrs in data.items():
        field = f"{where}: particles.{one_line(key, 40)}"
        if isinstance(key, bool) or not isinstance(key, int):
            try:
                index = int(str(key))
            except ValueError:
                raise EditsError(f"{field}: particle index must be a non-negative integer") from None
        else:
            index = key
        if index < 0:
            raise EditsError(f"{field}: particle index must be a non-negative integer")
        if index in out:
            raise EditsError(f"{field}: particle {index} is listed twice")
        if not isinstance(attrs, dict):
            raise EditsError(f"{field}: expected a mapping of attribute -> values, got {type(attrs).__name__}")
        values: dict[str, tuple[float, ...]] = {}
        for name, value in attrs.items():
            if name not in EDITABLE:
                raise EditsError(
                    f"{field}.{one_line(name, 40)}: not an editable attribute (one of {', '.join(EDITABLE)})"
                )
            seq = value if isinstance(value, (list, tuple)) else [value]
            if len(seq) != EDITABLE[name]:
                raise EditsError(f"{field}.{name}: expected {EDITABLE[name]} number(s), got {len(seq)}")
            nums = []
            for v in seq:
                if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(as_float(v)):
                    raise EditsError(f"{field}.{name}: expected finite numbers, got {short_repr(value)}")
                if not finite_float32(v):
                    raise EditsError(f"{field}.{name}: {float(v):g} is beyond float32 (|value| <= {FLOAT32_MAX:.4g})")
                nums.append(float(v))
            if name == "z_t" and not 0.0 <= nums[0] <= 1.0:
                raise EditsError(f"{field}.z_t: transparency must be in [0, 1], got {nums[0]}")
            values[name] = tuple(nums)
        if values:
            out[index] = values
    return out


def read_edit_document(path: str | PathLike) -> Any:
    """The parsed YAML of an edits file, any version (:func:`particlesplat.core.yamlsafe.read_yaml`: safe tags, no
    aliases, no duplicate keys); a file that cannot be read is an :class:`EditsError` naming it."""
    try:
        return read_yaml(Path(path), "edits file")
    except YamlError as e:
        raise EditsError(str(e)) from None


def check_indices(edits: Edits, num_particles: int, where: str = "edits") -> None:
    """Raise EditsError if an edit names a particle index >= ``num_particles``."""
    for index in edits:
        if index >= num_particles:
            raise EditsError(f"{where}: particles.{index}: no such particle (the scene has {num_particles})")


def apply_edits(particles: Particles, edits: Edits, where: str = "edits") -> Particles:
    """A copy of ``particles`` with the edited attribute values set."""
    check_indices(edits, particles.num, where)
    for index, attrs in edits.items():
        for name, value in attrs.items():
            particles = particles.with_attribute(index, name, value)
    return particles


def diff_edits(original: Particles, current: Particles, atol: float = 0.0) -> Edits:
    """The edits that turn ``original`` into ``current`` (attributes that differ by > atol)."""
    out: Edits = {}
    for name in EDITABLE:
        a, b = getattr(original, name).detach().cpu(), getattr(current, name).detach().cpu()
        changed = ((a - b).abs() > atol).any(dim=-1).nonzero().flatten().tolist()
        for index in changed:
            out.setdefault(int(index), {})[name] = tuple(float(x) for x in b[index].tolist())
    return out
