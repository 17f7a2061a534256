"""Standard 3DGS ``.ply`` read/write.

Layout (one ``vertex`` element, binary little endian, float32 unless noted)::

    x y z  nx ny nz  f_dc_0..2  f_rest_0..(3(K-1)-1)  opacity  scale_0..2  rot_0..3  [owner:int]

``opacity`` is a logit, ``scale_*`` are natural logs, ``rot_*`` is a wxyz quaternion and
``f_rest`` is channel-major: ``f_rest[c * (K-1) + (k-1)]`` is coefficient ``k`` of channel ``c``.
``owner`` is an extra integer property other tools ignore (absent means background, -1).
"""

from __future__ import annotations

import os
from os import PathLike
from pathlib import Path
from types import MappingProxyType
from typing import Any, NamedTuple, NoReturn, Protocol

import numpy as np
import torch

from particlesplat.core.atomic import atomic_write
from particlesplat.core.errors import UserError, one_line
from particlesplat.core.limits import FLOAT32_MAX_ABS, WORLD_MAX_METRES, reserve_memory
from particlesplat.core.sh import sh_degree_from_bases

_PLY_TYPES = MappingProxyType(
    {
        "char": "i1",
        "int8": "i1",
        "uchar": "u1",
        "uint8": "u1",
        "short": "i2",
        "int16": "i2",
        "ushort": "u2",
        "uint16": "u2",
        "int": "i4",
        "int32": "i4",
        "uint": "u4",
        "uint32": "u4",
        "float": "f4",
        "float32": "f4",
        "double": "f8",
        "float64": "f8",
    }
)
BACKGROUND_OWNER = -1
# Largest particle index an owner may hold: exact in float32 (the viewer's GL buffers) and small enough for
# per-owner tables (the model has a few dozen particles; a .ply owner of 2**31 - 1 would ask for 2**31 rows)
MAX_OWNER = 65535
_EPS = 1e-7
_MAX_HEADER = 1 << 16  # bytes of header: ~1000 property lines, far beyond SH degree 3's 62 properties


class PlyError(UserError):
    """A .ply file that cannot be read; the message names the file and the property."""


class GaussianWriteError(UserError):
    """Gaussians a writer cannot store (a non-finite value, a position beyond a format's range); the message names
    the output file, the field and the first Gaussian at fault. Nothing is written."""


class PlyFields(NamedTuple):
    """What a 3DGS .ply holds, as float32 CPU tensors (N Gaussians, K SH bases), in ``Gaussians`` field order."""

    means: torch.Tensor  # (N, 3) world metres
    quats: torch.Tensor  # (N, 4) wxyz
    scales: torch.Tensor  # (N, 3) linear
    opacities: torch.Tensor  # (N,) in [0, 1]
    sh: torch.Tensor  # (N, K, 3)
    owner: torch.Tensor  # (N,) int64, BACKGROUND_OWNER or a particle index


class GaussianFields(Protocol):
    """What :func:`write_ply` needs of a set of Gaussians (``particlesplat.Gaussians`` has it)."""

    means: torch.Tensor
    quats: torch.Tensor
    scales: torch.Tensor
    opacities: torch.Tensor
    sh: torch.Tensor
    owner: torch.Tensor

    @property
    def num(self) -> int: ...

    def detach(self) -> GaussianFields: ...

    def to(self, device: torch.device | str | None = None, dtype: torch.dtype | None = None) -> GaussianFields: ...


def read_header(f, path: Path) -> tuple[str, list[tuple[str, int, list[tuple[str, str]]]]]:
    """The format (``binary_little_endian`` or ``binary_big_endian``) and the elements, each (name, count,
    [(property, numpy type code)]), of the binary PLY open in ``f``, which is left at the first data byte.
    PlyError names ``path`` and the header line for anything else, and the property and element of a property
    declared twice in one element."""
    first = f.readline(_MAX_HEADER)
    if first.strip() != b"ply":
        raise PlyError(f"{path}: not a PLY file (first line is {first[:20]!r})")
    fmt = None
    elements: list[tuple[str, int, list[tuple[str, str]]]] = []
    while True:
        line = f.readline(_MAX_HEADER)
        if not line:
            raise PlyError(f"{path}: truncated header (no end_header)")
        if f.tell() > _MAX_HEADER:
            raise PlyError(f"{path}: header longer than {_MAX_HEADER} bytes (no end_header)")
        words = line.decode("ascii", errors="replace").split()
        shown = repr(one_line(line.decode("ascii", errors="replace"), 80))  # the line, bounded
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "end_header":
            break
        if words[0] == "format" and len(words) >= 2:
            fmt = words[1]
        elif words[0] == "element":
            if len(words) != 3 or not words[2].isdigit():
                raise PlyError(f"{path}: malformed header line {shown} (expected 'element NAME COUNT')")
            elements.append((words[1], int(words[2]), []))
        elif words[0] == "property":
            if not elements:
                raise PlyError(f"{path}: property before any element")
            if len(words) >= 2 and words[1] == "list":
                raise PlyError(
                    f"{path}: list property '{one_line(words[-1], 40)}' in element "
                    f"'{one_line(elements[-1][0], 40)}' is not supported in a Gaussian .ply"
                )
            if len(words) != 3:
                raise PlyError(f"{path}: malformed header line {shown} (expected 'property TYPE NAME')")
            if words[1] not in _PLY_TYPES:
                raise PlyError(
                    f"{path}: property '{one_line(words[2], 40)}' has unknown type '{one_line(words[1], 40)}'"
                )
            if any(name == words[2] for name, _ in elements[-1][2]):
                raise PlyError(
                    f"{path}: property '{one_line(words[2], 40)}' is declared twice in element "
                    f"'{one_line(elements[-1][0], 40)}'"
                )
            elements[-1][2].append((words[2], _PLY_TYPES[words[1]]))
        else:
            raise PlyError(f"{path}: malformed header line {shown}")
    if fmt not in ("binary_little_endian", "binary_big_endian"):
        raise PlyError(
            f"{path}: format '{one_line(fmt, 40)}' is not supported (binary_little_endian or binary_big_endian)"
        )
    return fmt, elements


def read_ply(path: str | PathLike) -> PlyFields:
    """Read a 3DGS .ply into float32 CPU tensors (``Gaussians.load_ply`` wraps them).

    Raises :class:`PlyError` (naming the file and the property) for a missing property,
    an ``f_rest`` count that is no SH degree, a truncated file, or a non-finite value (but for an
    ``opacity`` logit of ±inf: opacity 1 or 0). Extra properties and any property order are accepted.
    """
    path = Path(path)
    with open(path, "rb") as f:
        n, props, dtype = _vertex_layout(f, path)
        # the count is checked against the bytes the file holds before anything is allocated, and what reading
        # holds (the records, their float64 columns, the tensors) is reserved of the job's memory limit
        available = max(os.fstat(f.fileno()).st_size - f.tell(), 0)
        if n * dtype.itemsize > available:
            _truncated(path, n, props, dtype, available)
        with reserve_memory(_read_bytes(n, props, dtype), f"{path}: {n} vertices"):
            raw = f.read(n * dtype.itemsize)
            if len(raw) < n * dtype.itemsize:
                _truncated(path, n, props, dtype, len(raw))
            return _decode_vertices(raw, n, props, dtype, path)


def _vertex_layout(f, path: Path) -> tuple[int, list[tuple[str, str]], np.dtype]:
    """(vertex count, properties, record dtype) of the 3DGS .ply open in ``f`` (left at its first data byte)."""
    fmt, elements = read_header(f, path)
    order = "<" if fmt == "binary_little_endian" else ">"
    if not elements or elements[0][0] != "vertex":
        raise PlyError(f"{path}: the first element must be 'vertex'")
    _, n, props = elements[0]
    if not props:
        raise PlyError(f"{path}: element 'vertex' has no properties")
    return n, props, np.dtype([(name, order + t) for name, t in props])


def _read_bytes(n: int, props: list[tuple[str, str]], dtype: np.dtype) -> float:
    """Bytes reading ``n`` vertices holds at its peak: the records, a float64 copy of each property and its
    stacked copy, the float32 tensors."""
    return n * (dtype.itemsize + 16.0 * len(props) + 64.0)


def ply_size(path: str | PathLike) -> tuple[int, int, float]:
    """(vertices, SH bases a channel, bytes reading it holds) of the 3DGS .ply at ``path``, from its header alone
    and the file's size (nothing else is read); PlyError names the file for a header :func:`read_ply` would refuse
    or a vertex count the file cannot hold."""
    path = Path(path)
    with open(path, "rb") as f:
        n, props, dtype = _vertex_layout(f, path)
        available = max(os.fstat(f.fileno()).st_size - f.tell(), 0)
    if n * dtype.itemsize > available:
        _truncated(path, n, props, dtype, available)
    rest = sum(1 for name, _ in props if name.startswith("f_rest_"))
    return n, rest // 3 + 1, _read_bytes(n, props, dtype)


def _truncated(path: Path, n: int, props: list[tuple[str, str]], dtype: np.dtype, size: int) -> NoReturn:
    """PlyError: the file holds ``size`` bytes of records where its header declares ``n`` vertices."""
    got, partial = divmod(size, dtype.itemsize)
    fields: dict[str, Any] = dict(dtype.fields or {})  # a structured dtype: name -> (dtype, byte offset)
    first_missing = next(name for name, _ in props if fields[name][1] + dtype[name].itemsize > partial)
    raise PlyError(
        f"{path}: truncated: header declares {n} vertices ({n * dtype.itemsize} bytes), "
        f"file holds {size} bytes (vertex {got}, property '{first_missing}' onwards missing)"
    )


def _decode_vertices(raw: bytes, n: int, props: list[tuple[str, str]], dtype: np.dtype, path: Path) -> PlyFields:
    """The Gaussians of ``n`` records of ``dtype`` (the properties ``props``) read from ``path``."""
    data = np.frombuffer(raw, dtype=dtype, count=n)
    names = {name for name, _ in props}

    def column(name: str) -> np.ndarray:
        if name not in names:
            raise PlyError(f"{path}: missing property '{name}' in element 'vertex'")
        col = data[name].astype(np.float64)
        # an opacity logit of ±inf is an opacity of exactly 1 or 0 (tools that quantise opacity write them)
        bad = np.isnan(col) if name == "opacity" else ~np.isfinite(col)
        if bad.any():
            raise PlyError(f"{path}: property '{name}' has a non-finite value at vertex {int(np.argmax(bad))}")
        return col

    def stack(prefix: str, count: int) -> np.ndarray:
        return np.stack([column(f"{prefix}{i}") for i in range(count)], axis=-1) if count else np.zeros((n, 0))

    n_rest = sum(1 for name in names if name.startswith("f_rest_"))
    if n_rest % 3 != 0:
        raise PlyError(f"{path}: property 'f_rest_*' count {n_rest} is not a multiple of 3")
    try:
        sh_degree_from_bases(n_rest // 3 + 1)
    except ValueError:
        raise PlyError(
            f"{path}: property 'f_rest_*' count {n_rest} is no SH degree (expected 0, 9, 24 or 45)"
        ) from None
    k = n_rest // 3 + 1
    means = np.stack([column("x"), column("y"), column("z")], axis=-1)
    dc = stack("f_dc_", 3)
    rest = stack("f_rest_", n_rest).reshape(n, 3, k - 1).transpose(0, 2, 1)
    sh = np.concatenate([dc[:, None, :], rest], axis=1)
    opacities = np.exp(-np.logaddexp(0.0, -column("opacity")))  # sigmoid without overflow
    log_scales = stack("scale_", 3)
    too_big = log_scales > np.log(np.finfo(np.float32).max)
    if too_big.any():
        vertex, axis = (int(i) for i in np.argwhere(too_big)[0])
        raise PlyError(
            f"{path}: property 'scale_{axis}' at vertex {vertex} is exp({log_scales[vertex, axis]:.4g}), beyond float32"
        )
    quats = stack("rot_", 4)
    problem = range_problem(path, means, log_scales, {"quats": quats, "opacities": opacities, "sh": sh}, "vertex")
    if problem:
        raise PlyError(problem)
    scales = np.exp(log_scales)
    if "owner" in names:
        owner = _owner_column(data["owner"], path)
    else:
        owner = np.full(n, BACKGROUND_OWNER, dtype=np.int64)
    f32 = lambda a: torch.from_numpy(np.ascontiguousarray(a, dtype=np.float32))  # noqa: E731
    return PlyFields(f32(means), f32(quats), f32(scales), f32(opacities), f32(sh), torch.from_numpy(owner))


def range_problem(
    path: str | PathLike, means: np.ndarray, log_scales: np.ndarray, others: dict[str, np.ndarray], item: str
) -> str | None:
    """What keeps decoded Gaussians (float64 arrays, before their cast to float32) from being held, as one line
    naming ``path``, the field and the first ``item`` (``Gaussian``, ``vertex``) at fault; None when nothing does.

    ``means`` (N, 3) metres and ``log_scales`` (N, 3) natural logs of metres must lie within
    :data:`~particlesplat.core.limits.WORLD_MAX_METRES` (where float32 keeps millimetres: 8.4e6 m or 1e30 would
    render as a point or a degenerate camera); every field of ``others`` (name -> (N, ...) values) within
    +-:data:`~particlesplat.core.limits.FLOAT32_MAX_ABS` (a value past float32 becomes inf in the cast). Every
    value must be finite. Only comparisons: no numpy warning is raised."""
    for name, col in {"means": means, "scales": log_scales, **others}.items():
        flat = col.reshape(len(col), -1) if col.size else col.reshape(len(col), 0)
        bad = ~np.isfinite(flat)
        if bad.any():
            return f"{path}: {name}: non-finite value at {item} {int(np.argwhere(bad.any(1))[0, 0])}"
    bad = np.abs(means) > WORLD_MAX_METRES
    if bad.any():
        row, k = (int(i) for i in np.argwhere(bad)[0])
        return (
            f"{path}: means: {means[row, k]:.4g} m at {item} {row} is beyond the +-{WORLD_MAX_METRES:g} m a position "
            "may hold (float32 keeps millimetres within it); translate the scene near the origin"
        )
    bad = log_scales > np.log(WORLD_MAX_METRES)
    if bad.any():
        row, k = (int(i) for i in np.argwhere(bad)[0])
        return (
            f"{path}: scales: exp({log_scales[row, k]:.4g}) m at {item} {row} is beyond the {WORLD_MAX_METRES:g} m "
            "a Gaussian's size may hold"
        )
    for name, col in others.items():
        flat = col.reshape(len(col), -1) if col.size else col.reshape(len(col), 0)
        bad = np.abs(flat) > FLOAT32_MAX_ABS
        if bad.any():
            row, k = (int(i) for i in np.argwhere(bad)[0])
            return (
                f"{path}: {name}: {flat[row, k]:.4g} at {item} {row} is beyond +-{FLOAT32_MAX_ABS:g} (float32 "
                "arithmetic on it overflows)"
            )
    return None


def _owner_column(col: np.ndarray, path: Path) -> np.ndarray:
    """The ``owner`` property as int64: each value -1 (background) or a particle index 0..MAX_OWNER.

    Anything else (NaN, a fraction, -5, 2**31 - 1) is refused rather than drawn by one renderer and
    dropped by another, or turned into a table of 2**31 rows."""
    wide = col.astype(np.float64)
    bad = ~(np.isfinite(wide) & (wide == np.round(wide)) & (wide >= BACKGROUND_OWNER) & (wide <= MAX_OWNER))
    if bad.any():
        vertex = int(np.argmax(bad))
        value = col[vertex].item()  # a plain int or float (NaN included) in the message
        raise PlyError(
            f"{path}: property 'owner' at vertex {vertex} is {value!r}: expected -1 (background) "
            f"or a particle index 0..{MAX_OWNER}"
        )
    return wide.astype(np.int64)


def finite_float64(gaussians: GaussianFields, path: str | PathLike) -> GaussianFields:
    """``gaussians`` as float64 on the CPU, for writing to ``path``; GaussianWriteError naming the file, the field
    and the first bad Gaussian for a non-finite value (nothing is written)."""
    g = gaussians.detach().to("cpu", torch.float64)
    for name in ("means", "quats", "scales", "opacities", "sh"):
        bad = ~torch.isfinite(getattr(g, name))
        if bool(bad.any()):
            row = int(bad.reshape(bad.shape[0], -1).any(1).nonzero()[0, 0])
            raise GaussianWriteError(f"{path}: cannot write Gaussians.{name}: non-finite value at Gaussian {row}")
    return g


def write_ply(gaussians: GaussianFields, path: str | PathLike) -> None:
    """Write ``gaussians`` as a binary little-endian 3DGS .ply, atomically (temp file + rename).

    Opacities are clamped to [1e-7, 1 - 1e-7] and scales to >= 1e-30 so that the logit and
    the log stay finite. Non-finite values raise GaussianWriteError (the reader would reject the file)
    and leave an existing file untouched.
    """
    path = Path(path)
    g = finite_float64(gaussians, path)
    n, k = g.num, g.sh.shape[1]
    sh = g.sh.numpy()
    props: list[tuple[str, np.ndarray]] = [
        ("x", g.means[:, 0].numpy()),
        ("y", g.means[:, 1].numpy()),
        ("z", g.means[:, 2].numpy()),
    ]
    props += [(f"n{a}", np.zeros(n)) for a in "xyz"]
    props += [(f"f_dc_{c}", sh[:, 0, c]) for c in range(3)]
    rest = sh[:, 1:, :].transpose(0, 2, 1).reshape(n, 3 * (k - 1))
    props += [(f"f_rest_{i}", rest[:, i]) for i in range(3 * (k - 1))]
    o = np.clip(g.opacities.numpy(), _EPS, 1.0 - _EPS)
    props.append(("opacity", np.log(o) - np.log1p(-o)))
    log_s = np.log(np.maximum(g.scales.numpy(), 1e-30))
    props += [(f"scale_{i}", log_s[:, i]) for i in range(3)]
    props += [(f"rot_{i}", g.quats[:, i].numpy()) for i in range(4)]
    dtype = np.dtype([(name, "<f4") for name, _ in props] + [("owner", "<i4")])
    rec = np.empty(n, dtype=dtype)
    for name, col in props:
        rec[name] = col
    rec["owner"] = g.owner.numpy()
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {n}"]
    header += [f"property float {name}" for name, _ in props] + ["property int owner", "end_header"]
    with atomic_write(path, "wb") as f:
        f.write(("\n".join(header) + "\n").encode("ascii"))
        f.write(rec.tobytes())
