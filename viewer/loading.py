"""Opening what the viewer shows: a model + scene folder (editable particles) or a .ply."""

from __future__ import annotations

import argparse
import sys

from particlesplat.core.sh import SH_C0
from particlesplat.core.vectors import float3
from particlesplat.data.scene_meta import default_checkpoint
from particlesplat.editing.open_scene import demo_scenes, load_model_scene, load_ply_checked

from .session import EditableScene, PlyScene, Scene


def source_inputs(args: argparse.Namespace) -> list[tuple[str, str]]:
    """(flag, path) of the files ``args`` open, nothing read: ``--ply``, or ``--scene`` (default: the first demo
    scene) and ``--checkpoint`` (default: the shipped model of the scene's family)."""
    if getattr(args, "ply", None):
        return [("--ply", str(args.ply))]
    scene = args.scene or next(iter(demo_scenes()), None)
    return [("--scene", str(scene or "")), ("--checkpoint", str(args.checkpoint or default_checkpoint(scene)))]


def load_session(args: argparse.Namespace) -> Scene:
    """A session from ``--ply`` or ``--checkpoint`` + ``--scene`` (defaults: the shipped model
    and the first demo scene), with ``--edits`` applied."""
    if getattr(args, "ply", None):
        return PlyScene(load_ply_checked(args.ply), source=str(args.ply))
    model, encoded, name = load_model_scene(args.checkpoint, args.scene, getattr(args, "context", None))
    checkpoint = str(args.checkpoint or default_checkpoint(encoded.path))
    session = EditableScene(model, encoded, model_name=name, source=str(encoded.path), checkpoint=checkpoint)
    for warning in encoded.warnings:
        print(f"particlesplat-viewer: warning: {warning}", file=sys.stderr)
    if getattr(args, "edits", None):
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
