"""Opening what the viewer shows: a model + scene folder (editable particles) or a .ply."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from particlesplat.core.sh import SH_C0
from particlesplat.core.vectors import float3
from particlesplat.data.scene_meta import default_checkpoint
from particlesplat.editing.open_scene import demo_scenes, load_model_scene, load_ply_checked

from .session import EditableScene, PlyScene, Scene

if TYPE_CHECKING:
    from particlesplat.model import ParticleSplat


def source_inputs(args: argparse.Namespace) -> list[tuple[str, str]]:
    """(flag, path) of the files ``args`` open, nothing read: ``--ply``, or ``--scene`` (default: the first demo
    scene) and ``--checkpoint`` (default: the shipped model of the scene's family)."""
    if getattr(args, "ply", None):
        return [("--ply", str(args.ply))]
    scene = args.scene or next(iter(demo_scenes()), None)
    return [("--scene", str(scene or "")), ("--checkpoint", str(args.checkpoint or default_checkpoint(scene)))]


_MODELS: dict[tuple[str, int, int], ParticleSplat] = {}  # the models loaded, by resolved path, mtime and size


def cached_model(path: str | Path) -> ParticleSplat:
    """The model of checkpoint ``path``, loaded once a viewer process (:func:`particlesplat.model.load_model`):
    switching between two families' scenes reloads neither model. A checkpoint whose file changed loads again."""
    from particlesplat.data.families import shipped_model_named
    from particlesplat.model import load_model

    found = shipped_model_named(path) or Path(path)  # a shipped model's name opens it from anywhere
    try:
        stat = found.stat()
        key = (str(found.resolve()), stat.st_mtime_ns, stat.st_size)
    except OSError:
        return load_model(path)  # the loader names what is missing
    if key not in _MODELS:
        _MODELS[key] = load_model(path)
    return _MODELS[key]


def load_session(args: argparse.Namespace, progress: Callable[[str], None] | None = None) -> Scene:
    """A session from ``--ply`` or ``--checkpoint`` + ``--scene`` (defaults: the shipped model
    and the first demo scene), with ``--edits`` applied. ``progress`` hears each stage as it starts (loading the
    model, encoding the scene, applying the edits)."""
    say = progress or (lambda _: None)
    if getattr(args, "ply", None):
        say(f"reading {Path(args.ply).name}")
        return PlyScene(load_ply_checked(args.ply), source=str(args.ply))
    model, encoded, name = load_model_scene(
        args.checkpoint, args.scene, getattr(args, "context", None), progress, cached_model
    )
    checkpoint = str(args.checkpoint or default_checkpoint(encoded.path))
    session = EditableScene(model, encoded, model_name=name, source=str(encoded.path), checkpoint=checkpoint)
    for warning in encoded.warnings:
        print(f"particlesplat-viewer: warning: {warning}", file=sys.stderr)
    if getattr(args, "edits", None):
        say(f"applying the edits of {Path(args.edits).name}")
        warning = session.load_edits(args.edits)
        if warning:
            print(f"particlesplat-viewer: warning: {args.edits}: {warning}", file=sys.stderr)
    return session


def particle_swatches(session: Scene) -> dict[int, tuple[float, float, float]]:
    """Each particle's base colour: the opacity-weighted mean SH DC colour of its Gaussians (none for a .ply)."""
    editor = session.editor
    if editor is None:
        return {}
    g = editor.model.decode(editor.particles, background=False).detach().to("cpu")
    rgb = (g.sh[:, 0] * SH_C0 + 0.5).clamp(0.0, 1.0)
    out: dict[int, tuple[float, float, float]] = {}
    for i in range(editor.num_particles):
        m = g.owner == i
        if m.any():
            w = g.opacities[m].clamp_min(1e-6)[:, None]
            out[i] = float3(((rgb[m] * w).sum(0) / w.sum()).tolist())
    return out
