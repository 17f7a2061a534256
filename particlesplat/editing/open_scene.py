"""Encode a scene folder into particles the way the viewer and ``particlesplat render`` do."""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from os import PathLike
from pathlib import Path

from particlesplat.core.bundled import bundled_assets
from particlesplat.core.errors import InputWarning, OptionError
from particlesplat.core.limits import check_memory
from particlesplat.core.viewpoints import default_context_views
from particlesplat.core.world import Support
from particlesplat.data import Scene, read_scene
from particlesplat.data.families import DEFAULT_FAMILY, Family, families, get_family
from particlesplat.data.scene_meta import read_support, scene_pose
from particlesplat.editing.source_options import parse_context
from particlesplat.model import Particles, ParticleSplat

# the shipped model on the 32 test scenes, as the README's results table: particlesplat eval [--no-depth]
NO_DEPTH_NOTE = "the shipped model: 17.49 dB PSNR from 2 RGB views, 29.04 dB from 2 RGB-D views, on 32 test scenes"


@dataclass
class EncodedScene:
    """Particles of a scene folder and what they came from.

    Attributes:
        particles: the encoded particles (posterior means).
        scene: the context views at the model's resolution.
        all_cameras: every camera of the folder at its native size (for the default view and
            snapping to input views).
        context: the context frame indices in the folder.
        path: the scene folder.
        warnings: what the user should know about the result (e.g. the scene has no depth).
        support: what the scene's objects rest on (its table and the floor around it, or a floor:
            :func:`particlesplat.data.scene_meta.read_support`).
    """

    particles: Particles
    scene: Scene
    all_cameras: list
    context: list[int]
    path: Path
    warnings: list[str] = field(default_factory=list)
    support: Support = field(default_factory=Support)


def _demo_families() -> list[Family]:
    """The registered families, the default one first."""
    return sorted(families(), key=lambda f: f.name != DEFAULT_FAMILY)


def demo_scenes() -> list[Path]:
    """Scene folders shipped in each registered family's demo folder (``assets/scenes``, ``assets/robot/scenes``;
    where it exists), each sorted, the default family's first (the first is the default scene)."""
    out: list[Path] = []
    for family in _demo_families():
        root = bundled_assets() / family.demo_scenes
        if root.is_dir():
            out += sorted(p for p in root.iterdir() if (p / "transforms.json").is_file())
    return out


def demo_scene_name(path: Path) -> str:
    """A demo scene's name in the viewer's picker: its folder name, after its family's name for a family other
    than the default one (``robot/scene_00000``)."""
    path = Path(path)
    for family in _demo_families():
        if path.parent == bundled_assets() / family.demo_scenes:
            return path.name if family.name == DEFAULT_FAMILY else f"{family.name}/{path.name}"
    return path.name


def encode_scene(
    model: ParticleSplat, path: str | PathLike, context: list[int] | None = None, use_depth: bool = True
) -> EncodedScene:
    """Load ``path`` (a scene folder), pick the context frames (default
    :func:`particlesplat.core.viewpoints.default_context_views`) and encode them with ``model``."""
    raw = read_scene(path)
    ctx = default_context_views(raw.num_frames) if context is None else list(context)
    bad = [i for i in ctx if not 0 <= i < raw.num_frames]
    if not ctx or bad:
        raise OptionError(f"--context: {raw.path} has frames 0..{raw.num_frames - 1}, got {ctx}")
    from particlesplat.model.io import encode_memory

    check_memory(  # the encoder's memory grows with the cube of the context views
        encode_memory(model.config, len(ctx)),
        f"{'--context' if context is not None else 'the default context'}: {len(ctx)} context views of {raw.path} "
        f"(the model: particles_per_view {model.config.particles_per_view}, {model.config.resolution}^2 pixels)",
    )
    scene = raw.select(ctx, model.config.resolution)
    depth = scene.depth if use_depth and scene.depth is not None and bool((scene.depth > 0).any()) else None
    cfg = model.config
    with warnings.catch_warnings(record=True) as caught:  # shown where the scene's other warnings are
        warnings.simplefilter("always", InputWarning)
        pose = scene_pose(raw.path, cfg.bg_static_pose, cfg.bg_static_pose_dims, model.input_ranges)
    from particlesplat.rendering.budget import render_budget

    with render_budget(f"encoding {raw.path} ({cfg.render_keys()})"):  # the refinement's renders, priced first
        particles = model.encode(scene.rgb, depth, scene.cameras, pose)
    notes = [str(w.message) for w in caught]
    if use_depth and depth is None:
        notes.append(
            f"{raw.path}: no depth in the context frames {ctx}: the model was trained with depth, and "
            f"from RGB alone it reconstructs far worse ({NO_DEPTH_NOTE})"
        )
    return EncodedScene(particles, scene, list(raw.cameras), ctx, Path(raw.path), notes, read_support(raw.path))


def load_model_scene(
    checkpoint: str | None,
    scene: str | PathLike | None,
    context: str | None = None,
    progress: Callable[[str], None] | None = None,
    load: Callable[[str | Path], ParticleSplat] | None = None,
):
    """Load a model (None = the shipped model of the scene's family) and encode ``scene`` (None = the first demo
    scene). ``progress`` hears what is being done as it starts ("loading the model assets/model.pt", "encoding
    scene_00000 from frames 4, 16"); ``load`` loads a checkpoint (default :func:`particlesplat.model.load_model`;
    the viewer's keeps the models it loaded).

    Returns (model, EncodedScene, model name for PNG/YAML metadata).
    """
    from particlesplat.data.scene_meta import default_checkpoint
    from particlesplat.model import load_model
    from particlesplat.model.io import shipped_model_name

    if scene is None:
        scenes = demo_scenes()
        if not scenes:
            where = f"assets/{get_family(DEFAULT_FAMILY).demo_scenes}"
            raise FileNotFoundError(f"no demo scenes in {where}; pass --scene DIR (or --ply FILE)")
        scene = scenes[0]
    path = checkpoint or default_checkpoint(scene)  # the shipped model of the scene's family
    say = progress or (lambda _: None)
    say(f"loading the model {shipped_model_name(path)}")
    model = (load or load_model)(path)
    frames = parse_context(context)
    say(f"encoding {Path(scene).name}" + (f" from frames {', '.join(map(str, frames))}" if frames else ""))
    return model, encode_scene(model, scene, frames), shipped_model_name(path)


def load_ply_checked(path: str | PathLike):
    """Gaussians of a Gaussian file in any format the program reads (.ply, .compressed.ply, .splat, .spz, .sog:
    :func:`particlesplat.formats.splat_files.read_gaussians`); FileNotFoundError names the path."""
    from particlesplat.core.gaussians import Gaussians

    return Gaussians.load(path)
