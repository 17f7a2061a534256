"""Screenshots and exports: PNG with text chunks (camera, edits, model), numbered names that
never overwrite, and Gaussian file export (.ply and the compact formats). Each takes the scene's ``guard``
(:meth:`viewer.session.SceneFiles.guard_output`), called with the name before anything is written."""

from __future__ import annotations

import os
from collections.abc import Callable
from os import PathLike
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from particlesplat.core.atomic import create_temp_file
from particlesplat.core.gaussians import Gaussians
from particlesplat.formats.png import png_info, png_text, save_png, to_image

if TYPE_CHECKING:
    from .session import Scene

__all__ = ["BUNDLE", "export_bundle", "export_ply", "png_text", "save_numbered", "save_png", "save_screenshot"]
BUNDLE = "bundle"  # the export menu's entry for an object bundle (particlesplat.formats.bundle)
Guard = Callable[[Path], None]  # raises (OutputError) when a path may not be written


def _unguarded(path: Path) -> None:
    pass


def save_numbered(folder: str | PathLike, prefix: str, suffix: str, write, guard: Guard = _unguarded) -> Path:
    """Write a new file ``<prefix>NNNN<suffix>`` in ``folder`` with the first free number.

    ``guard(path)`` is called with the first free name before anything (the folder, the temporary file) is
    written. ``write(tmp_path)`` writes the content to a temporary file; it is then hard-linked to the
    numbered name, which fails instead of overwriting if that name appeared meanwhile.
    """
    folder = Path(folder)
    n = 1
    while (folder / f"{prefix}{n:04d}{suffix}").exists():
        n += 1
    guard(folder / f"{prefix}{n:04d}{suffix}")
    folder.mkdir(parents=True, exist_ok=True)
    fd, tmp = create_temp_file(folder / prefix, suffix)
    os.close(fd)
    try:
        write(tmp)
        taken = {p.name for p in folder.glob(f"{prefix}*{suffix}")}
        n = 1
        while True:
            name = f"{prefix}{n:04d}{suffix}"
            if name not in taken:
                try:
                    os.link(tmp, folder / name)
                    return folder / name
                except FileExistsError:
                    pass
            n += 1
    finally:
        os.unlink(tmp)


def save_screenshot(folder: str | PathLike, rgb: np.ndarray, text: dict[str, str], guard: Guard = _unguarded) -> Path:
    """A numbered PNG screenshot (``particlesplat_NNNN.png``) in ``folder``; rgb: (H, W, 3) in [0, 1]."""
    img, info = to_image(rgb), png_info(text)
    return save_numbered(folder, "particlesplat_", ".png", lambda p: img.save(p, format="PNG", pnginfo=info), guard)


def export_ply(folder: str | PathLike, gaussians: Gaussians, suffix: str = ".ply", guard: Guard = _unguarded) -> Path:
    """A numbered Gaussian file (``particlesplat_NNNN<suffix>``) of ``gaussians`` in ``folder``, in the format
    ``suffix`` names (:data:`particlesplat.formats.splat_files.SUFFIXES`: .ply, .compressed.ply, .splat, .spz,
    .sog)."""
    from particlesplat.formats.splat_files import format_for

    fmt = format_for(f"particlesplat{suffix}")
    return save_numbered(folder, "particlesplat_", fmt.suffix, lambda p: fmt.write(gaussians, p), guard)


def export_bundle(folder: str | PathLike, gaussians: Gaussians, session: Scene) -> Path:
    """A numbered object bundle (folder ``particlesplat_NNNN.bundle``) of ``gaussians`` in ``folder``: by object
    (the user's groups, as the scene's editor holds them) for a model scene, by particle (the owners stored) for a
    Gaussian file. The session's guard is asked first (``export``)."""
    from particlesplat.analysis.bundle_parts import bundle_header, bundle_parts
    from particlesplat.analysis.particle_arrays import particle_arrays
    from particlesplat.editing.scene_objects import SceneObjects
    from particlesplat.formats.bundle import write_bundle

    folder = Path(folder)
    n = 1
    while (folder / f"particlesplat_{n:04d}.bundle").exists():
        n += 1
    out = folder / f"particlesplat_{n:04d}.bundle"
    session.guard_output("export", out)
    folder.mkdir(parents=True, exist_ok=True)
    editor = session.editor
    if editor is not None:
        arrays = particle_arrays(editor.model, editor.particles, objects=SceneObjects(editor.objects()))
        edited = bool(editor.history.undo)
        header = bundle_header(session.source, session.model_name, editor.particles, editor.context, edited)
        write_bundle(out, "object", bundle_parts(gaussians, "object", arrays), header)
    else:
        write_bundle(out, "particle", bundle_parts(gaussians, "particle", None), bundle_header(session.source, None))
    return out
