"""``particlesplat encode``: write the particles of every scene folder under a folder as ``.npz`` arrays.

``OUT/<scene>.npz`` holds the arrays of :mod:`particlesplat.analysis.particle_arrays` (scene folders nested under
``--data``, e.g. ``train/scene_00000``, keep their relative path). Scenes are encoded ``--batch`` at a time
in one forward pass; a scene whose ``.npz`` exists is skipped, so an interrupted run resumes; each file is
written under a temporary name and renamed when complete.
"""

from __future__ import annotations

import argparse
import os
import time
from os import PathLike
from pathlib import Path

import torch
from tqdm import tqdm

from particlesplat.analysis.particle_arrays import OBJECT_CENTRES, file_sha256, particle_arrays
from particlesplat.core.viewpoints import default_context_views
from particlesplat.data import Scene, read_scene
from particlesplat.data.scene import TRANSFORMS
from particlesplat.model import Particles, ParticleSplat
from particlesplat.model.geometry import stack_cameras


def find_scenes(root: str | PathLike) -> list[Path]:
    """``root`` itself when it is a scene folder (holds ``transforms.json``), else every scene folder below it
    (sorted; hidden folders, e.g. a generator's unfinished temporaries, are skipped)."""
    root = Path(root)
    if not root.is_dir():
        raise FileNotFoundError(f"{root}: no such folder")
    if (root / TRANSFORMS).is_file():
        return [root]
    found, seen = [], set()
    for folder, subdirs, files in os.walk(root, followlinks=True):  # symlinked scene folders count
        real = os.path.realpath(folder)
        if real in seen:  # a symlink cycle
            subdirs[:] = []
            continue
        seen.add(real)
        subdirs[:] = sorted(d for d in subdirs if not d.startswith("."))
        if TRANSFORMS in files:
            found.append(Path(folder))
    if not found:
        raise FileNotFoundError(f"{root}: no scene folders (folders with {TRANSFORMS}) in it")
    return sorted(found)


def output_path(root: Path, scene: Path, out: Path) -> Path:
    """``out/<scene path relative to root>.npz`` (``out/<name>.npz`` when root is the scene itself)."""
    rel = Path(scene.name) if scene == root else scene.relative_to(root)
    return out / rel.parent / f"{rel.name}.npz"


@torch.no_grad()
def encode_batch(model: ParticleSplat, scenes: list[Scene]) -> list[Particles]:
    """Posterior means of B scenes in one forward pass (the same particles as :meth:`ParticleSplat.encode` of
    each). The scenes must share the number of views, the model's resolution, and either all have depth or
    none (depth None)."""
    dev = next(model.parameters()).device
    rgb = torch.stack([s.rgb for s in scenes]).to(dev)  # (B, V, 3, H, W)
    has_depth = [s.depth is not None for s in scenes]
    if any(has_depth) and not all(has_depth):
        raise ValueError("encode_batch: scenes with and without depth in one batch")
    depth = torch.stack([s.depth for s in scenes]).to(dev) if all(has_depth) else None
    cams = [stack_cameras(s.cameras, device=dev) for s in scenes]
    K = torch.stack([k for k, _ in cams])
    c2w = torch.stack([c for _, c in cams])
    post = model.refine(model.posterior(rgb, depth, K, c2w), rgb, depth, K, c2w)
    z = model.latents(post, sample=False)
    return [
        Particles(
            z_p=z["z_p"][b],
            z_s=z["z_s"][b],
            z_d=z["z_d"][b],
            z_e=z["z_e"][b],
            z_t=z["z_t"][b],
            z_f=z["z_f"][b],
            view=post.view,
            background=z["bg"][b],
            cameras=[c.to(dev) for c in s.cameras],
        )
        for b, s in enumerate(scenes)
    ]


def _load(path: Path, context: list[int] | None, resolution: int) -> Scene:
    raw = read_scene(path)
    ctx = default_context_views(raw.num_frames) if context is None else list(context)
    bad = [i for i in ctx if not 0 <= i < raw.num_frames]
    if not ctx or bad:
        raise ValueError(f"--context: {path} has frames 0..{raw.num_frames - 1}, got {ctx}")
    scene = raw.select(ctx, resolution)
    if scene.depth is not None and not bool((scene.depth > 0).any()):
        scene.depth = None
    return scene


def encode_folder(
    model: ParticleSplat,
    data: str | PathLike,
    out: str | PathLike,
    *,
    context: list[int] | None = None,
    batch: int = 1,
    object_centre: str = "resting",
    meta: dict | None = None,
    progress: bool = True,
) -> dict:
    """Encode every scene under ``data`` into ``out`` (see the module docstring).

    Returns {"written": n, "skipped": n, "seconds": wall time of the written scenes, "scenes_per_s": ...}.
    """
    if batch < 1:
        raise ValueError(f"--batch must be >= 1, got {batch}")
    root, out = Path(data), Path(out)
    scenes = find_scenes(root)
    todo = [(s, output_path(root, s, out)) for s in scenes]
    todo = [(s, p) for s, p in todo if not p.is_file()]
    res = model.config.resolution
    t0 = time.perf_counter()
    bar = tqdm(total=len(scenes), initial=len(scenes) - len(todo), desc="encode", unit="scene", disable=not progress)
    try:
        pending: list[tuple[Path, Path, Scene]] = []

        def flush() -> None:
            particles = encode_batch(model, [sc for _, _, sc in pending])
            for (path, target, sc), p in zip(pending, particles, strict=False):
                info = {"scene": str(path), "context": [int(i) for i in sc.frame_indices]}
                info.update(meta or {})
                particle_arrays(model, p, object_centre=object_centre, meta=info).save(target)
                bar.update(1)
            pending.clear()

        for path, target in todo:
            sc = _load(path, context, res)
            if pending and (sc.num_views, sc.depth is None) != (pending[0][2].num_views, pending[0][2].depth is None):
                flush()
            pending.append((path, target, sc))
            if len(pending) >= batch:
                flush()
        if pending:
            flush()
    finally:
        bar.close()
    seconds = time.perf_counter() - t0
    return {
        "written": len(todo),
        "skipped": len(scenes) - len(todo),
        "seconds": seconds,
        "scenes_per_s": len(todo) / seconds if todo and seconds > 0 else float("nan"),
    }


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--data", required=True, help="a scene folder, or a folder with scene folders below it")
    parser.add_argument("--out", required=True, help="output folder: OUT/<scene>.npz per scene")
    parser.add_argument("--checkpoint", help="model checkpoint; none = the shipped assets/model.pt")
    parser.add_argument(
        "--context", help="context frame indices, e.g. 4,16; none = two frames 12 apart about the middle"
    )
    parser.add_argument("--device", choices=("cpu", "cuda"), default=None, help="none = cuda when present, else cpu")
    parser.add_argument(
        "--batch",
        type=int,
        default=None,
        help="scenes per forward pass; none = 1 on cpu (larger batches measured slower per scene "
        "on CPU: docs/particles-as-data.md), 8 on cuda",
    )
    parser.add_argument(
        "--object-centre",
        choices=OBJECT_CENTRES,
        default="resting",
        help="object_centroid: 'resting' (the centre of an object standing on the floor) or "
        "'weighted' (the opacity-weighted mean of its Gaussians)",
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    from particlesplat.editing.open_scene import parse_context
    from particlesplat.model import load_model
    from particlesplat.model.io import shipped_model_path

    device = args.device or ("cuda" if torch.cuda.is_available() else "cpu")
    if device == "cuda" and not torch.cuda.is_available():
        raise ValueError("--device cuda: no CUDA device is available")
    checkpoint = Path(args.checkpoint) if args.checkpoint else shipped_model_path()
    model = load_model(checkpoint, device=device)
    meta = {"model": str(args.checkpoint or "assets/model.pt"), "checkpoint_sha256": file_sha256(checkpoint)}
    batch = args.batch if args.batch is not None else (8 if device == "cuda" else 1)
    stats = encode_folder(
        model,
        args.data,
        args.out,
        context=parse_context(args.context),
        batch=batch,
        object_centre=args.object_centre,
        meta=meta,
        progress=not args.no_progress,
    )
    rate = f", {stats['scenes_per_s']:.2f} scenes/s" if stats["written"] else ""
    print(f"wrote {stats['written']} .npz files to {args.out} ({stats['skipped']} existed){rate} on {device}")
    return 0
