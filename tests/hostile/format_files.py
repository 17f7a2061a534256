"""Hostile Gaussian files for the format readers' guards: each builder writes one file (or folder) from a good one
and returns its path. Large files are sparse (``truncate``): they take no disk, and a reader that reads them whole
takes gigabytes of memory."""

from __future__ import annotations

import io
import json
import struct
import zipfile
from collections.abc import Callable
from pathlib import Path

import numpy as np


def sparse(path: Path, head: bytes, size: int) -> Path:
    """A file of ``size`` bytes: ``head``, then zeros that take no disk."""
    with open(path, "wb") as f:
        f.write(head)
        f.truncate(size)
    return path


def sog_rewritten(src: Path, dst: Path, meta_edit: Callable[[dict], None] | None = None, **members: bytes) -> Path:
    """A copy of the ``.sog`` ``src`` with ``meta_edit(meta)`` applied to its meta.json and ``members`` (name with
    ``_`` for ``.``: ``quats_webp``) replaced or added."""
    new = {name.replace("_webp", ".webp").replace("_json", ".json"): data for name, data in members.items()}
    with zipfile.ZipFile(src) as z, zipfile.ZipFile(dst, "w", zipfile.ZIP_DEFLATED) as out:
        for name in z.namelist():
            data = z.read(name)
            if name == "meta.json" and meta_edit is not None:
                meta = json.loads(data)
                meta_edit(meta)
                data = json.dumps(meta).encode()
            out.writestr(name, new.pop(name, data))
        for name, data in new.items():
            out.writestr(name, data)
    return dst


def webp_image(width: int, height: int) -> bytes:
    """A lossless WebP of one colour, ``width`` x ``height`` (a few KB for 4096^2 pixels)."""
    from PIL import Image

    buf = io.BytesIO()
    Image.new("RGBA", (width, height), (128, 128, 128, 255)).save(buf, format="WEBP", lossless=True, method=0)
    return buf.getvalue()


def vp8l_header(width: int, height: int, body: bytes = b"") -> bytes:
    """A WebP lossless (VP8L) header of ``width`` x ``height`` followed by ``body`` (no valid image data)."""
    bits = (width - 1) | ((height - 1) << 14)
    chunk = b"\x2f" + bits.to_bytes(4, "little") + body
    riff = b"WEBP" + b"VP8L" + struct.pack("<I", len(chunk)) + chunk
    return b"RIFF" + struct.pack("<I", len(riff)) + riff


def sog_of_big_images(good: Path, dst: Path, side: int = 4096) -> Path:
    """A ``.sog`` of ``good``'s meta.json (its count) whose five images are each ``side``^2 pixels: each alone fits
    a few hundred MB, the five together do not."""
    image = webp_image(side, side)
    names = ("means_l", "means_u", "quats", "scales", "sh0")
    return sog_rewritten(good, dst, None, **{f"{n}_webp": image for n in names})


def unbundled_sog_with_sparse_member(good: Path, folder: Path, size: int = 2 << 30) -> Path:
    """An unbundled SOG (``folder/meta.json`` and its images) of ``good`` whose ``means_l.webp`` is a small valid
    header followed by zeros to ``size`` bytes (sparse)."""
    folder.mkdir(parents=True)
    with zipfile.ZipFile(good) as z:
        z.extractall(folder)
    sparse(folder / "means_l.webp", vp8l_header(8, 8), size)
    return folder / "meta.json"


def compressed_ply_edited(src: Path, dst: Path, header_edit=None, chunk_values: dict[str, float] | None = None):
    """A copy of the compressed ``.ply`` ``src`` with ``header_edit(text)`` applied to its header and, in its first
    chunk row, the float properties ``chunk_values`` set."""
    data = src.read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    header = data[:end].decode("ascii")
    body = bytearray(data[end:])
    if chunk_values:
        names = [line.split()[-1] for line in header.split("element chunk")[1].split("element")[0].splitlines()[1:]]
        for name, value in chunk_values.items():
            body[4 * names.index(name) : 4 * names.index(name) + 4] = np.float32(value).tobytes()
    if header_edit is not None:
        header = header_edit(header)
    dst.write_bytes(header.encode("ascii") + bytes(body))
    return dst


PLY_PROPS = "x y z nx ny nz f_dc_0 f_dc_1 f_dc_2 opacity scale_0 scale_1 scale_2 rot_0 rot_1 rot_2 rot_3".split()


def sparse_ply(path: Path, vertices: int) -> Path:
    """A 3DGS ``.ply`` of ``vertices`` all-zero records (valid: unit scales, opacity 0.5), sparse on disk."""
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {vertices}"]
    header += [f"property float {p}" for p in PLY_PROPS] + ["end_header"]
    head = ("\n".join(header) + "\n").encode("ascii")
    return sparse(path, head, len(head) + vertices * 4 * len(PLY_PROPS))


def bundle_folder(folder: Path, parts: list[tuple[str, int]], copy_of: Path | None = None) -> Path:
    """A bundle folder whose manifest lists ``parts`` (file name, Gaussians); each file named is a copy of the .ply
    ``copy_of``, or (None) a sparse .ply of the count its first listing says."""
    folder.mkdir(parents=True)
    for name, count in parts:
        if (folder / name).exists():
            continue
        if copy_of is not None:
            (folder / name).write_bytes(copy_of.read_bytes())
        else:
            sparse_ply(folder / name, count)
    entries = [{"name": Path(n).stem, "file": n, "gaussians": c} for n, c in parts]
    manifest = {
        "format": "particlesplat-bundle",
        "version": 1,
        "by": "particle",
        "gaussians": sum(c for _, c in parts),
        "parts": entries,
    }
    (folder / "manifest.json").write_text(json.dumps(manifest))
    return folder / "manifest.json"
