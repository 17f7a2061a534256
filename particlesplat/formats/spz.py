"""Niantic's SPZ (MIT; versions 2-4 read, 3 written): version 3 is a gzip stream of a 16-byte header and one array
per attribute.

Header (little endian): ``magic`` uint32 0x5053474e ("NGSP"), ``version`` uint32 (3; 2 is read too),
``num_points`` uint32, ``sh_degree`` uint8 (0..3), ``fractional_bits`` uint8, ``flags`` uint8 (bit 0:
antialiased), ``reserved`` uint8 (0). Then, for N points, in this order:

- positions: 3 x int24 each, fixed point with ``fractional_bits`` fraction bits (12 here: 0.24 mm steps within
  ±2 km; one fewer for each doubling of a larger scene's reach);
- alphas: uint8, opacity * 255;
- colours: 3 x uint8, ``dc * 0.15 * 255 + 127.5`` (the DC SH coefficient, not the colour);
- scales: 3 x uint8, ``(log scale + 10) * 16``;
- rotations: uint32, smallest three of the unit quaternion in (x, y, z, w) order: the largest component's index
  in bits 30-31, then for each other component in ascending order 10 bits (a sign bit over a 9-bit magnitude of
  ``|c| / sqrt(1/2) * 511``), the first in bits 20-29; version 2 stored x, y, z as ``c * 127.5 + 127.5``;
- SH: ``sh_dim * 3`` uint8 per point (coefficient-major, channel-minor), ``round(c * 128) + 128`` on 5 bits
  (step 8) for degree 1 and 4 bits (step 16) above.

Axes: the positions and rotations are stored in the ``.ply``'s own axes, as PlayCanvas's splat-transform,
SuperSplat and Spark write and read them (the spec names RUB as SPZ's internal frame; Niantic's own ``.ply``
converter flips y and z, which this one does not).

Version 4 (read, not written): no gzip; a plaintext 32-byte header (``magic``, ``version`` 4, ``num_points``,
``sh_degree`` 0..4, ``fractional_bits``, ``flags`` (bit 1: extension records follow the header), ``num_streams``
uint8, ``toc_offset`` uint32, 12 reserved bytes), the extension records (``type`` uint32, ``length`` uint32, then
``length`` bytes each) up to ``toc_offset``, a table of contents of ``num_streams`` pairs (compressed bytes,
inflated bytes; uint64), and the streams back to back to the file's end: one ZSTD frame per array above, in the
same order and encoding, an empty array's stream left out (a degree-0 file has 5). SH degree 4 stores 24
coefficients a channel, of which the first 15 (degrees 1-3) are kept.
"""

from __future__ import annotations

import gzip
import os
import struct
import zlib
from collections.abc import Iterator
from contextlib import contextmanager
from os import PathLike
from pathlib import Path
from typing import BinaryIO

import numpy as np

from particlesplat.core.atomic import atomic_write
from particlesplat.core.errors import warn_input
from particlesplat.core.sh import num_sh_bases
from particlesplat.formats.ply import GaussianFields, GaussianWriteError, PlyFields
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

MAGIC = 0x5053474E
VERSION = 3
HEADER = struct.Struct("<IIIBBBB")
FRACTIONAL_BITS = 12
COLOR_SCALE = 0.15
FLAG_ANTIALIASED = 0x1
MAX_POINTS = 1 << 26  # 67M points: a header asking for more is refused before anything is allocated
READ_CHUNK = 1 << 20  # bytes of the gzip stream read at a time: the compressed file is never held whole
_SQRT1_2 = np.sqrt(0.5)


def _sh_dim(degree: int) -> int:
    return num_sh_bases(degree) - 1


def encode_spz(a: SplatArrays, path: str | PathLike = "") -> bytes:
    """The (uncompressed) SPZ v3 payload of ``a``; GaussianWriteError naming ``path`` for a position beyond the
    fixed point's range."""
    n, degree = a.num, a.sh_degree
    peak = float(np.abs(a.means).max()) if n else 0.0
    frac = FRACTIONAL_BITS  # fewer fraction bits for a scene reaching beyond ±2 km: coarser steps, same range
    while frac > 0 and np.rint(peak * (1 << frac)) >= (1 << 23) - 1:
        frac -= 1
    fixed = np.rint(a.means * float(1 << frac))
    if n and np.abs(fixed).max() >= (1 << 23) - 1:
        row = int(np.argwhere((np.abs(fixed) >= (1 << 23) - 1).any(1))[0, 0])
        raise GaussianWriteError(
            f"{path}: cannot write SPZ: position {a.means[row].tolist()} of Gaussian {row} is beyond "
            f"±{(1 << 23) - 1} m (24-bit fixed point)"
        )
    pos = fixed.astype(np.int64).reshape(-1) & 0xFFFFFF
    pos_bytes = np.stack([pos & 0xFF, (pos >> 8) & 0xFF, (pos >> 16) & 0xFF], axis=1).astype(np.uint8)
    alphas = np.clip(np.rint(a.opacities * 255.0), 0, 255).astype(np.uint8)
    colours = np.clip(np.rint(a.sh[:, 0, :] * (COLOR_SCALE * 255.0) + 127.5), 0, 255).astype(np.uint8)
    scales = np.clip(np.rint((a.log_scales + 10.0) * 16.0), 0, 255).astype(np.uint8)
    rotations = _pack_rotations(a.quats)
    dim = _sh_dim(degree)
    rest = a.sh[:, 1:, :]  # (N, dim, 3): coefficient-major, channel-minor as stored
    q = np.rint(rest * 128.0) + 128.0
    step = np.where(np.arange(dim) < 3, 8.0, 16.0)[None, :, None]
    q = np.clip(np.floor((q + step / 2) / step) * step, 0, 255).astype(np.uint8)
    header = HEADER.pack(MAGIC, VERSION, n, degree, frac, 0, 0)
    parts = [pos_bytes, alphas, colours, scales, rotations.astype("<u4"), q.reshape(n, dim * 3)]
    return header + b"".join(np.ascontiguousarray(p).tobytes() for p in parts)


def _pack_rotations(wxyz: np.ndarray) -> np.ndarray:
    """(N,) uint32 smallest-three codes of (N, 4) unit wxyz quaternions (stored in x, y, z, w order)."""
    xyzw = wxyz[:, [1, 2, 3, 0]]
    largest, q = largest_component(xyzw)
    others = others_of(largest)
    packed = largest.astype(np.uint64) << np.uint64(30)
    for slot in range(3):
        c = q[np.arange(len(q)), others[:, slot]]
        mag = np.clip(np.rint(np.abs(c) / _SQRT1_2 * 511.0), 0, 511).astype(np.uint64)
        code = mag | ((c < 0).astype(np.uint64) << np.uint64(9))
        packed |= code << np.uint64(10 * (2 - slot))
    return packed.astype(np.uint32)


def write_spz(gaussians: GaussianFields, path: str | PathLike) -> None:
    """Write ``gaussians`` as a gzip-compressed SPZ v3 file (SH kept up to degree 3), atomically."""
    data = gzip.compress(encode_spz(splat_arrays(gaussians, path), path), compresslevel=9, mtime=0)
    with atomic_write(Path(path), "wb") as f:
        f.write(data)


def _payload_size(n: int, degree: int, version: int) -> int:
    return HEADER.size + n * (9 + 1 + 3 + 3 + (3 if version == 2 else 4) + 3 * _sh_dim(degree))


def decode_spz(raw: bytes | bytearray, path: str | PathLike) -> SplatArrays:
    """The Gaussians of an uncompressed SPZ payload (version 2 or 3); SplatFileError names ``path`` and the field."""
    if len(raw) < HEADER.size:
        raise SplatFileError(f"{path}: truncated SPZ header ({len(raw)} of {HEADER.size} bytes)")
    magic, version, n, degree, frac, _flags, _reserved = HEADER.unpack_from(raw)
    if magic != MAGIC:
        raise SplatFileError(f"{path}: magic: 0x{magic:08x} is not SPZ's 0x{MAGIC:08x} ('NGSP')")
    if version not in (2, 3):
        raise SplatFileError(f"{path}: version: {version} is not supported (2 or 3)")
    if degree > 3:
        raise SplatFileError(f"{path}: sh_degree: {degree} is not supported (0..3)")
    if frac > 23:
        raise SplatFileError(f"{path}: fractional_bits: {frac} is beyond the 24-bit positions")
    want = _payload_size(n, degree, version)
    if len(raw) != want:
        raise SplatFileError(
            f"{path}: num_points: {n} points of SH degree {degree} need {want} bytes, the file holds {len(raw)}"
        )
    off = HEADER.size

    def take(count: int, width: int) -> np.ndarray:
        nonlocal off
        block = np.frombuffer(raw, dtype=np.uint8, count=count * width, offset=off).reshape(count, width)
        off += count * width
        return block.astype(np.int64)

    p = take(n * 3, 3)
    fixed = p[:, 0] | (p[:, 1] << 8) | (p[:, 2] << 16)
    fixed = np.where(fixed >= 1 << 23, fixed - (1 << 24), fixed)
    means = fixed.reshape(n, 3) / float(1 << frac)
    alphas = take(n, 1)[:, 0] / 255.0
    dc = (take(n, 3) / 255.0 - 0.5) / COLOR_SCALE
    log_scales = take(n, 3) / 16.0 - 10.0
    if version == 2:
        xyz = take(n, 3) / 127.5 - 1.0
        w = np.sqrt(np.maximum(0.0, 1.0 - (xyz**2).sum(1)))
        quats = np.concatenate([w[:, None], xyz], axis=1)
    else:
        quats = _unpack_rotations(take(n, 4))
    dim = _sh_dim(degree)
    rest = (take(n, dim * 3).reshape(n, dim, 3) - 128.0) / 128.0
    sh = np.concatenate([dc[:, None, :], rest], axis=1)
    return SplatArrays(means, quats, log_scales, alphas, sh, background_owner(n))


def _unpack_rotations(b: np.ndarray) -> np.ndarray:
    """(N, 4) wxyz quaternions of (N, 4) little-endian bytes of smallest-three codes."""
    packed = b[:, 0] | (b[:, 1] << 8) | (b[:, 2] << 16) | (b[:, 3] << 24)
    largest = packed >> 30
    others = others_of(largest)
    xyzw = np.zeros((len(b), 4))
    rows = np.arange(len(b))
    for slot in range(3):
        code = (packed >> (10 * (2 - slot))) & 0x3FF
        value = _SQRT1_2 * (code & 0x1FF) / 511.0
        xyzw[rows, others[:, slot]] = np.where(code & 0x200, -value, value)
    xyzw[rows, largest] = np.sqrt(np.maximum(0.0, 1.0 - (xyzw**2).sum(1)))
    return xyzw[:, [3, 0, 1, 2]]


def read_spz(path: str | PathLike) -> PlyFields:
    """Read an SPZ file (version 2 or 3: gzip; 4: ZSTD streams) into float32 tensors; SplatFileError names the file
    and the field.

    The file is streamed: its first bytes tell the format, the gzip stream's first 16 inflated bytes (the header)
    size the payload, which is reserved with the decoding's arrays against the job's memory limit
    (:func:`particlesplat.formats.splat_arrays.decoding`) before the rest is inflated, never beyond that size.
    Neither the compressed file nor more than the header's payload is held. Version 4 is read the same way, stream
    by stream, into the version 3 layout (:func:`_inflated_v4`)."""
    path = Path(path)
    with open(path, "rb") as f:
        magic = f.read(4)
        f.seek(0)
        if magic == struct.pack("<I", MAGIC):  # version 4: a plaintext header, then ZSTD streams
            with _inflated_v4(f, path) as raw:
                return to_fields(decode_spz(raw, path), path)
        if magic[:2] != b"\x1f\x8b":
            raise SplatFileError(f"{path}: not an SPZ file (no gzip stream)")
        f.seek(0)
        with _inflated(f, path) as raw:
            return to_fields(decode_spz(raw, path), path)


class _Inflater:
    """The gzip stream of an open file, inflated on demand: :meth:`take` returns up to ``count`` more bytes,
    reading the file :data:`READ_CHUNK` bytes at a time (fewer only at the stream's end)."""

    def __init__(self, f: BinaryIO, path: Path) -> None:
        self.f, self.path = f, path
        self.z = zlib.decompressobj(wbits=31)
        self.pending = b""

    def take(self, count: int) -> bytearray:
        out = bytearray()
        try:
            while len(out) < count and not self.z.eof:
                data = self.pending or self.f.read(READ_CHUNK)
                if not data:
                    break
                out += self.z.decompress(data, count - len(out))
                self.pending = self.z.unconsumed_tail
        except zlib.error as e:
            raise SplatFileError(f"{self.path}: corrupt gzip stream ({e})") from None
        return out


@contextmanager
def _inflated(f: BinaryIO, path: Path) -> Iterator[bytearray]:
    """The gzip stream's bytes, never more than its header's point count can need (a stream that would inflate
    beyond that is refused as a lying size, not inflated), inside the reservation of what they and their decoding
    hold."""
    inflater = _Inflater(f, path)
    head = inflater.take(HEADER.size)
    if len(head) < HEADER.size:
        raise SplatFileError(f"{path}: truncated SPZ header ({len(head)} of {HEADER.size} bytes)")
    _magic, version, n, degree = HEADER.unpack_from(head)[:4]
    if n > MAX_POINTS:
        raise SplatFileError(f"{path}: num_points: {n} is beyond {MAX_POINTS}")
    want = _payload_size(n, min(degree, 3), 2 if version == 2 else 3)
    with decoding(decode_bytes(n, num_sh_bases(min(degree, 3))) + 2.0 * want, f"{path}: num_points {n}"):
        head += inflater.take(want - HEADER.size + 1)  # one byte more tells a stream longer than the header says
        yield head


HEADER_V4 = struct.Struct("<IIIBBBBI12s")  # magic, version, num_points, sh_degree, fractional_bits, flags,
# num_streams, toc_offset, reserved
TOC_ENTRY = struct.Struct("<QQ")  # compressed bytes, inflated bytes
EXTENSION = struct.Struct("<II")  # type, payload bytes
FLAG_EXTENSIONS = 0x2
MAX_EXTENSION_BYTES = 1 << 20  # the plaintext extension records (camera limits, a coordinate-system label)
STREAMS = ("positions", "alphas", "colors", "scales", "rotations", "sh")
MIN_WINDOW = 1 << 20  # a ZSTD frame's window is allowed its stream's inflated size, and at least this


def _stream_sizes(n: int, degree: int) -> list[tuple[str, int]]:
    """(name, inflated bytes) of the streams a version 4 file of ``n`` points and SH ``degree`` (0..4) stores: the
    version 3 arrays in order, empty ones left out."""
    sizes = (9 * n, n, 3 * n, 3 * n, 4 * n, 3 * n * ((degree + 1) ** 2 - 1))  # degree 4: 24 coefficients a channel
    return [(name, size) for name, size in zip(STREAMS, sizes, strict=True) if size]


class _Slice:
    """The next ``size`` bytes of an open file, read as a file (a ZSTD stream reader never reads past them)."""

    def __init__(self, f: BinaryIO, size: int) -> None:
        self.f, self.left = f, size

    def read(self, count: int = -1) -> bytes:
        data = self.f.read(self.left if count < 0 else min(count, self.left))
        self.left -= len(data)
        return data


def _extension_types(raw: bytes, path: Path) -> list[int]:
    """The types of the extension records in ``raw`` (the bytes between the header and the table of contents);
    SplatFileError when a record runs past them."""
    types, off = [], 0
    while off < len(raw):
        if off + EXTENSION.size > len(raw):
            raise SplatFileError(f"{path}: extension record at byte {HEADER_V4.size + off}: truncated")
        kind, length = EXTENSION.unpack_from(raw, off)
        off += EXTENSION.size + length
        if off > len(raw):
            raise SplatFileError(
                f"{path}: extension record 0x{kind:08x}: {length} bytes run past the table of contents"
            )
        types.append(kind)
    return types


@contextmanager
def _inflated_v4(f: BinaryIO, path: Path) -> Iterator[bytearray]:
    """A version 4 file's arrays in the version 3 payload layout (:func:`decode_spz` decodes it), inside the
    reservation of what they and their decoding hold, sized from the header before any stream is inflated: each
    stream is inflated from the file a chunk at a time and never beyond the size its table of contents gives
    (which must be what the header's point count needs), within a window of at most that size (at least
    :data:`MIN_WINDOW`). SH degree 4 keeps its degree 1-3 coefficients (a warning says so)."""
    try:
        import zstandard
    except ImportError:
        raise SplatFileError(
            f"{path}: SPZ version 4 (ZSTD streams) needs the zstandard package: pip install zstandard"
        ) from None
    head = f.read(HEADER_V4.size)
    if len(head) < HEADER_V4.size:
        raise SplatFileError(f"{path}: truncated SPZ version 4 header ({len(head)} of {HEADER_V4.size} bytes)")
    _magic, version, n, degree, frac, flags, count, toc, _reserved = HEADER_V4.unpack(head)
    if version != 4:
        raise SplatFileError(
            f"{path}: version: {version} in a plaintext header is not supported (4; versions 2 and 3 are gzip streams)"
        )
    if n > MAX_POINTS:
        raise SplatFileError(f"{path}: num_points: {n} is beyond {MAX_POINTS}")
    if degree > 4:
        raise SplatFileError(f"{path}: sh_degree: {degree} is not supported (0..4)")
    streams = _stream_sizes(n, degree)
    if count != len(streams):
        raise SplatFileError(
            f"{path}: num_streams: {count}, but {n} points of SH degree {degree} store {len(streams)} "
            f"({', '.join(name for name, _ in streams) or 'none'})"
        )
    size = os.fstat(f.fileno()).st_size
    toc_end = toc + TOC_ENTRY.size * count
    if not HEADER_V4.size <= toc <= size or toc_end > size:
        raise SplatFileError(f"{path}: toc_offset: {toc} leaves no table of contents in the file's {size} bytes")
    if toc - HEADER_V4.size > MAX_EXTENSION_BYTES:
        raise SplatFileError(
            f"{path}: toc_offset: {toc} leaves {toc - HEADER_V4.size} bytes of extension records, beyond "
            f"{MAX_EXTENSION_BYTES}"
        )
    zone = f.read(toc - HEADER_V4.size)
    if flags & FLAG_EXTENSIONS:
        types = _extension_types(zone, path)
        if types:
            warn_input(
                f"{path}: extension records {', '.join(f'0x{t:08x}' for t in types)} ignored (the Gaussians are read "
                "as stored)"
            )
    entries = [TOC_ENTRY.unpack(f.read(TOC_ENTRY.size)) for _ in range(count)]
    offset = toc_end
    for (name, want), (packed, inflated) in zip(streams, entries, strict=True):
        if inflated != want:
            raise SplatFileError(
                f"{path}: {name} stream: {inflated} bytes inflated, but {n} points of SH degree {degree} need {want}"
            )
        if packed > size - offset:
            raise SplatFileError(f"{path}: {name} stream: {packed} compressed bytes run past the file's end")
        offset += packed
    if offset != size:
        raise SplatFileError(f"{path}: the streams end at byte {offset}, the file at {size}")
    kept = min(degree, 3)
    payload = _payload_size(n, kept, 3)
    window = max(MIN_WINDOW, *(want for _, want in streams)) if streams else MIN_WINDOW
    with decoding(decode_bytes(n, num_sh_bases(kept)) + 2.0 * payload + 2.0 * window, f"{path}: num_points {n}"):
        out = bytearray(HEADER.pack(MAGIC, 3, n, kept, frac, flags & FLAG_ANTIALIASED, 0))
        reader = zstandard.ZstdDecompressor(max_window_size=1 << (window - 1).bit_length())
        offset = toc_end
        for (name, want), (packed, _) in zip(streams, entries, strict=True):
            f.seek(offset)
            data = _inflate_stream(reader, _Slice(f, packed), want, f"{path}: {name} stream")
            if name == "sh" and degree > kept:
                keep = 3 * (num_sh_bases(kept) - 1)
                data = bytearray(np.frombuffer(data, np.uint8).reshape(n, -1)[:, :keep].tobytes())
            out += data
            offset += packed
        if degree > kept:
            warn_input(f"{path}: sh_degree: 4; its degree-4 coefficients are left out (read to degree 3)")
        yield out


def _inflate_stream(reader, source: _Slice, want: int, where: str) -> bytearray:
    """The ``want`` bytes one ZSTD frame of ``source`` inflates to; SplatFileError naming ``where`` for a corrupt
    frame or one that inflates to another size (never inflated beyond ``want`` + 1 bytes)."""
    import zstandard

    out = bytearray()
    try:
        stream = reader.stream_reader(source, read_size=READ_CHUNK, read_across_frames=False, closefd=False)
        while len(out) < want:
            chunk = stream.read(want - len(out))
            if not chunk:
                break
            out += chunk
        extra = stream.read(1)
    except zstandard.ZstdError as e:
        raise SplatFileError(f"{where}: corrupt ZSTD data ({e})") from None
    if len(out) != want or extra:
        got = f"more than {want}" if extra else str(len(out))
        raise SplatFileError(f"{where}: inflates to {got} bytes, its table of contents says {want}")
    return out
