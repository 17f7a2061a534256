"""PlayCanvas's compressed ``.ply``: Gaussians in chunks of 256, 16 bytes each plus 1 byte a higher SH coefficient.

A binary little-endian PLY with three elements:

- ``chunk`` (ceil(N / 256) rows, float32): per chunk the bounds ``min_x min_y min_z max_x max_y max_z``, the
  log-scale bounds ``min_scale_x .. max_scale_z`` and the colour bounds ``min_r min_g min_b max_r max_g max_b``
  (colour = ``SH_C0 * dc + 0.5``);
- ``vertex`` (N rows, uint32): ``packed_position`` (x, y, z on 11, 10, 11 bits from the top, each the fraction of
  the way from its chunk's min to max), ``packed_rotation`` (smallest three of the unit wxyz quaternion: the
  largest component's index in bits 30-31, the other three in ascending order on 10 bits each from bit 20 down,
  ``c / sqrt(2) + 0.5``), ``packed_scale`` (log scales as positions), ``packed_color`` (r, g, b, opacity on
  8 bits each from the top; the colour within its chunk's bounds, the opacity absolute);
- ``sh`` (N rows, uint8, only for SH degree > 0): ``f_rest_*`` in the ``.ply``'s order, ``floor((c / 8 + 0.5) *
  256)`` clipped to [0, 255], read back as ``((b + 0.5) / 256 - 0.5) * 8`` (0 and 255 as the ends, ±4).

Gaussian i belongs to chunk i // 256. The writer orders the Gaussians along a Morton curve first so that a chunk
is spatially small (:func:`morton_order`); opacity 0 is stored exactly, which a reader turns into a logit of -inf.
"""

from __future__ import annotations

import os
from os import PathLike
from pathlib import Path

import numpy as np

from particlesplat.core.atomic import atomic_write
from particlesplat.core.errors import one_line
from particlesplat.core.sh import SH_C0, sh_degree_from_bases
from particlesplat.formats.ply import GaussianFields, PlyError, PlyFields, read_header
from particlesplat.formats.splat_arrays import (
    SplatArrays,
    SplatFileError,
    background_owner,
    decode_bytes,
    decoding,
    largest_component,
    others_of,
    splat_arrays,
    to_fields,
)

CHUNK = 256
BOUNDS = (
    "min_x min_y min_z max_x max_y max_z min_scale_x min_scale_y min_scale_z max_scale_x max_scale_y max_scale_z "
    "min_r min_g min_b max_r max_g max_b"
).split()
PACKED = ("packed_position", "packed_rotation", "packed_scale", "packed_color")
LOG_SCALE_CLAMP = 20.0  # log scales are clamped to ±20 before their chunk bounds are taken
_SQRT2 = np.sqrt(2.0)


def morton_order(means: np.ndarray) -> np.ndarray:
    """(N,) stable order of (N, 3) positions along a 3D Morton (Z-order) curve of 1024 cells a side."""
    if len(means) == 0:
        return np.zeros(0, dtype=np.int64)
    lo, hi = means.min(0), means.max(0)
    cell = np.clip(((means - lo) / np.where(hi > lo, hi - lo, 1.0) * 1023.0).astype(np.int64), 0, 1023)
    code = np.zeros(len(means), dtype=np.int64)
    for bit in range(10):
        for axis in range(3):
            code |= ((cell[:, axis] >> bit) & 1) << (3 * bit + (2 - axis))
    return np.argsort(code, kind="stable")


def _unorm(value: np.ndarray, lo: np.ndarray, hi: np.ndarray, bits: int) -> np.ndarray:
    t = np.where(hi > lo, (value - lo) / np.where(hi > lo, hi - lo, 1.0), 0.0)
    return np.clip(np.rint(t * ((1 << bits) - 1)), 0, (1 << bits) - 1).astype(np.uint32)


def _pack_111011(v: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    return (
        (_unorm(v[:, 0], lo[:, 0], hi[:, 0], 11) << 21)
        | (_unorm(v[:, 1], lo[:, 1], hi[:, 1], 10) << 11)
        | (_unorm(v[:, 2], lo[:, 2], hi[:, 2], 11))
    )


def _chunk_bounds(values: np.ndarray, chunks: np.ndarray, num_chunks: int) -> tuple[np.ndarray, np.ndarray]:
    lo = np.full((num_chunks, values.shape[1]), np.inf)
    hi = np.full((num_chunks, values.shape[1]), -np.inf)
    np.minimum.at(lo, chunks, values)
    np.maximum.at(hi, chunks, values)
    return lo, hi


def encode_compressed_ply(a: SplatArrays) -> bytes:
    """The bytes of a compressed ``.ply`` holding ``a`` in its order (the caller orders it: :func:`morton_order`)."""
    n = a.num
    num_chunks = -(-n // CHUNK)
    chunks = np.arange(n) // CHUNK
    log_s = np.clip(a.log_scales, -LOG_SCALE_CLAMP, LOG_SCALE_CLAMP)
    colour = SH_C0 * a.sh[:, 0, :] + 0.5
    p_lo, p_hi = _chunk_bounds(a.means, chunks, num_chunks)
    s_lo, s_hi = _chunk_bounds(log_s, chunks, num_chunks)
    c_lo, c_hi = _chunk_bounds(colour, chunks, num_chunks)
    bounds = np.concatenate([p_lo, p_hi, s_lo, s_hi, c_lo, c_hi], axis=1).astype("<f4")
    # the bounds are stored as float32: quantise against the stored values
    b64 = bounds.astype(np.float64)
    p_lo, p_hi, s_lo, s_hi, c_lo, c_hi = (b64[:, 3 * i : 3 * i + 3][chunks] for i in range(6))
    vertex = np.zeros((n, 4), dtype="<u4")
    vertex[:, 0] = _pack_111011(a.means, p_lo, p_hi)
    largest, q = largest_component(a.quats)
    others = others_of(largest)
    rot = largest.astype(np.uint32) << 30
    for slot in range(3):
        c = q[np.arange(n), others[:, slot]]
        rot |= np.clip(np.rint((c / _SQRT2 + 0.5) * 1023.0), 0, 1023).astype(np.uint32) << (10 * (2 - slot))
    vertex[:, 1] = rot
    vertex[:, 2] = _pack_111011(log_s, s_lo, s_hi)
    rgb = [_unorm(colour[:, i], c_lo[:, i], c_hi[:, i], 8) for i in range(3)]
    alpha = np.clip(np.rint(a.opacities * 255.0), 0, 255).astype(np.uint32)
    vertex[:, 3] = (rgb[0] << 24) | (rgb[1] << 16) | (rgb[2] << 8) | alpha
    k = a.sh.shape[1]
    header = [
        "ply",
        "format binary_little_endian 1.0",
        "comment compressed by particlesplat",
        f"element chunk {num_chunks}",
    ]
    header += [f"property float {name}" for name in BOUNDS]
    header += [f"element vertex {n}"] + [f"property uint {name}" for name in PACKED]
    body = bounds.tobytes() + vertex.tobytes()
    if k > 1:
        rest = a.sh[:, 1:, :].transpose(0, 2, 1).reshape(n, 3 * (k - 1))  # channel-major, as f_rest
        header += [f"element sh {n}"] + [f"property uchar f_rest_{i}" for i in range(3 * (k - 1))]
        body += np.clip(np.floor((rest / 8.0 + 0.5) * 256.0), 0, 255).astype(np.uint8).tobytes()
    return ("\n".join(header + ["end_header"]) + "\n").encode("ascii") + body


def write_compressed_ply(gaussians: GaussianFields, path: str | PathLike) -> None:
    """Write ``gaussians`` (Morton ordered) as a compressed ``.ply``, atomically; SH kept as 8-bit values."""
    a = splat_arrays(gaussians, path)
    data = encode_compressed_ply(a.take(morton_order(a.means)))
    with atomic_write(Path(path), "wb") as f:
        f.write(data)


def is_compressed(elements: list[tuple[str, int, list[tuple[str, str]]]]) -> bool:
    """Whether a PLY header's elements (:func:`particlesplat.formats.ply.read_header`) are a compressed ``.ply``'s."""
    by_name = {name: props for name, _, props in elements}
    return "chunk" in by_name and any(p == "packed_position" for p, _ in by_name.get("vertex", []))


def read_compressed_ply(path: str | PathLike) -> PlyFields:
    """Read a compressed ``.ply`` into float32 tensors; PlyError/SplatFileError name the file and the field. Every
    element's bytes are sized from the header and checked against the file's size, then reserved with the
    decoding's arrays against the job's memory limit before anything is read."""
    path = Path(path)
    with open(path, "rb") as f:
        fmt, elements = read_header(f, path)
        start = f.tell()
        size = os.fstat(f.fileno()).st_size
        if fmt != "binary_little_endian":
            raise PlyError(f"{path}: format '{fmt}': a compressed .ply is binary_little_endian")
        dtypes = [np.dtype([(p, "<" + t) for p, t in props]) for _, _, props in elements]
        offset = start
        for (name, count, _), dtype in zip(elements, dtypes, strict=True):
            if count * dtype.itemsize > size - offset:
                raise SplatFileError(
                    f"{path}: element '{one_line(name, 40)}' declares {count} rows ({count * dtype.itemsize} "
                    f"bytes), the file holds {max(size - offset, 0)} bytes from there: truncated, or a lying count"
                )
            offset += count * dtype.itemsize
        vertices = next((count for name, count, _ in elements if name == "vertex"), 0)
        rest = sum(len(props) for name, _, props in elements if name == "sh")
        estimate = decode_bytes(vertices, rest // 3 + 1) + (offset - start)
        with decoding(estimate, f"{path}: {vertices} vertices"):
            blocks: dict[str, np.ndarray] = {}
            for (name, count, _), dtype in zip(elements, dtypes, strict=True):
                blocks[name] = np.frombuffer(f.read(count * dtype.itemsize), dtype=dtype, count=count)
            return to_fields(decode_compressed(blocks, path), path)


def decode_compressed(blocks: dict[str, np.ndarray], path: str | PathLike) -> SplatArrays:
    """The Gaussians of a compressed ``.ply``'s elements (structured arrays by element name)."""
    for element, names in (("chunk", BOUNDS[:12]), ("vertex", PACKED)):
        if element not in blocks:
            raise SplatFileError(f"{path}: missing element '{element}' of a compressed .ply")
        have = blocks[element].dtype.names or ()
        missing = [p for p in names if p not in have]
        if missing:
            raise SplatFileError(f"{path}: missing property '{missing[0]}' in element '{element}'")
    chunk, vertex = blocks["chunk"], blocks["vertex"]
    n = len(vertex)
    if len(chunk) != -(-n // CHUNK):
        raise SplatFileError(
            f"{path}: element 'chunk' has {len(chunk)} rows; {n} vertices need {-(-n // CHUNK)} (256 a chunk)"
        )
    bounds = {name: chunk[name].astype(np.float64) for name in BOUNDS if name in (chunk.dtype.names or ())}
    for name, bound in bounds.items():
        if not np.isfinite(bound).all():
            raise SplatFileError(f"{path}: property '{name}' in element 'chunk' has a non-finite value")
    ci = np.arange(n) // CHUNK

    def lerp(word: np.ndarray, shift: int, bits: int, lo: str, hi: str) -> np.ndarray:
        t = ((word >> shift) & ((1 << bits) - 1)) / float((1 << bits) - 1)
        return bounds[lo][ci] * (1 - t) + bounds[hi][ci] * t

    def three(word: np.ndarray, stem: str) -> np.ndarray:
        return np.stack(
            [
                lerp(word, 21, 11, f"min_{stem}x", f"max_{stem}x"),
                lerp(word, 11, 10, f"min_{stem}y", f"max_{stem}y"),
                lerp(word, 0, 11, f"min_{stem}z", f"max_{stem}z"),
            ],
            axis=1,
        )

    words = {name: vertex[name].astype(np.int64) for name in PACKED}
    means = three(words["packed_position"], "")
    log_scales = three(words["packed_scale"], "scale_")
    rot = words["packed_rotation"]
    largest = rot >> 30
    others = others_of(largest)
    quats = np.zeros((n, 4))
    rows = np.arange(n)
    for slot in range(3):
        quats[rows, others[:, slot]] = (((rot >> (10 * (2 - slot))) & 0x3FF) / 1023.0 - 0.5) * _SQRT2
    quats[rows, largest] = np.sqrt(np.maximum(0.0, 1.0 - (quats**2).sum(1)))
    col = words["packed_color"]
    t = np.stack([((col >> s) & 0xFF) / 255.0 for s in (24, 16, 8)], axis=1)
    if all(f"{m}_{c}" in bounds for m in ("min", "max") for c in "rgb"):
        lo = np.stack([bounds[f"min_{c}"][ci] for c in "rgb"], axis=1)
        hi = np.stack([bounds[f"max_{c}"][ci] for c in "rgb"], axis=1)
        t = lo * (1 - t) + hi * t
    dc = (t - 0.5) / SH_C0
    opacities = (col & 0xFF) / 255.0
    rest = np.zeros((n, 0, 3))
    if "sh" in blocks:
        sh_block = blocks["sh"]
        if len(sh_block) != n:
            raise SplatFileError(f"{path}: element 'sh' has {len(sh_block)} rows, element 'vertex' {n}")
        sh_names = sh_block.dtype.names or ()
        m = len(sh_names)
        try:
            sh_degree_from_bases(m // 3 + 1)
            ok = m % 3 == 0
        except ValueError:
            ok = False
        if not ok:
            raise SplatFileError(f"{path}: element 'sh' has {m} properties: no SH degree (9, 24 or 45)")
        missing = [f"f_rest_{i}" for i in range(m) if f"f_rest_{i}" not in sh_names]
        if missing:
            raise SplatFileError(f"{path}: missing property '{missing[0]}' in element 'sh'")
        b = np.stack([sh_block[f"f_rest_{i}"].astype(np.float64) for i in range(m)], axis=1)
        norm = np.where(b == 0, 0.0, np.where(b == 255, 1.0, (b + 0.5) / 256.0))
        rest = ((norm - 0.5) * 8.0).reshape(n, 3, m // 3).transpose(0, 2, 1)
    sh = np.concatenate([dc[:, None, :], rest], axis=1)
    return SplatArrays(means, quats, log_scales, opacities, sh, background_owner(n))
