"""Opening what the viewer shows: a model + scene folder (editable particles) or a .ply."""

from __future__ import annotations

import argparse
import sys

from particlesplat.core.sh import SH_C0
from particlesplat.editing.open_scene import load_model_scene, load_ply_checked

from .session import SceneSession


def load_session(args: argparse.Namespace) -> SceneSession:
    """A session from ``--ply`` or ``--checkpoint`` + ``--scene`` (defaults: the shipped model
    and the first demo scene), with ``--edits`` applied."""
    if getattr(args, "ply", None):
        return SceneSession(gaussians=load_ply_checked(args.ply), source=str(args.ply))
    model, encoded, name = load_model_scene(args.checkpoint, args.scene, getattr(args, "context", None))
    session = SceneSession(model, encoded, model_name=name, source=str(encoded.path))
    for warning in encoded.warnings:
        print(f"particlesplat-viewer: warning: {warning}", file=sys.stderr)
    if getattr(args, "edits", None):
        warning = session.load_edits(args.edits)
        if warning:
            print(f"particlesplat-viewer: warning: {args.edits}: {warning}", file=sys.stderr)
    return session


def particle_swatches(session: SceneSession) -> dict[int, tuple[float, float, float]]:
    """Each particle's base colour: the opacity-weighted mean SH DC colour of its Gaussians."""
    if not session.editable:
        return {}
    g = session.model.decode(session.particles, background=False).detach().to("cpu")
    rgb = (g.sh[:, 0] * SH_C0 + 0.5).clamp(0.0, 1.0)
    out = {}
    for i in range(session.num_particles):
        m = g.owner == i
        if m.any():
            w = g.opacities[m].clamp_min(1e-6)[:, None]
            out[i] = tuple(float(v) for v in ((rgb[m] * w).sum(0) / w.sum()).tolist())
    return out
