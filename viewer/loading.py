"""Opening what the viewer shows: a model + scene folder (editable particles) or a .ply."""

from __future__ import annotations

import argparse
from pathlib import Path

import torch

from particlesplat.encode_scene import demo_scenes, encode_scene, parse_context
from particlesplat.gaussians import Gaussians
from particlesplat.sh import SH_C0

from .session import SceneSession


def load_session(args: argparse.Namespace) -> SceneSession:
    """A session from ``--ply`` or ``--checkpoint`` + ``--scene`` (defaults: the shipped model
    and the first demo scene), with ``--edits`` applied."""
    if getattr(args, "ply", None):
        path = Path(args.ply)
        if not path.is_file():
            raise FileNotFoundError(f"{path}: .ply file not found")
        return SceneSession(gaussians=Gaussians.load_ply(path), source=str(path))
    from particlesplat.model import load_model

    model = load_model(args.checkpoint)
    scene = args.scene
    if scene is None:
        scenes = demo_scenes()
        if not scenes:
            raise FileNotFoundError("no demo scenes in assets/scenes; pass --scene DIR or --ply FILE")
        scene = scenes[0]
    encoded = encode_scene(model, scene, parse_context(getattr(args, "context", None)))
    session = SceneSession(model, encoded, model_name=str(args.checkpoint or "assets/model.pt"), source=str(scene))
    if getattr(args, "edits", None):
        session.load_edits(args.edits)
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
