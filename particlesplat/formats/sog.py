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
import re
import zipfile
from os import PathLike
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
from PIL import Image, UnidentifiedImageError

from particlesplat.core.atomic import atomic_write
from particlesplat.core.errors import one_line
from particlesplat.core.jsonfile import read_json, read_json_stream
from particlesplat.core.limits import check_memory
from particlesplat.formats.header_fields import numbers, text_list, whole_number
from particlesplat.formats.image_headers import HEAD_BYTES, image_header_size
from particlesplat.formats.ply import GaussianFields, PlyFields
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

VERSION = 2
CODEBOOK = 256
KMEANS_ITERATIONS = 12
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
    """The members of a bundled or unbundled SOG, sized and read by name: a member's size is what the zip directory
    (or the file system, beside an unbundled ``meta.json``) declares, and no read goes past it."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.zip: zipfile.ZipFile | None = None
        if path.name != "meta.json":
            try:
                self.zip = zipfile.ZipFile(path)
            except (zipfile.BadZipFile, OSError) as e:
                raise SplatFileError(f"{path}: not a SOG zip ({one_line(e, 120)})") from None

    def meta(self) -> object:
        """``meta.json``'s value, read by the checked JSON reader (:mod:`particlesplat.core.jsonfile`: at most
        16 MiB, UTF-8, nesting), from the zip as from a file."""
        if self.zip is None:
            return read_json(self.path, error=SplatFileError)
        self.size("meta.json")
        try:
            with self.zip.open("meta.json") as f:
                return read_json_stream(f, f"{self.path}: meta.json", error=SplatFileError)
        except (zipfile.BadZipFile, OSError, EOFError) as e:
            raise SplatFileError(f"{self.path}: member 'meta.json': corrupt ({one_line(e, 120)})") from None

    def _member(self, name: str) -> Path:
        member = self.path.parent / name
        if Path(name).name != name or not member.is_file():
            raise SplatFileError(f"{self.path}: file '{one_line(name, 80)}' named in meta.json is not beside it")
        return member

    def size(self, name: str) -> int:
        """The bytes the member ``name`` holds (as declared: the zip directory's uncompressed size)."""
        if self.zip is None:
            return self._member(name).stat().st_size
        try:
            return self.zip.getinfo(name).file_size
        except KeyError:
            raise SplatFileError(f"{self.path}: member '{one_line(name, 80)}' is not in the zip") from None

    def read(self, name: str, count: int | None = None) -> bytes:
        """The member's first ``count`` bytes (None: all :meth:`size` says it holds, never more)."""
        size = self.size(name)
        count = size if count is None else min(count, size)
        try:
            if self.zip is None:
                with open(self._member(name), "rb") as f:
                    return f.read(count)
            with self.zip.open(name) as f:
                return f.read(count)
        except (zipfile.BadZipFile, OSError, EOFError) as e:
            raise SplatFileError(f"{self.path}: member '{one_line(name, 80)}': corrupt ({one_line(e, 120)})") from None

    def close(self) -> None:
        if self.zip is not None:
            self.zip.close()


class _Sized(NamedTuple):
    """An image a SOG names: its file name, its bytes and its pixels' size from its header."""

    name: str
    nbytes: int
    width: int
    height: int


def _images(files: _Files, meta: dict, count: int) -> dict[tuple[str, int], _Sized]:
    """(key, index) -> the sized image ``meta[key].files[index]`` of every image the SOG's decoding reads, from the
    zip directory and the images' first bytes; a per-Gaussian image with fewer than ``count`` pixels is refused."""
    where = f"{files.path}: meta.json"
    wanted = [("means", 0), ("means", 1), ("quats", 0), ("scales", 0), ("sh0", 0)]
    if meta.get("shN"):
        wanted += [("shN", 0), ("shN", 1)]
    sized = {}
    for key, index in wanted:
        name = text_list(meta, where, key, "files", min_length=index + 1)[index]
        shown = one_line(name, 80)
        nbytes = files.size(name)
        dims = image_header_size(files.read(name, HEAD_BYTES))
        if dims is None:
            raise SplatFileError(f"{files.path}: {shown}: not a WebP or PNG image")
        if (key, index) != ("shN", 0) and dims[0] * dims[1] < count:
            raise SplatFileError(f"{files.path}: {shown}: {dims[0]}x{dims[1]} pixels, fewer than count {count}")
        sized[key, index] = _Sized(name, nbytes, *dims)
    return sized


_BYTES_A_PIXEL = 12  # a decoded image (RGBA or RGB), its RGBA conversion and the array made of it


def _decode_image(files: _Files, image: _Sized) -> np.ndarray:
    """(H, W, 4) uint8 pixels of ``image`` (sized before, its memory reserved); SplatFileError names the SOG and
    the image, never Pillow's buffer."""
    shown = one_line(image.name, 80)
    try:
        with Image.open(io.BytesIO(files.read(image.name)), formats=("WEBP", "PNG")) as im:
            if im.size != (image.width, image.height):
                raise SplatFileError(
                    f"{files.path}: {shown}: {im.width}x{im.height} pixels, its header said {image.width}x"
                    f"{image.height}"
                )
            return np.asarray(im.convert("RGBA"))
    except (OSError, ValueError, Image.DecompressionBombError) as e:
        if isinstance(e, SplatFileError):
            raise
        detail = "not an image Pillow reads" if isinstance(e, UnidentifiedImageError) else one_line(e, 120)
        detail = re.sub(r"<_io\.BytesIO object at 0x[0-9a-fA-F]+>", shown, detail)
        raise SplatFileError(f"{files.path}: {shown}: not a readable image ({detail})") from None


class _Plan(NamedTuple):
    """What reading a SOG will hold, sized before any pixel is decoded: its ``meta.json``, Gaussian count, SH
    bands (0: none), images and bytes (:func:`decode_bytes` of the arrays plus each image's bytes and pixels)."""

    meta: dict
    gaussians: int
    bands: int
    images: dict[tuple[str, int], _Sized]
    nbytes: float
    what: str


def plan_sog(files: _Files) -> _Plan:
    """Read ``meta.json`` and type its fields, then size every image from the zip directory and its header."""
    path = files.path
    where = f"{path}: meta.json"
    meta = files.meta()
    if not isinstance(meta, dict):
        raise SplatFileError(f"{where}: expected a JSON object")
    version = meta.get("version")
    if not (isinstance(version, int) and not isinstance(version, bool) and version == VERSION):
        raise SplatFileError(
            f"{where}: version {one_line(repr(version), 40)} is not supported (2; re-save older SOG files with "
            "splat-transform)"
        )
    n = whole_number(meta, where, "count")
    bands = whole_number(meta, where, "shN", "bands", lo=1, hi=3) if meta.get("shN") else 0
    arrays = decode_bytes(n, (bands + 1) ** 2)
    check_memory(arrays, f"{where}: count {n}")  # before a member is looked at
    images = _images(files, meta, n)
    pixels = sum(im.width * im.height for im in images.values())
    nbytes = arrays + sum(im.nbytes + _BYTES_A_PIXEL * im.width * im.height for im in images.values())
    return _Plan(meta, n, bands, images, nbytes, f"{where}: count {n} and {len(images)} images of {pixels:,} pixels")


def decode_sog(files: _Files, plan: _Plan) -> SplatArrays:
    """The Gaussians of an open SOG sized by :func:`plan_sog` (its memory reserved)."""
    where = f"{files.path}: meta.json"
    meta, n, bands, images = plan.meta, plan.gaussians, plan.bands, plan.images
    mins = numbers(meta, where, "means", "mins", length=3)
    maxs = numbers(meta, where, "means", "maxs", length=3)
    scale_book = numbers(meta, where, "scales", "codebook", length=CODEBOOK)
    dc_book = numbers(meta, where, "sh0", "codebook", length=CODEBOOK)

    def pixels_of(key: str, index: int) -> np.ndarray:  # (n, 4): the first n pixels, row-major
        return _decode_image(files, images[key, index]).reshape(-1, 4)[:n]

    lo, hi = pixels_of("means", 0), pixels_of("means", 1)
    q16 = lo[:, :3].astype(np.float64) + 256.0 * hi[:, :3]
    means = inverse_log_transform(mins + (maxs - mins) * (q16 / 65535.0))
    qpx = pixels_of("quats", 0).astype(np.int64)
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
    log_scales = scale_book[pixels_of("scales", 0)[:, :3]]
    sh0 = pixels_of("sh0", 0)
    dc = dc_book[sh0[:, :3]]
    opacities = sh0[:, 3] / 255.0
    rest = np.zeros((n, 0, 3))
    if bands:
        rest = _read_sh_n(files, meta, images, n, bands)
    sh = np.concatenate([dc[:, None, :], rest], axis=1)
    return SplatArrays(means, quats, log_scales, opacities, sh, background_owner(n))


def _read_sh_n(files: _Files, meta: dict, images: dict[tuple[str, int], _Sized], n: int, bands: int) -> np.ndarray:
    """(n, coeffs, 3) the higher SH bands of the ``shN`` palette of ``bands`` bands."""
    path = files.path
    where = f"{path}: meta.json"
    coeffs = _SH_COEFFS[bands]
    book = numbers(meta, where, "shN", "codebook")
    palette = whole_number(meta, where, "shN", "count")
    centroids = _decode_image(files, images["shN", 0])
    cw = centroids.shape[1]
    if cw != 64 * coeffs:
        raise SplatFileError(f"{path}: shN centroids image: width {cw}, expected {64 * coeffs} for {bands} bands")
    centroids_px = centroids.reshape(-1, 4)
    labels_px = _decode_image(files, images["shN", 1]).reshape(-1, 4)[:n].astype(np.int64)
    label = labels_px[:, 0] | (labels_px[:, 1] << 8)
    ok = label < palette
    label = np.where(ok, label, 0)
    pixel = (label // 64)[:, None] * cw + (label % 64)[:, None] * coeffs + np.arange(coeffs)[None, :]  # (n, coeffs)
    inside = pixel < len(centroids_px)
    idx = centroids_px[np.where(inside, pixel, 0)][..., :3].astype(np.int64)  # (n, coeffs, 3)
    if idx.size and idx.max() >= len(book):
        raise SplatFileError(f"{where}: 'shN.codebook' has {len(book)} entries, the palette indexes more")
    rest = book[idx] if len(book) else np.zeros(idx.shape)
    return np.where((ok[:, None] & inside)[..., None], rest, 0.0)


def read_sog(path: str | PathLike) -> PlyFields:
    """Read a bundled ``.sog`` (or an unbundled ``meta.json``) into float32 tensors; SplatFileError names the file
    and the field."""
    path = Path(path)
    files = _Files(path)
    try:
        plan = plan_sog(files)
        with decoding(plan.nbytes, plan.what):
            return to_fields(decode_sog(files, plan), path)
    finally:
        files.close()
