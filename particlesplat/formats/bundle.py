"""Object bundles: a scene as one ``.ply`` per part (a particle or an object) plus ``rest.ply``, and a manifest.

A bundle is a folder::

    manifest.json      what the parts are (below)
    particle_<i>.ply   (or object_<k>.ply) one INRIA .ply per part, owners kept
    rest.ply           every Gaussian no part holds (background, static layers, particles in no object)

``manifest.json`` holds ``format`` ("particlesplat-bundle"), ``version`` (1), ``by`` ("particle" or "object"),
``gaussians`` (the scene's count), whatever the writer's ``header`` adds (scene, model, context cameras), and
``parts``: one entry per file, each with ``name``, ``file``, ``gaussians`` and the writer's fields (centre,
extent, presence, object label, member particles). Every Gaussian of the scene is in exactly one file, so the
files concatenated are the scene (:func:`read_bundle`).
"""

from __future__ import annotations

import json
import os
import shutil
import uuid
from collections.abc import Sequence
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
import torch

from particlesplat.core.errors import one_line
from particlesplat.core.jsonfile import read_json
from particlesplat.core.limits import reserve_memory
from particlesplat.core.outputs import OutputError
from particlesplat.formats.header_fields import text, whole_number
from particlesplat.formats.ply import GaussianFields, PlyFields, ply_size, read_ply, write_ply
from particlesplat.formats.splat_arrays import SplatFileError

FORMAT = "particlesplat-bundle"
VERSION = 1
MANIFEST = "manifest.json"
REST = "rest"


def write_bundle(
    out: str | PathLike, by: str, parts: Sequence[tuple[str, GaussianFields, dict[str, Any]]], header: dict[str, Any]
) -> dict[str, Any]:
    """Write the folder ``out``: ``<name>.ply`` for each (name, Gaussians, manifest fields) of ``parts`` (the last
    one, named ``rest``, holds what the others do not) and ``manifest.json``. The folder is written beside
    ``out`` and renamed into place; an ``out`` that exists must be an empty folder or an earlier bundle (it is
    replaced), else OutputError names it (:func:`check_bundle_target`). Returns the manifest."""
    out = check_bundle_target(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.parent / f".{out.name}.tmp-{uuid.uuid4().hex[:8]}"
    tmp.mkdir()
    try:
        entries = []
        for name, g, info in parts:
            write_ply(g, tmp / f"{name}.ply")
            entries.append({"name": name, "file": f"{name}.ply", "gaussians": int(g.num), **info})
        manifest = {
            "format": FORMAT,
            "version": VERSION,
            "by": by,
            "gaussians": sum(e["gaussians"] for e in entries),
            **header,
            "parts": entries,
        }
        (tmp / MANIFEST).write_text(json.dumps(manifest, indent=1) + "\n", encoding="utf-8")
        old = None
        if out.exists():
            old = out.parent / f".{out.name}.old-{uuid.uuid4().hex[:8]}"
            os.replace(out, old)
        os.replace(tmp, out)
        if old is not None:
            shutil.rmtree(old)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return manifest


def check_bundle_target(out: str | PathLike) -> Path:
    """``out`` as a Path; OutputError naming it unless it is absent, an empty folder or an earlier bundle holding
    nothing but its ``manifest.json`` and the files it lists (what :func:`write_bundle` may replace: a file of the
    user's in the folder is never swapped away with it). Nothing is created."""
    out = Path(out)
    if not out.exists() and not out.is_symlink():
        return out
    if not out.is_dir() or out.is_symlink():
        raise OutputError(f"{out}: exists and is not a folder: a bundle is written as a folder")
    if not any(out.iterdir()):
        return out
    try:
        _, manifest = read_manifest(out)
    except (OSError, SplatFileError):
        raise OutputError(
            f"{out}: a folder that is neither empty nor a bundle (no readable {MANIFEST}): not replaced"
        ) from None
    listed = {MANIFEST} | {p.get("file") for p in manifest["parts"]}
    other = sorted(p.name for p in out.iterdir() if p.name not in listed)
    if other:
        raise OutputError(
            f"{out}: holds {one_line(other[0], 80)}{f' and {len(other) - 1} more' if len(other) > 1 else ''}, which "
            f"its {MANIFEST} does not list: the bundle is not replaced (move it out first)"
        )
    return out


def read_manifest(path: str | PathLike) -> tuple[Path, dict[str, Any]]:
    """(the bundle folder, its manifest) for a bundle folder or its ``manifest.json``, read by the checked JSON
    reader (:mod:`particlesplat.core.jsonfile`: at most 16 MiB, nesting); SplatFileError names the file and the
    field."""
    path = Path(path)
    folder = path if path.is_dir() else path.parent
    file = folder / MANIFEST
    try:
        manifest = read_json(file, error=SplatFileError)
    except FileNotFoundError:
        raise FileNotFoundError(f"{file}: bundle manifest not found") from None
    if not isinstance(manifest, dict) or manifest.get("format") != FORMAT:
        raise SplatFileError(f"{file}: format: not a {FORMAT} manifest")
    version = manifest.get("version")
    if not (isinstance(version, int) and not isinstance(version, bool) and version == VERSION):
        raise SplatFileError(f"{file}: version: {one_line(repr(version), 40)} is not {VERSION}")
    parts = manifest.get("parts")
    if not isinstance(parts, list) or not all(isinstance(p, dict) for p in parts):
        raise SplatFileError(f"{file}: parts: expected a list of objects")
    return folder, manifest


def read_bundle(path: str | PathLike) -> PlyFields:
    """The whole scene of a bundle (its parts' Gaussians concatenated in manifest order, owners kept).

    Every part is sized from its ``.ply`` header first, and the sum (the parts kept, their SH padded, the scene
    they make) reserved of the job's memory limit before any part is read: a part listed many times cannot pass
    where each alone would. SplatFileError names the manifest and the part whose file is missing, outside the
    folder, listed twice or of another Gaussian count than the manifest says."""
    folder, manifest = read_manifest(path)
    where = str(folder / MANIFEST)
    files: list[Path] = []
    first: dict[str, int] = {}
    sizes = []
    for i in range(len(manifest["parts"])):
        name = text(manifest, where, "parts", i, "file")
        if Path(name).name != name or not name.endswith(".ply"):
            raise SplatFileError(f"{where}: parts.{i}.file: expected a .ply file name in the folder")
        if name in first:
            raise SplatFileError(
                f"{where}: parts.{i}.file: {one_line(name, 80)} is listed already as parts.{first[name]}.file (each "
                "Gaussian is in one file)"
            )
        first[name] = i
        declared = whole_number(manifest, where, "parts", i, "gaussians")
        n, bases, _ = ply_size(folder / name)
        if declared != n:
            raise SplatFileError(f"{where}: parts.{i}.gaussians: {declared}, but {one_line(name, 80)} holds {n}")
        files.append(folder / name)
        sizes.append((n, bases))
    if not files:
        raise SplatFileError(f"{where}: parts: the bundle lists no files")
    total, k = sum(n for n, _ in sizes), max(b for _, b in sizes)
    kept = sum(n * _tensor_bytes(b) for n, b in sizes)
    with reserve_memory(kept + 2 * total * _tensor_bytes(k), f"{where}: {len(files)} parts of {total:,} Gaussians"):
        fields = [read_ply(file) for file in files]
        sh = [torch.nn.functional.pad(f.sh, (0, 0, 0, k - f.sh.shape[1])) for f in fields]
        return PlyFields(
            means=torch.cat([f.means for f in fields]),
            quats=torch.cat([f.quats for f in fields]),
            scales=torch.cat([f.scales for f in fields]),
            opacities=torch.cat([f.opacities for f in fields]),
            sh=torch.cat(sh),
            owner=torch.cat([f.owner for f in fields]),
        )


def _tensor_bytes(bases: int) -> int:
    """Bytes of one Gaussian's float32 tensors with ``bases`` SH bases a channel, and its int64 owner."""
    return 4 * (3 + 4 + 3 + 1 + 3 * bases) + 8


def weighted_centre(g: GaussianFields) -> tuple[list[float], list[float]]:
    """(centre, extent) of a part: the opacity-weighted mean of its Gaussians' positions and their weighted
    standard deviation along world x, y, z (metres); zeros for a part that draws nothing."""
    means = g.means.detach().double().cpu().numpy()
    w = g.opacities.detach().double().cpu().numpy()
    total = w.sum()
    if len(means) == 0 or total <= 0:
        return [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]
    centre = (w[:, None] * means).sum(0) / total
    extent = np.sqrt((w[:, None] * (means - centre) ** 2).sum(0) / total)
    return [float(v) for v in centre], [float(v) for v in extent]
