"""Encode every scene folder under a folder into ``.npz`` particle arrays (the work of ``particlesplat encode``).

``OUT/<scene>.npz`` holds the arrays of :mod:`particlesplat.analysis.particle_arrays` (scene folders nested under
``--data``, e.g. ``train/scene_00000``, keep their relative path). Scenes are encoded ``--batch`` at a time
in one forward pass; each file is written under a temporary name and renamed when complete. A scene whose
``.npz`` exists is skipped only when that file proves it is what this run would write: it opens, and its
``meta`` records the same checkpoint (SHA-256), the same ``--context`` request, object centre and format
version; otherwise it is encoded again (``--force``: every scene). Temporary files of an earlier run that was
killed are removed at the start, so an interrupted run resumes cleanly.
"""

from __future__ import annotations

import os
import time
from os import PathLike
from pathlib import Path

import torch
from tqdm import tqdm

from particlesplat.analysis.particle_arrays import (
    FORMAT_VERSION,
    particle_arrays,
    read_npz_meta,
)
from particlesplat.core.atomic import stale_temporaries
from particlesplat.core.choices import ObjectCentre
from particlesplat.core.errors import OptionError, UserError, one_line, short_repr, warn_input
from particlesplat.core.viewpoints import default_context_views
from particlesplat.data import Scene, read_scene
from particlesplat.data.folders import TRANSFORMS
from particlesplat.data.scene_meta import scene_pose
from particlesplat.model import Particles, ParticleSplat
from particlesplat.model.geometry import stack_cameras


def find_scenes(root: str | PathLike) -> list[Path]:
    """``root`` itself when it is a scene folder (holds ``transforms.json``), else every scene folder below it
    (sorted; hidden folders, e.g. a generator's unfinished temporaries, are skipped). A scene's own subfolders
    (a robot test scene's ``edits/``) are not searched; a symbolic link out of ``root`` counts when it names a scene
    folder and is not walked otherwise (a link to ``/`` would walk the machine)."""
    root = Path(root)
    if not root.is_dir():
        raise FileNotFoundError(f"{root}: no such folder")
    if (root / TRANSFORMS).is_file():
        return [root]
    found: list[Path] = []
    seen: dict[str, str] = {}
    top = os.path.realpath(root)
    for folder, subdirs, files in os.walk(root, followlinks=True):  # symlinked scene folders count
        real = os.path.realpath(folder)
        outside = real != top and not real.startswith(top.rstrip(os.sep) + os.sep)
        if outside and TRANSFORMS not in files:  # a link out of --data is a scene, or it is not walked (a link to /)
            warn_input(f"{folder}: a symbolic link to {real[:120]}, outside {root} and not a scene folder; left out")
            subdirs[:] = []
            continue
        if real in seen:  # a symlink to a folder already found (or a cycle): encoded once, under its first path
            if TRANSFORMS in files:
                warn_input(f"{folder}: the same scene folder as {seen[real]} (a symbolic link); encoded once, as that")
            subdirs[:] = []
            continue
        seen[real] = folder
        subdirs[:] = sorted(d for d in subdirs if not d.startswith("."))
        if TRANSFORMS in files:
            found.append(Path(folder))
            subdirs[:] = []  # a scene's own folders (a robot test scene's edits/) are not scenes of --data
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
    depths = [s.depth for s in scenes if s.depth is not None]
    depth = torch.stack(depths).to(dev) if len(depths) == len(scenes) else None
    cams = [stack_cameras(s.cameras, device=dev) for s in scenes]
    K = torch.stack([k for k, _ in cams])
    c2w = torch.stack([c for _, c in cams])
    cfg = model.config
    poses = [scene_pose(s.path, cfg.bg_static_pose, cfg.bg_static_pose_dims, model.input_ranges) for s in scenes]
    pose = model.batch_pose(poses, dev)
    post = model.encode_posterior(rgb, depth, K, c2w, pose)
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
            pose=None if pose is None else pose[b],
            cameras=[c.to(dev) for c in s.cameras],
            backdrop=model.views_backdrop(rgb[b], None if depth is None else depth[b], K[b], c2w[b]),
            support_map=model.views_support_map(
                rgb[b],
                None if depth is None else depth[b],
                K[b],
                c2w[b],
                None if pose is None else pose[b],
                model.views_evidence(post, b),
            ),
        )
        for b, s in enumerate(scenes)
    ]


def stale_output(path: Path, request: dict, object_centre: str) -> str | None:
    """Why the existing ``path`` is not what this run would write (None when it is): it does not open (truncated,
    not an .npz), or its ``meta`` records another format version, object centre or value of a ``request`` key
    (checkpoint SHA-256, --context request)."""
    try:
        meta = read_npz_meta(path)  # headers and meta only: a lying header allocates nothing
    except (UserError, OSError) as e:
        return one_line(e, 160)
    want = {"format_version": FORMAT_VERSION, "object_centre": object_centre}
    want.update({k: v for k, v in request.items() if k != "model"})  # the same weights may have another path
    if request.get("context_request") is not None:
        want["context"] = request["context_request"]
    for key, value in want.items():
        if key not in meta or meta[key] != value:
            return f"meta.{key} is {short_repr(meta.get(key, 'absent'), 40)}, this run {short_repr(value, 40)}"
    return None


def check_context_memory(model: ParticleSplat, views: int, batch: int, option: str) -> None:
    """BudgetError naming ``option`` when encoding ``batch`` scenes of ``views`` context views would not fit the
    memory limit (:func:`particlesplat.model.io.encode_memory`)."""
    from particlesplat.core.limits import check_memory
    from particlesplat.model.io import encode_memory

    check_memory(
        batch * encode_memory(model.config, views),
        f"{option}: encoding {batch} scene(s) of {views} context view(s) (the model: particles_per_view "
        f"{model.config.particles_per_view}, {model.config.resolution}^2 pixels)",
    )


def _load(path: Path, context: list[int] | None, resolution: int) -> Scene:
    raw = read_scene(path)
    ctx = default_context_views(raw.num_frames) if context is None else list(context)
    bad = [i for i in ctx if not 0 <= i < raw.num_frames]
    if not ctx or bad:
        raise OptionError(f"--context: {path} has frames 0..{raw.num_frames - 1}, got {ctx}")
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
    object_centre: ObjectCentre = "resting",
    meta: dict | None = None,
    progress: bool = True,
    force: bool = False,
) -> dict:
    """Encode every scene under ``data`` into ``out`` (see the module docstring).

    ``meta`` (e.g. the checkpoint's SHA-256) is recorded in every file and, with ``context`` and
    ``object_centre``, compared with an existing file's (:func:`stale_output`); ``force`` encodes every scene.

    Returns {"written": n, "replaced": n of them over a stale file, "skipped": n, "seconds": wall time of the
    written scenes, "scenes_per_s": ...}.
    """
    if batch < 1:
        raise OptionError(f"--batch must be >= 1, got {batch}")
    root, out = Path(data), Path(out)
    scenes = find_scenes(root)
    for tmp in stale_temporaries(out, recursive=True):  # a killed run's half-written files
        tmp.unlink(missing_ok=True)
    request = {"context_request": None if context is None else [int(i) for i in context], **(meta or {})}
    check_context_memory(model, len(context) if context is not None else 2, batch, "--context")
    targets = [(s, output_path(root, s, out)) for s in scenes]
    todo = [(s, p) for s, p in targets if force or not p.is_file() or stale_output(p, request, object_centre)]
    redone = sum(p.is_file() for _, p in todo)
    res = model.config.resolution
    t0 = time.perf_counter()
    bar = tqdm(total=len(scenes), initial=len(scenes) - len(todo), desc="encode", unit="scene", disable=not progress)
    try:
        pending: list[tuple[Path, Path, Scene]] = []

        def flush() -> None:
            particles = encode_batch(model, [sc for _, _, sc in pending])
            for (path, target, sc), p in zip(pending, particles, strict=False):
                info = {"scene": str(path), "context": [int(i) for i in sc.frame_indices]}
                info.update(request)
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
        "replaced": redone,
        "skipped": len(scenes) - len(todo),
        "seconds": seconds,
        "scenes_per_s": len(todo) / seconds if todo and seconds > 0 else float("nan"),
    }
