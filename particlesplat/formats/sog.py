"""PlayCanvas's SOG (version 2): a zip of ``meta.json`` and lossless WebP images, one pixel a Gaussian.

Gaussian i is pixel (i % W, i // W) of every per-Gaussian image (W x H >= count; W and H multiples of 4 here).

- ``means_l.webp`` / ``means_u.webp``: the low / high byte (R, G, B = x, y, z) of a 16-bit fraction of the way
  from ``means.mins`` to ``means.maxs`` of ``sign(v) * log(|v| + 1)`` per axis (the log spends the steps near
  the origin);
- ``quats.webp``: the smallest three of the unit wxyz quaternion (largest component made positive) in ascending
  index order as ``(c * sqrt(2) * 0.5 + 0.5) * 255`` in R, G, B, and 252 + the largest component's index in A;
- ``scales.webp``: per axis an index into ``scales.codebook`` (256 log scales);
- ``sh0.webp``: per channel an index into ``sh0.codebook`` (256 DC coefficients), opacity * 255 in A;
- ``shN_labels.webp`` / ``shN_centroids.webp`` (optional, higher SH bands): a 16-bit palette index (R | G << 8)
  per Gaussian; the palette is 64 entries a row, each ``coeffs`` pixels wide, whose R, G, B index
  ``shN.codebook``.

The writer fits each 256-entry codebook with 1D k-means (Lloyd iterations from quantiles). Higher SH bands are
written for up to :data:`MAX_PALETTE` Gaussians, each its own palette entry (exact but for the 8-bit codebook);
a larger scene is written with SH degree 0 (:func:`keeps_sh` says which). Images are written with ``exact`` so
that a pixel of alpha 0 keeps its colour bytes. The reader takes a ``.sog`` zip or an unbundled ``meta.json``
beside its images.
"""

from __future__ import annotations

import io
import json
import math
import zipfile
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

from particlesplat.core.atomic import atomic_write
from particlesplat.core.errors import one_line
from particlesplat.core.limits import check_memory
from particlesplat.formats.ply import GaussianFields, PlyFields
from particlesplat.formats.splat_arrays import (
    SplatArrays,
    SplatFileError,
    background_owner,
    decode_bytes,
    largest_component,
    others_of,
    splat_arrays,
    to_fields,
)

VERSION = 2
CODEBOOK = 256
KMEANS_ITERATIONS = 12
MAX_MEMBER_BYTES = 1 << 30  # a zip member that would inflate beyond 1 GiB is refused
_SH_COEFFS = {1: 3, 2: 8, 3: 15}


MAX_PALETTE = 65536  # the labels are 16 bits: at most this many palette entries


def keeps_sh(count: int, bases: int) -> bool:
    """Whether a SOG of ``count`` Gaussians with ``bases`` SH bases a channel keeps the bands above degree 0 (one
    palette entry a Gaussian needs ``count`` <= :data:`MAX_PALETTE`)."""
    return bases > 1 and count <= MAX_PALETTE


def log_transform(v: np.ndarray) -> np.ndarray:
    return np.sign(v) * np.log1p(np.abs(v))


def inverse_log_transform(v: np.ndarray) -> np.ndarray:
    return np.sign(v) * np.expm1(np.abs(v))


def fit_codebook(values: np.ndarray, size: int = CODEBOOK, iterations: int = KMEANS_ITERATIONS) -> np.ndarray:
    """(size,) ascending 1D k-means centres of ``values`` (any shape), started from quantiles."""
    v = np.sort(values.reshape(-1).astype(np.float64))
    if len(v) == 0:
        return np.zeros(size)
    centres = np.quantile(v, (np.arange(size) + 0.5) / size)
    for _ in range(iterations):
        labels = nearest(centres, v)
        sums = np.bincount(labels, weights=v, minlength=size)
        counts = np.bincount(labels, minlength=size)
        centres = np.where(counts > 0, sums / np.maximum(counts, 1), centres)
        centres.sort()
    return centres


def nearest(codebook: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Index of the nearest entry of ascending ``codebook`` for each of ``values`` (same shape)."""
    mid = (codebook[1:] + codebook[:-1]) / 2.0
    return np.searchsorted(mid, values).astype(np.int64)


def image_size(count: int) -> tuple[int, int]:
    """(W, H) of the per-Gaussian images: multiples of 4, W x H >= count."""
    width = max(4, math.ceil(math.sqrt(count) / 4) * 4)
    return width, max(4, math.ceil(count / width / 4) * 4)


def _webp(rgba: np.ndarray) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(rgba, "RGBA").save(buf, format="WEBP", lossless=True, quality=100, method=4, exact=True)
    return buf.getvalue()


def encode_sog(a: SplatArrays) -> dict[str, bytes]:
    """The files (name -> bytes) of a SOG holding ``a`` in its order (higher SH bands when :func:`keeps_sh`)."""
    n = a.num
    w, h = image_size(n)

    def image(channels: list[np.ndarray], alpha: np.ndarray | None = None) -> bytes:
        px = np.zeros((w * h, 4), dtype=np.uint8)
        px[:, 3] = 255
        for i, c in enumerate(channels):
            px[:n, i] = c
        if alpha is not None:
            px[:n, 3] = alpha
        return _webp(px.reshape(h, w, 4))

    lt = log_transform(a.means)
    mins, maxs = lt.min(0) if n else np.zeros(3), lt.max(0) if n else np.zeros(3)
    span = np.where(maxs > mins, maxs - mins, 1.0)
    q16 = np.clip(np.rint((lt - mins) / span * 65535.0), 0, 65535).astype(np.uint32)
    largest, q = largest_component(a.quats)
    others = others_of(largest)
    quat_bytes = [
        np.clip(np.rint((q[np.arange(n), others[:, s]] * math.sqrt(2) * 0.5 + 0.5) * 255.0), 0, 255) for s in range(3)
    ]
    scale_book = fit_codebook(a.log_scales)
    dc_book = fit_codebook(a.sh[:, 0, :])
    scale_idx = nearest(scale_book, a.log_scales)
    dc_idx = nearest(dc_book, a.sh[:, 0, :])
    meta: dict[str, Any] = {
        "version": VERSION,
        "asset": {"generator": "particlesplat"},
        "count": n,
        "antialias": False,
        "means": {
            "mins": [float(v) for v in mins],
            "maxs": [float(v) for v in maxs],
            "files": ["means_l.webp", "means_u.webp"],
        },
        "scales": {"codebook": [float(v) for v in scale_book], "files": ["scales.webp"]},
        "quats": {"files": ["quats.webp"]},
        "sh0": {"codebook": [float(v) for v in dc_book], "files": ["sh0.webp"]},
    }
    files: dict[str, bytes] = {}
    if keeps_sh(a.num, a.sh.shape[1]):
        coeffs = a.sh.shape[1] - 1
        rest = a.sh[:, 1:, :]  # (N, coeffs, 3)
        book = fit_codebook(rest)
        idx = nearest(book, rest).astype(np.uint8)  # (N, coeffs, 3)
        rows = math.ceil(n / 64)
        centroids = np.zeros((rows * 64, coeffs, 4), dtype=np.uint8)  # entry l = Gaussian l
        centroids[:, :, 3] = 255
        centroids[:n, :, :3] = idx
        files["shN_centroids.webp"] = _webp(centroids.reshape(rows, 64 * coeffs, 4))
        label = np.arange(n)
        files["shN_labels.webp"] = image([label & 0xFF, label >> 8])
        meta["shN"] = {
            "count": n,
            "bands": a.sh_degree,
            "codebook": [float(v) for v in book],
            "files": ["shN_centroids.webp", "shN_labels.webp"],
        }
    return {
        "meta.json": json.dumps(meta, indent=1).encode("utf-8"),
        **files,
        "means_l.webp": image([q16[:, i] & 0xFF for i in range(3)]),
        "means_u.webp": image([q16[:, i] >> 8 for i in range(3)]),
        "quats.webp": image([b.astype(np.uint8) for b in quat_bytes], (252 + largest).astype(np.uint8)),
        "scales.webp": image([scale_idx[:, i] for i in range(3)]),
        "sh0.webp": image(
            [dc_idx[:, i] for i in range(3)], np.clip(np.rint(a.opacities * 255.0), 0, 255).astype(np.uint8)
        ),
    }


def write_sog(gaussians: GaussianFields, path: str | PathLike) -> None:
    """Write ``gaussians`` as a bundled ``.sog`` (a zip, stored: the images are compressed already), atomically.
    Higher SH bands are kept when :func:`keeps_sh`."""
    files = encode_sog(splat_arrays(gaussians, path))
    with atomic_write(Path(path), "wb") as f, zipfile.ZipFile(f, "w", zipfile.ZIP_STORED) as z:
        for name, data in files.items():
            z.writestr(zipfile.ZipInfo(name, date_time=(2026, 1, 1, 0, 0, 0)), data)


class _Files:
    """The members of a bundled or unbundled SOG, read by name with a size bound."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.zip: zipfile.ZipFile | None = None
        if path.name != "meta.json":
            try:
                self.zip = zipfile.ZipFile(path)
            except (zipfile.BadZipFile, OSError) as e:
                raise SplatFileError(f"{path}: not a SOG zip ({one_line(e, 120)})") from None

    def read(self, name: str) -> bytes:
        shown = one_line(name, 80)
        if self.zip is None:
            member = self.path.parent / name
            if Path(name).name != name or not member.is_file():
                raise SplatFileError(f"{self.path}: file '{shown}' named in meta.json is not beside it")
            return member.read_bytes()
        try:
            info = self.zip.getinfo(name)
        except KeyError:
            raise SplatFileError(f"{self.path}: member '{shown}' is not in the zip") from None
        if info.file_size > MAX_MEMBER_BYTES:
            raise SplatFileError(f"{self.path}: member '{shown}' is {info.file_size} bytes, beyond {MAX_MEMBER_BYTES}")
        try:
            return self.zip.read(info)
        except (zipfile.BadZipFile, OSError, EOFError) as e:
            raise SplatFileError(f"{self.path}: member '{shown}': corrupt ({one_line(e, 120)})") from None

    def close(self) -> None:
        if self.zip is not None:
            self.zip.close()


def _field(meta: dict, path: Path, *keys: str) -> Any:
    node: Any = meta
    for i, key in enumerate(keys):
        if not isinstance(node, dict) or key not in node:
            raise SplatFileError(f"{path}: meta.json: missing '{'.'.join(keys[: i + 1])}'")
        node = node[key]
    return node


def _numbers(meta: dict, path: Path, length: int | None, *keys: str) -> np.ndarray:
    value = _field(meta, path, *keys)
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        arr = None
    if arr is None or arr.ndim != 1 or (length is not None and len(arr) != length) or not np.isfinite(arr).all():
        want = f"{length} finite numbers" if length is not None else "a list of finite numbers"
        raise SplatFileError(f"{path}: meta.json: '{'.'.join(keys)}': expected {want}")
    return arr


def _image(files: _Files, meta: dict, key: str, index: int, count: int) -> np.ndarray:
    """(H, W, 4) uint8 pixels of the image ``meta[key].files[index]``; SplatFileError when it holds < count."""
    names = _field(meta, files.path, key, "files")
    if not isinstance(names, list) or len(names) <= index or not isinstance(names[index], str):
        raise SplatFileError(f"{files.path}: meta.json: '{key}.files' must list {index + 1} file name(s)")
    data = files.read(names[index])
    shown = one_line(names[index], 80)
    try:
        im = Image.open(io.BytesIO(data))  # the header alone: no pixel is decoded yet
    except (OSError, ValueError, Image.DecompressionBombError) as e:
        raise SplatFileError(f"{files.path}: {shown}: not a readable image ({one_line(e, 120)})") from None
    with im:
        check_memory(8.0 * im.width * im.height, f"{files.path}: {shown}: {im.width}x{im.height} pixels")
        try:
            px = np.asarray(im.convert("RGBA"))
        except (OSError, ValueError, Image.DecompressionBombError) as e:
            raise SplatFileError(f"{files.path}: {shown}: not a readable image ({one_line(e, 120)})") from None
    if px.shape[0] * px.shape[1] < count:
        raise SplatFileError(f"{files.path}: {shown}: {px.shape[1]}x{px.shape[0]} pixels, fewer than count {count}")
    return px


def _pixels(files: _Files, meta: dict, key: str, index: int, count: int) -> np.ndarray:
    """(count, 4) uint8: the first ``count`` pixels of :func:`_image`, row-major."""
    return _image(files, meta, key, index, count).reshape(-1, 4)[:count]


def decode_sog(files: _Files) -> SplatArrays:
    """The Gaussians of an open SOG."""
    path = files.path
    try:
        meta = json.loads(files.read("meta.json") if files.zip is not None else path.read_bytes())
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise SplatFileError(f"{path}: meta.json: not valid JSON ({one_line(e, 120)})") from None
    if not isinstance(meta, dict):
        raise SplatFileError(f"{path}: meta.json: expected a JSON object")
    if meta.get("version") != VERSION:
        raise SplatFileError(
            f"{path}: meta.json: version {one_line(repr(meta.get('version')), 40)} is not supported (2; "
            "re-save older SOG files with splat-transform)"
        )
    n = _field(meta, path, "count")
    if not isinstance(n, int) or isinstance(n, bool) or n < 0:
        raise SplatFileError(f"{path}: meta.json: 'count' must be a whole number >= 0")
    sh_n = meta.get("shN")
    bands = sh_n.get("bands") if isinstance(sh_n, dict) else 0
    check_memory(decode_bytes(n, (bands + 1) ** 2 if bands in _SH_COEFFS else 1), f"{path}: meta.json: count {n}")
    mins = _numbers(meta, path, 3, "means", "mins")
    maxs = _numbers(meta, path, 3, "means", "maxs")
    lo, hi = _pixels(files, meta, "means", 0, n), _pixels(files, meta, "means", 1, n)
    q16 = lo[:, :3].astype(np.float64) + 256.0 * hi[:, :3]
    means = inverse_log_transform(mins + (maxs - mins) * (q16 / 65535.0))
    qpx = _pixels(files, meta, "quats", 0, n).astype(np.int64)
    tag = qpx[:, 3]
    bad = (tag < 252) | (tag > 255)
    largest = np.clip(tag - 252, 0, 3)
    others = others_of(largest)
    quats = np.zeros((n, 4))
    rows = np.arange(n)
    for s in range(3):
        quats[rows, others[:, s]] = (qpx[:, s] / 255.0 * 2.0 - 1.0) / math.sqrt(2)
    quats[rows, largest] = np.sqrt(np.maximum(0.0, 1.0 - (quats**2).sum(1)))
    quats[bad] = (1.0, 0.0, 0.0, 0.0)  # as PlayCanvas reads a pixel with no component tag
    scale_book = _numbers(meta, path, CODEBOOK, "scales", "codebook")
    log_scales = scale_book[_pixels(files, meta, "scales", 0, n)[:, :3]]
    dc_book = _numbers(meta, path, CODEBOOK, "sh0", "codebook")
    sh0 = _pixels(files, meta, "sh0", 0, n)
    dc = dc_book[sh0[:, :3]]
    opacities = sh0[:, 3] / 255.0
    rest = _read_sh_n(files, meta, n)
    sh = np.concatenate([dc[:, None, :], rest], axis=1)
    return SplatArrays(means, quats, log_scales, opacities, sh, background_owner(n))


def _read_sh_n(files: _Files, meta: dict, n: int) -> np.ndarray:
    """(n, coeffs, 3) the higher SH bands of the optional ``shN`` palette (coeffs = 0 without one)."""
    path = files.path
    sh_n = meta.get("shN")
    if not sh_n:
        return np.zeros((n, 0, 3))
    bands = _field(meta, path, "shN", "bands")
    if bands not in _SH_COEFFS:
        raise SplatFileError(f"{path}: meta.json: 'shN.bands' must be 1, 2 or 3")
    coeffs = _SH_COEFFS[bands]
    book = _numbers(meta, path, None, "shN", "codebook")
    palette = _field(meta, path, "shN", "count")
    if not isinstance(palette, int) or palette < 0:
        raise SplatFileError(f"{path}: meta.json: 'shN.count' must be a whole number >= 0")
    centroids = _image(files, meta, "shN", 0, 0)
    cw = centroids.shape[1]
    if cw != 64 * coeffs:
        raise SplatFileError(f"{path}: shN centroids image: width {cw}, expected {64 * coeffs} for {bands} bands")
    centroids_px = centroids.reshape(-1, 4)
    labels_px = _pixels(files, meta, "shN", 1, n).astype(np.int64)
    label = labels_px[:, 0] | (labels_px[:, 1] << 8)
    ok = label < palette
    label = np.where(ok, label, 0)
    pixel = (label // 64)[:, None] * cw + (label % 64)[:, None] * coeffs + np.arange(coeffs)[None, :]  # (n, coeffs)
    inside = pixel < len(centroids_px)
    idx = centroids_px[np.where(inside, pixel, 0)][..., :3].astype(np.int64)  # (n, coeffs, 3)
    if idx.size and idx.max() >= len(book):
        raise SplatFileError(f"{path}: meta.json: 'shN.codebook' has {len(book)} entries, the palette indexes more")
    rest = book[idx] if len(book) else np.zeros(idx.shape)
    return np.where((ok[:, None] & inside)[..., None], rest, 0.0)


def read_sog(path: str | PathLike) -> PlyFields:
    """Read a bundled ``.sog`` (or an unbundled ``meta.json``) into float32 tensors; SplatFileError names the file
    and the field."""
    path = Path(path)
    files = _Files(path)
    try:
        return to_fields(decode_sog(files), path)
    finally:
        files.close()
