"""The antimatter15 ``.splat`` format: 32 bytes a Gaussian, no header, no SH beyond the base colour.

Each record, little endian::

    x y z          float32 x 3   world position
    sx sy sz       float32 x 3   scales (linear standard deviations, not logs)
    r g b a        uint8 x 4     colour (SH_C0 * dc + 0.5) * 255 clipped to [0, 255], opacity * 255
    qw qx qy qz    uint8 x 4     unit quaternion q * 128 + 128 clipped to [0, 255]

The colour is the view-independent one (higher SH bands are dropped) and clipped to [0, 1]. Readers decode a
rotation byte as ``(b - 128) / 128`` (antimatter15) or ``b / 255 * 2 - 1`` (PlayCanvas) and normalise; both are
the same rotation to within a step.
"""

from __future__ import annotations

import os
from os import PathLike
from pathlib import Path

import numpy as np

from particlesplat.core.atomic import atomic_write
from particlesplat.core.sh import SH_C0
from particlesplat.formats.ply import GaussianFields, PlyFields
from particlesplat.formats.splat_arrays import (
    LOG_SCALE_FLOOR,
    SplatArrays,
    SplatFileError,
    background_owner,
    decode_bytes,
    decoding,
    splat_arrays,
    to_fields,
    unit_quats,
)

RECORD = np.dtype([("pos", "<f4", 3), ("scale", "<f4", 3), ("rgba", "u1", 4), ("rot", "u1", 4)])
assert RECORD.itemsize == 32


def encode_splat(a: SplatArrays) -> bytes:
    """The bytes of a ``.splat`` file holding ``a`` (in its order)."""
    rec = np.zeros(a.num, dtype=RECORD)
    rec["pos"] = a.means
    rec["scale"] = np.exp(a.log_scales)
    colour = SH_C0 * a.sh[:, 0, :] + 0.5
    rec["rgba"][:, :3] = np.clip(np.rint(colour * 255.0), 0, 255)
    rec["rgba"][:, 3] = np.clip(np.rint(a.opacities * 255.0), 0, 255)
    rec["rot"] = np.clip(np.rint(a.quats * 128.0 + 128.0), 0, 255)
    return rec.tobytes()


def write_splat(gaussians: GaussianFields, path: str | PathLike) -> None:
    """Write ``gaussians`` as a ``.splat`` file, atomically; GaussianWriteError (naming the file) for non-finite
    values."""
    data = encode_splat(splat_arrays(gaussians, path))
    with atomic_write(Path(path), "wb") as f:
        f.write(data)


def _check_size(size: int, path: str | PathLike) -> None:
    if size % RECORD.itemsize:
        raise SplatFileError(
            f"{path}: size {size} bytes is not a multiple of the .splat record ({RECORD.itemsize} bytes): "
            "truncated, or not a .splat file"
        )


def decode_splat(data: bytes, path: str | PathLike) -> SplatArrays:
    """The Gaussians of ``.splat`` bytes; SplatFileError names ``path`` when the size is no whole record count."""
    _check_size(len(data), path)
    rec = np.frombuffer(data, dtype=RECORD)
    n = len(rec)
    scales = rec["scale"].astype(np.float64)
    bad = ~(scales >= 0)  # NaN and negative sizes alike
    if bad.any():
        row = int(np.argwhere(bad.any(1))[0, 0])
        raise SplatFileError(f"{path}: scale at Gaussian {row} is {scales[row].tolist()}: expected sizes >= 0")
    with np.errstate(divide="ignore"):
        log_scales = np.log(scales)
    rgba = rec["rgba"].astype(np.float64) / 255.0
    sh = ((rgba[:, :3] - 0.5) / SH_C0)[:, None, :]
    return SplatArrays(
        means=rec["pos"].astype(np.float64),
        quats=unit_quats(rec["rot"].astype(np.float64) - 128.0),
        log_scales=np.maximum(log_scales, LOG_SCALE_FLOOR),
        opacities=rgba[:, 3],
        sh=sh,
        owner=background_owner(n),
    )


def read_splat(path: str | PathLike) -> PlyFields:
    """Read a ``.splat`` file (see the module docstring) into float32 tensors: sized from the file's size (its
    bytes and the decoding's arrays reserved of the job's memory first), then read to that size."""
    path = Path(path)
    with open(path, "rb") as f:
        size = os.fstat(f.fileno()).st_size
        _check_size(size, path)  # before reading the file
        count = size // RECORD.itemsize
        with decoding(decode_bytes(count, 1) + size, f"{path}: {count} records"):
            return to_fields(decode_splat(f.read(size), path), path)
