"""The fields of an edit file's operations: how each is read (checked, with errors that name the field) and
written. The document around them is :mod:`particlesplat.editing.edit_file`; each operation's record is its class's
(:mod:`particlesplat.editing.operations`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from particlesplat.core.errors import short_repr
from particlesplat.core.limits import FLOAT32_MAX_ABS, FLOAT32_MIN_POSITIVE, float32_problem
from particlesplat.editing.particle_edits import EditsError, finite_float32

DECIMALS = 6  # offsets and places are written rounded to micrometres


class PickError(EditsError):
    """A pick hits no object (or names a frame or pixel the scene does not have)."""


@dataclass(frozen=True)
class Pick:
    """The object under ``pixel`` (x, y: column, row of the stored image) of input frame ``frame``."""

    frame: int
    pixel: tuple[int, int]


def read_numbers(value: Any, n: int, where: str) -> tuple[float, ...]:
    """``n`` finite numbers (float32 range); a bare number is accepted for ``n`` = 1."""
    seq = value if isinstance(value, (list, tuple)) else [value]
    if len(seq) != n or any(
        isinstance(v, bool) or not isinstance(v, (int, float)) or not finite_float32(v) for v in seq
    ):
        raise EditsError(
            f"{where}: expected {n} finite number(s) (float32: |value| <= 3.4e38), got {short_repr(value)}"
        )
    return tuple(float(v) for v in seq)


def read_positive(value: Any, where: str) -> float:
    """A positive number usable in float32 arithmetic: in [1e-18, 1e18], the bounds every positive number read from
    a file is held to (:func:`particlesplat.core.limits.float32_problem`); 1e-30 is refused, not turned into a
    Gaussian that vanishes in float32."""
    (x,) = read_numbers(value, 1, where)
    problem = float32_problem(x, positive=True)
    if problem:
        raise EditsError(
            f"{where}: expected a positive number in [{FLOAT32_MIN_POSITIVE:g}, {FLOAT32_MAX_ABS:g}], "
            f"got {short_repr(value)} ({problem})"
        )
    return x


def read_index(value: Any, where: str) -> int:
    """A non-negative integer (a particle, frame, object or pixel coordinate)."""
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise EditsError(f"{where}: expected a non-negative integer, got {short_repr(value)}")
    return int(value)


def read_pick(value: Any, where: str) -> Pick:
    """``{frame: F, pixel: [x, y]}``; ``where`` names the field (``...pick``)."""
    if not isinstance(value, dict) or set(value) != {"frame", "pixel"}:
        raise EditsError(f"{where}: expected {{frame: F, pixel: [x, y]}}, got {short_repr(value)}")
    pixel = value["pixel"]
    if not isinstance(pixel, (list, tuple)) or len(pixel) != 2:
        raise EditsError(f"{where}.pixel: expected [x, y], got {short_repr(pixel)}")
    return Pick(
        read_index(value["frame"], f"{where}.frame"),
        (read_index(pixel[0], f"{where}.pixel"), read_index(pixel[1], f"{where}.pixel")),
    )


def pick_yaml(pick: Pick) -> dict[str, Any]:
    """The YAML mapping of a pick (inverse of :func:`read_pick`)."""
    return {"frame": int(pick.frame), "pixel": [int(pick.pixel[0]), int(pick.pixel[1])]}


def rounded(values: tuple[float, ...] | list[float]) -> list[float]:
    """Metres as written: rounded to :data:`DECIMALS`."""
    return [round(float(v), DECIMALS) for v in values]


def read_frames(value: Any, where: str) -> tuple[int, ...]:
    """A non-empty list of frame indices."""
    if (
        not isinstance(value, list)
        or not value
        or not all(isinstance(c, int) and not isinstance(c, bool) and c >= 0 for c in value)
    ):
        raise EditsError(f"{where}: expected a list of frame indices, got {short_repr(value)}")
    return tuple(value)


@dataclass(frozen=True)
class Insert:
    """Object ``object`` of scene folder ``scene`` (encoded from ``context``, None = the default frames; objects
    numbered as ``particlesplat encode``'s ``object`` array) placed with its centre at ``at`` (x, y) world
    metres on the edited scene's floor (:func:`particlesplat.editing.compose.insert_object`)."""

    scene: str
    object: int
    at: tuple[float, float]
    context: tuple[int, ...] | None = None


def read_insert(spec: Any, where: str) -> Insert:
    """``{scene: DIR, object: K, at: [x, y], context: [..] (optional)}``; ``where`` names the field."""
    if (
        not isinstance(spec, dict)
        or not {"scene", "object", "at"} <= set(spec)
        or set(spec) - {"scene", "object", "at", "context"}
    ):
        raise EditsError(
            f"{where}: expected {{scene: DIR, object: K, at: [x, y], context: [..] (optional)}}, got {short_repr(spec)}"
        )
    if not isinstance(spec["scene"], str) or not spec["scene"]:
        raise EditsError(f"{where}.scene: expected a scene folder, got {short_repr(spec['scene'])}")
    context = spec.get("context")
    at = read_numbers(spec["at"], 2, f"{where}.at")
    return Insert(
        spec["scene"],
        read_index(spec["object"], f"{where}.object"),
        (at[0], at[1]),
        None if context is None else read_frames(context, f"{where}.context"),
    )


def insert_yaml(insert: Insert) -> dict[str, Any]:
    """The YAML mapping of an insert (inverse of :func:`read_insert`)."""
    spec: dict[str, Any] = {"scene": insert.scene, "object": int(insert.object), "at": rounded(insert.at)}
    if insert.context is not None:
        spec["context"] = [int(c) for c in insert.context]
    return spec
