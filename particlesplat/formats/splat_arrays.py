"""Gaussians as float64 numpy arrays: what every splat file writer starts from and every reader ends with.

The writers of the compact formats (:mod:`.splat`, :mod:`.spz`, :mod:`.compressed_ply`, :mod:`.sog`) quantise
these arrays; their readers rebuild them and hand them on as :class:`particlesplat.formats.ply.PlyFields`, the
float32 tensors ``Gaussians(*fields)`` takes. Conventions are the INRIA ``.ply``'s: a wxyz quaternion, natural-log
scales, an opacity in [0, 1] (stored as a logit in a ``.ply``), SH coefficients (N, K, 3) with the colour
``SH_C0 * dc + 0.5`` for degree 0.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from os import PathLike

import numpy as np
import torch

from particlesplat.core.errors import UserError
from particlesplat.core.limits import reserve_memory
from particlesplat.core.sh import sh_degree_from_bases
from particlesplat.formats.ply import BACKGROUND_OWNER, GaussianFields, PlyFields, finite_float64, range_problem

MIN_SCALE = 1e-30  # a zero scale is written as this (as write_ply does), so that its log is finite
LOG_SCALE_FLOOR = float(np.log(MIN_SCALE))


class SplatFileError(UserError):
    """A splat file (``.splat``, ``.spz``, ``.compressed.ply``, ``.sog``) that cannot be read; the message names
    the file and the field."""


@dataclass
class SplatArrays:
    """N Gaussians as float64 arrays (owner int64).

    Attributes:
        means: (N, 3) world metres.
        quats: (N, 4) unit wxyz quaternions (a zero quaternion becomes the identity).
        log_scales: (N, 3) natural logs of the standard deviations (metres).
        opacities: (N,) in [0, 1].
        sh: (N, K, 3) SH coefficients, K = (degree + 1)^2.
        owner: (N,) particle index, -1 for background (only the ``.ply`` stores it; others read as -1).
    """

    means: np.ndarray
    quats: np.ndarray
    log_scales: np.ndarray
    opacities: np.ndarray
    sh: np.ndarray
    owner: np.ndarray

    @property
    def num(self) -> int:
        return int(self.means.shape[0])

    @property
    def sh_degree(self) -> int:
        return sh_degree_from_bases(self.sh.shape[1])

    def take(self, index: np.ndarray) -> SplatArrays:
        """The Gaussians at ``index`` (an index array or a bool mask), in that order."""
        return SplatArrays(*(getattr(self, f)[index] for f in _FIELDS))


_FIELDS = ("means", "quats", "log_scales", "opacities", "sh", "owner")


def unit_quats(q: np.ndarray) -> np.ndarray:
    """(N, 4) quaternions divided by their norm; a zero quaternion becomes the identity (1, 0, 0, 0)."""
    q = np.asarray(q, dtype=np.float64)
    norm = np.linalg.norm(q, axis=1, keepdims=True)
    out = np.where(norm > 0, q / np.where(norm > 0, norm, 1.0), 0.0)
    out[norm[:, 0] == 0, 0] = 1.0
    return out


def splat_arrays(gaussians: GaussianFields, path: str | PathLike) -> SplatArrays:
    """The arrays of ``gaussians`` for writing to ``path``; GaussianWriteError naming ``path``, the field and the
    first bad Gaussian for a non-finite value (nothing is written)."""
    g = finite_float64(gaussians, path)
    return SplatArrays(
        means=g.means.numpy(),
        quats=unit_quats(g.quats.numpy()),
        log_scales=np.log(np.maximum(g.scales.numpy(), MIN_SCALE)),
        opacities=np.clip(g.opacities.numpy(), 0.0, 1.0),
        sh=g.sh.numpy(),
        owner=g.owner.numpy().astype(np.int64),
    )


def to_fields(arrays: SplatArrays, path: str | PathLike) -> PlyFields:
    """Float32 tensors of decoded ``arrays`` (what ``Gaussians(*fields)`` takes), the one conversion every compact
    format's reader ends with. Before anything is cast, every field is held to what float32 and the world keep
    (:func:`particlesplat.formats.ply.range_problem`: finite; positions and scales within the world limit; the
    rest within +-1e18): SplatFileError names ``path`` (the input), the field and the Gaussian, and no numpy
    warning is printed."""
    problem = range_problem(
        path,
        arrays.means,
        arrays.log_scales,
        {"quats": arrays.quats, "opacities": arrays.opacities, "sh": arrays.sh},
        "Gaussian",
    )
    if problem:
        raise SplatFileError(problem)

    def f32(a: np.ndarray) -> torch.Tensor:
        return torch.from_numpy(np.ascontiguousarray(a, dtype=np.float32))

    owner = np.asarray(arrays.owner, dtype=np.int64)
    with np.errstate(under="ignore"):  # a scale of exp(-69) m is a flat Gaussian, not an error
        scales = np.exp(arrays.log_scales)
    return PlyFields(
        f32(arrays.means),
        f32(arrays.quats),
        f32(scales),
        f32(np.clip(arrays.opacities, 0.0, 1.0)),
        f32(arrays.sh),
        torch.from_numpy(np.ascontiguousarray(owner)),
    )


def decode_bytes(count: int, bases: int) -> float:
    """Bytes that decoding ``count`` Gaussians of ``bases`` SH bases a channel holds at its peak: float64 arrays,
    their float32 copies and temporaries, ~(300 + 80 bases) bytes each."""
    return count * (300.0 + 80.0 * bases)


@contextmanager
def decoding(estimate: float, what: str) -> Iterator[None]:
    """The block a compact format's reader reads and decodes in: ``estimate`` bytes (everything the file makes it
    hold, sized from its headers: :func:`decode_bytes` plus the bytes it reads) reserved of the job's memory
    limit (:func:`particlesplat.core.limits.reserve_memory`; BudgetError names ``what``, which starts with the
    file), and numpy's floating-point warnings off: a value that overflows in decoding is refused by name in
    :func:`to_fields`, never printed as a RuntimeWarning."""
    with reserve_memory(estimate, what), np.errstate(all="ignore"):
        yield


def background_owner(n: int) -> np.ndarray:
    """(n,) owners of Gaussians from a file that stores none: all background."""
    return np.full(n, BACKGROUND_OWNER, dtype=np.int64)


def sigmoid(x: np.ndarray) -> np.ndarray:
    """Elementwise logistic function without overflow (±inf give 1 and 0)."""
    return np.exp(-np.logaddexp(0.0, -np.asarray(x, dtype=np.float64)))


def largest_component(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For (N, 4) unit quaternions: the index (N,) of each one's largest |component| and the quaternion with
    its sign flipped so that component is >= 0 (q and -q are the same rotation)."""
    idx = np.argmax(np.abs(q), axis=1)
    sign = np.where(q[np.arange(len(q)), idx] < 0, -1.0, 1.0)
    return idx, q * sign[:, None]


def others_of(largest: np.ndarray) -> np.ndarray:
    """(N, 3) the three component indices other than ``largest`` (N,), ascending."""
    table = np.array([[j for j in range(4) if j != i] for i in range(4)])
    return table[largest]
