"""One entry point for the Gaussian file formats: the writer chosen by the output's extension, the reader by the
file's first bytes (then its extension).

- ``.ply``: INRIA 3DGS ``.ply`` (:mod:`.ply`): everything as float32, and each Gaussian's owner;
- ``.compressed.ply``: PlayCanvas's compressed ``.ply`` (:mod:`.compressed_ply`): 11/10/11-bit positions and
  scales within chunks of 256, 8-bit colour and opacity, SH as bytes;
- ``.splat``: antimatter15's ``.splat`` (:mod:`.splat`): float32 positions and sizes, 8-bit colour, no SH;
- ``.spz``: Niantic's SPZ v3 (:mod:`.spz`): 24-bit positions, 8-bit values, SH to degree 3;
- ``.sog``: PlayCanvas's SOG v2 (:mod:`.sog`): 16-bit positions, 256-entry codebooks, SH degree 0.

An object bundle's ``manifest.json`` (:mod:`.bundle`) reads as its parts merged.
"""

from __future__ import annotations

from collections.abc import Callable
from os import PathLike
from pathlib import Path
from typing import NamedTuple

from particlesplat.core.errors import OptionError, one_line
from particlesplat.formats.ply import GaussianFields, PlyFields, read_header, read_ply, write_ply


class SplatFormat(NamedTuple):
    """A Gaussian file format: its extension, a short description, its writer and reader."""

    suffix: str
    description: str
    write: Callable[[GaussianFields, str | PathLike], None]
    read: Callable[[str | PathLike], PlyFields]


def _write_compressed(g: GaussianFields, path: str | PathLike) -> None:
    from particlesplat.formats.compressed_ply import write_compressed_ply

    write_compressed_ply(g, path)


def _read_compressed(path: str | PathLike) -> PlyFields:
    from particlesplat.formats.compressed_ply import read_compressed_ply

    return read_compressed_ply(path)


def _write_splat(g: GaussianFields, path: str | PathLike) -> None:
    from particlesplat.formats.splat import write_splat

    write_splat(g, path)


def _read_splat(path: str | PathLike) -> PlyFields:
    from particlesplat.formats.splat import read_splat

    return read_splat(path)


def _write_spz(g: GaussianFields, path: str | PathLike) -> None:
    from particlesplat.formats.spz import write_spz

    write_spz(g, path)


def _read_spz(path: str | PathLike) -> PlyFields:
    from particlesplat.formats.spz import read_spz

    return read_spz(path)


def _write_sog(g: GaussianFields, path: str | PathLike) -> None:
    from particlesplat.formats.sog import write_sog

    write_sog(g, path)


def _read_sog(path: str | PathLike) -> PlyFields:
    from particlesplat.formats.sog import read_sog

    return read_sog(path)


FORMATS: tuple[SplatFormat, ...] = (
    SplatFormat(".ply", "INRIA 3DGS .ply", write_ply, read_ply),
    SplatFormat(".compressed.ply", "PlayCanvas compressed .ply", _write_compressed, _read_compressed),
    SplatFormat(".splat", "antimatter15 .splat", _write_splat, _read_splat),
    SplatFormat(".spz", "Niantic SPZ v3", _write_spz, _read_spz),
    SplatFormat(".sog", "PlayCanvas SOG v2", _write_sog, _read_sog),
)
SUFFIXES = tuple(f.suffix for f in FORMATS)
SUFFIX_HELP = ", ".join(SUFFIXES)


def format_for(path: str | PathLike) -> SplatFormat:
    """The format named by ``path``'s extension; OptionError naming the path and the extensions otherwise."""
    name = Path(path).name.lower()
    for fmt in sorted(FORMATS, key=lambda f: -len(f.suffix)):  # ".compressed.ply" before ".ply"
        if name.endswith(fmt.suffix) and len(name) > len(fmt.suffix):
            return fmt
    raise OptionError(f"{path}: unknown Gaussian file extension (have: {SUFFIX_HELP})")


def write_gaussians(gaussians: GaussianFields, path: str | PathLike) -> SplatFormat:
    """Write ``gaussians`` to ``path`` in the format its extension names, atomically. Returns the format."""
    fmt = format_for(path)
    fmt.write(gaussians, path)
    return fmt


def sniff_format(path: str | PathLike) -> SplatFormat:
    """The format of the file at ``path``: by its first bytes (a PLY header, compressed or not; gzip: SPZ; a zip
    or a ``meta.json``: SOG), else by its extension (``.splat`` has no magic)."""
    path = Path(path)
    by_suffix = {f.suffix: f for f in FORMATS}
    if path.name == "meta.json":
        return by_suffix[".sog"]
    with open(path, "rb") as f:
        head = f.read(4)
        if head[:3] == b"ply":
            f.seek(0)
            _, elements = read_header(f, path)
            from particlesplat.formats.compressed_ply import is_compressed

            return by_suffix[".compressed.ply" if is_compressed(elements) else ".ply"]
    if head[:2] == b"\x1f\x8b" or head == b"NGSP":
        return by_suffix[".spz"]
    if head == b"PK\x03\x04":
        return by_suffix[".sog"]
    try:
        return format_for(path)
    except OptionError:
        raise OptionError(
            f"{path}: not a Gaussian file this program reads (first bytes {one_line(repr(head), 40)}; have: "
            f"{SUFFIX_HELP})"
        ) from None


def read_gaussians(path: str | PathLike) -> PlyFields:
    """Read any supported Gaussian file (:func:`sniff_format`), or an object bundle's ``manifest.json`` (its parts
    merged), into float32 tensors (``Gaussians(*fields)``).
    FileNotFoundError names a missing path; a bad file raises a UserError naming the file and the field."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: Gaussian file not found")
    if path.name == "manifest.json":  # an object bundle: its parts merged (particlesplat.formats.bundle)
        from particlesplat.formats.bundle import read_bundle

        return read_bundle(path)
    return sniff_format(path).read(path)
