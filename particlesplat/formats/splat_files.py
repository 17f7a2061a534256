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

import importlib
from os import PathLike
from pathlib import Path
from typing import TYPE_CHECKING, NamedTuple

from particlesplat.core.errors import OptionError, one_line

if TYPE_CHECKING:  # the table loads without torch: commands name the extensions in their --help
    from particlesplat.formats.ply import GaussianFields, PlyFields


class SplatFormat(NamedTuple):
    """A Gaussian file format: its extension, a short description and where its writer and reader live (the
    module is imported on first use: Pillow only for SOG)."""

    suffix: str
    description: str
    module: str
    writer: str
    reader: str

    def write(self, gaussians: GaussianFields, path: str | PathLike) -> None:
        getattr(importlib.import_module(self.module), self.writer)(gaussians, path)

    def read(self, path: str | PathLike) -> PlyFields:
        return getattr(importlib.import_module(self.module), self.reader)(path)


_F = "particlesplat.formats."
FORMATS: tuple[SplatFormat, ...] = (
    SplatFormat(".ply", "INRIA 3DGS .ply", _F + "ply", "write_ply", "read_ply"),
    SplatFormat(
        ".compressed.ply",
        "PlayCanvas compressed .ply",
        _F + "compressed_ply",
        "write_compressed_ply",
        "read_compressed_ply",
    ),
    SplatFormat(".splat", "antimatter15 .splat", _F + "splat", "write_splat", "read_splat"),
    SplatFormat(".spz", "Niantic SPZ v3", _F + "spz", "write_spz", "read_spz"),
    SplatFormat(".sog", "PlayCanvas SOG v2", _F + "sog", "write_sog", "read_sog"),
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
            from particlesplat.formats.compressed_ply import is_compressed
            from particlesplat.formats.ply import read_header

            _, elements = read_header(f, path)

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
