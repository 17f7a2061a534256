"""``particlesplat bench edits``: edit fidelity against ground truth (the uORF scene-manipulation protocol).

For each held-out tabletop scene the generator draws ground-truth pairs from one scene: one object
translated on the floor by 0.2-0.45 m, the same object removed, a copy of it placed elsewhere on the
floor, and (where it stays clear of the others) the object at 1.5 times its size, resting on the floor.
With ``--data`` the ground truth is instead read from disk, where a generator wrote it beside each test scene
(``edits.json`` and ``edits/{move,lift,remove}/``: the robot family's test split, one object moved by
0.10-0.20 m on the table, the same object lifted 0.15 m straight up (less, down to 0.10 m, where it would touch
the arm or another object; scenes written before the lift, or with no room for it, have none) and removed,
simulated and rendered from the scene's cameras).

The original's context views are encoded; the edit is applied as the viewer applies it (pick the object by
the most interior pixel of its ground-truth mask in the context frame where it is largest, take its object
group, translate by the true displacement in world metres; lift by the true height along world z, as the
viewer's Ctrl + drag does; remove; duplicate by the true offset; scale 1.5 times about its resting centre); every
other input view is rendered and compared with the simulator's image of the edited scene. PSNR is taken over

- ``changed``: the object's old and new ground-truth masks, dilated by ``--dilate`` pixels;
- ``vacated``: where the object was and no longer is (old mask dilated, minus the new mask);
- ``view``: the whole image;

for the edit, a no-op edit (the original's encoding, unedited) and the ceiling (the model's own encoding of
the edited scene's context views). Squared errors are pooled over a scene's rendered views, PSNR per scene,
then averaged over the scenes.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import sys
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch
import torch.nn.functional as F

from particlesplat.analysis.metrics import psnr_of_mse
from particlesplat.core.atomic import atomic_write
from particlesplat.core.errors import OptionError, short_repr
from particlesplat.core.options import HelpFormatter
from particlesplat.core.vectors import float3
from particlesplat.data.families import checkpoint_help, tabletop
from particlesplat.data.scene import Scene, SceneFormatError, read_scene
from particlesplat.data.scene_meta import default_checkpoint, read_scene_json
from particlesplat.data.synth import scene_rng, write_tabletop
from particlesplat.editing.editor import Pick, PickError, SceneEditor
from particlesplat.editing.move import MoveError
from particlesplat.editing.open_scene import encode_scene
from particlesplat.editing.source_options import parse_context
from particlesplat.rendering.api import render

if TYPE_CHECKING:
    from particlesplat.core.camera import Camera
    from particlesplat.model.particles import Particles
    from particlesplat.model.particlesplat import ParticleSplat

KINDS = ("move", "lift", "remove", "duplicate", "scale")
SCALE = 1.5  # the scale edit: the object at 1.5 times its size, resting on the floor
REGIONS = ("changed", "vacated", "view")
VARIANTS = ("edit", "noop", "ceiling")
MOVE_RANGE = (0.2, 0.45)  # metres on the floor
MAX_DILATE = 64  # pixels --dilate may grow a mask by (the model's images are at most 1024 pixels a side)
MIN_PICK_PIXELS = 20  # the object must cover this many pixels of a context frame (stored size) to be picked
MAX_LIFT = 1.0  # metres: the largest lift_height an edits.json may give


def _fits(obj: tabletop.TabletopObject, others: list[tabletop.TabletopObject]) -> bool:
    """On the floor (inside the checkerboard, within the generator's placement disc plus a margin) and clear
    of every other object's footprint."""
    x, y, _ = obj.center
    r = obj.footprint_radius
    if max(abs(x), abs(y)) + r > tabletop.FLOOR_HALF - 0.3 or math.hypot(x, y) > tabletop.CENTRE_RADIUS + 0.3:
        return False
    return all(math.hypot(x - o.center[0], y - o.center[1]) >= r + o.footprint_radius + 0.02 for o in others)


def _moved(obj: tabletop.TabletopObject, dx: float, dy: float) -> tabletop.TabletopObject:
    return replace(obj, center=(obj.center[0] + dx, obj.center[1] + dy, obj.center[2]))


def _scaled(obj: tabletop.TabletopObject, factor: float) -> tabletop.TabletopObject:
    """``obj`` ``factor`` times its size, still resting on the floor (its centre's height is its half height)."""
    x, y, z = obj.center
    return replace(obj, center=(x, y, z * factor), size=float3(s * factor for s in obj.size))


def edit_pairs(seed: int, split: str, index: int, res: int, context: list[int]) -> dict | None:
    """The ground-truth scenes of one held-out scene: original, moved, removed, duplicated and (where it stays
    clear of the others) scaled :data:`SCALE` times, with the edited object, the move and copy offsets (metres),
    and the pick (a context-frame pixel deep inside the object's ground-truth mask). None if no object can be
    moved and copied cleanly."""
    scene = tabletop.sample_scene(scene_rng(seed, split, index))
    rng = np.random.default_rng(np.random.SeedSequence([seed, 7, index]))
    from particlesplat.data.synth import scene_cameras

    cams = scene_cameras(scene, res)
    for k in rng.permutation(len(scene.objects)):
        k = int(k)
        obj, others = scene.objects[k], scene.objects[:k] + scene.objects[k + 1 :]
        pick = None
        best = 0
        for f in context:
            _, _, inst = tabletop.render_view(scene, cams[f].K.numpy(), cams[f].c2w.numpy(), res, res)
            mask = torch.from_numpy(inst == k + 1)
            if int(mask.sum()) >= max(MIN_PICK_PIXELS, best + 1):
                best, pick = int(mask.sum()), Pick(f, _interior_pixel(mask))
        if pick is None:
            continue
        move = dup = None
        for _ in range(200):
            if move is None:
                dist, ang = rng.uniform(*MOVE_RANGE), rng.uniform(-math.pi, math.pi)
                cand = (dist * math.cos(ang), dist * math.sin(ang))
                if _fits(_moved(obj, *cand), others):
                    move = cand
            if dup is None:
                dist, ang = rng.uniform(0.3, 1.2), rng.uniform(-math.pi, math.pi)
                cand = (dist * math.cos(ang), dist * math.sin(ang))
                if _fits(_moved(obj, *cand), scene.objects):
                    dup = cand
            if move is not None and dup is not None:
                break
        if move is None or dup is None:
            continue
        pairs = {
            "original": scene,
            "object": k,
            "pick": pick,
            "offsets": {"move": move, "duplicate": dup},
            "move": replace(scene, objects=others[:k] + [_moved(obj, *move)] + others[k:]),
            "remove": replace(scene, objects=list(others)),
            "duplicate": replace(scene, objects=scene.objects + [_moved(obj, *dup)]),
        }
        grown = _scaled(obj, SCALE)  # no draw from the generator: the other edits keep their scenes
        if _fits(grown, others):
            pairs["scale"] = replace(scene, objects=others[:k] + [grown] + others[k:])
        return pairs
    return None


def _interior_pixel(mask: torch.Tensor) -> tuple[int, int]:
    """(x, y) of the pixel of ``mask`` (H, W) bool farthest inside it (ties: nearest the mask's centroid)."""
    depth = torch.zeros(mask.shape)
    cur = mask.float()[None, None]
    while bool(cur.any()):
        depth += cur[0, 0]
        cur = -F.max_pool2d(-cur, 3, stride=1, padding=1)
    ys, xs = torch.nonzero(depth == depth.max(), as_tuple=True)
    cy, cx = mask.nonzero().float().mean(0)
    i = int(((ys.float() - cy) ** 2 + (xs.float() - cx) ** 2).argmin())
    return int(xs[i]), int(ys[i])


def _dilate(mask: torch.Tensor, px: int) -> torch.Tensor:
    """(V, H, W) bool grown by ``px`` pixels (square)."""
    if px <= 0:
        return mask
    return F.max_pool2d(mask.float()[:, None], 2 * px + 1, stride=1, padding=px)[:, 0] > 0


def _renders(
    model: ParticleSplat, particles: Particles, cameras: list[Camera], z_t_threshold: float | None = None
) -> torch.Tensor:
    """(V, 3, H, W) renders of the particles (edits applied) in ``cameras``."""
    g = model.decode(particles, z_t_threshold=z_t_threshold).detach().to("cpu")
    with torch.no_grad():
        backs = [model.backdrop_image(particles, c).detach().cpu() for c in cameras]
        renders = [render(g, c, background=b).rgb for c, b in zip(cameras, backs, strict=True)]
    return torch.stack(renders).permute(0, 3, 1, 2)


def _sq_err(pred: torch.Tensor, gt: torch.Tensor, region: torch.Tensor) -> tuple[float, int]:
    """(sum of squared error over ``region`` pixels (V, H, W) and the 3 channels, number of values)."""
    err = ((pred.clamp(0, 1) - gt) ** 2).sum(1)
    return float(err[region].sum()), int(region.sum()) * 3


@dataclass(frozen=True)
class GroundTruth:
    """One scene's ground-truth edits as scene folders: ``folders`` maps "original" and each edit kind the scene
    has (:data:`KINDS`) to its folder; ``object`` is the edited object's instance id (1..K, its value in the masks),
    ``copy`` the copy's id in the duplicate scene (0 without one), ``pick`` selects the object in a context
    frame, ``offsets`` {kind: (dx, dy) world metres on the support}, ``lift`` the metres the lift raises the
    object by along world z (0 without a lift)."""

    label: str
    folders: dict[str, Path]
    object: int
    pick: Pick
    offsets: dict[str, tuple[float, float]]
    copy: int = 0
    lift: float = 0.0

    @property
    def kinds(self) -> tuple[str, ...]:
        return tuple(k for k in KINDS if k in self.folders)


def bench_scene(
    model: ParticleSplat,
    seed: int,
    split: str,
    index: int,
    res: int,
    context: list[int],
    dilate: int,
    work: Path,
    z_t_threshold: float | None = None,
) -> dict | None:
    """Edit-fidelity PSNR of one held-out tabletop scene of the generator: {kind: {variant: {region: dB}}}, plus
    the pick's outcome; None if no object of the scene can be edited cleanly."""
    pairs = edit_pairs(seed, split, index, res, context)
    if pairs is None:
        return None
    folders = {}
    for name in ("original", *(k for k in KINDS if k in pairs)):
        folders[name] = work / f"{index:05d}_{name}"
        if not folders[name].is_dir():
            write_tabletop(
                folders[name], pairs[name], res, {"seed": seed, "split": split, "index": index, "edit": name}
            )
    truth = GroundTruth(
        f"{split}/{index:05d}",
        folders,
        pairs["object"] + 1,
        pairs["pick"],
        pairs["offsets"],
        copy=len(pairs["duplicate"].objects),
    )
    return score_scene(model, truth, context, dilate, z_t_threshold)


def read_edits(scene_dir: Path, context: list[int]) -> GroundTruth | None:
    """The ground-truth edits written beside a scene folder (``edits.json``: ``object`` instance id, ``offset``
    (dx, dy, dz) metres, ``move`` and ``remove`` scene folders relative to the scene's, and where the scene has
    a lift its ``lift`` folder and ``lift_height`` metres; the robot family's test scenes). A ``lift`` that is
    absent (scenes written before it) or null (no room for it) means no lift. None if the scene has no edit
    (``object`` null) or the object covers fewer than :data:`MIN_PICK_PIXELS` pixels of every context frame."""
    where = scene_dir / "edits.json"
    info = read_scene_json(where)
    if not isinstance(info, dict) or "object" not in info:
        raise SceneFormatError(f"{where}: must be an object with key 'object' (an instance id, or null)")
    if info["object"] is None:
        return None
    k = info["object"]
    if not isinstance(k, int) or isinstance(k, bool) or not 1 <= k <= 255:
        raise SceneFormatError(f"{where}: key 'object' must be an instance id 1..255, got {short_repr(k)}")
    offset = info.get("offset")
    if (
        not isinstance(offset, list)
        or len(offset) != 3
        or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in offset)
    ):
        raise SceneFormatError(f"{where}: key 'offset' must be 3 finite numbers (metres), got {short_repr(offset)}")
    folders = {"original": scene_dir}
    lift = 0.0
    if info.get("lift") is not None:
        height = info.get("lift_height")
        if not isinstance(height, (int, float)) or isinstance(height, bool) or not 0.0 < height <= MAX_LIFT:
            raise SceneFormatError(
                f"{where}: key 'lift_height' must be metres in (0, {MAX_LIFT}] beside a 'lift' folder, "
                f"got {short_repr(height)}"
            )
        lift = float(height)
    for kind in ("move", "lift", "remove") if lift else ("move", "remove"):
        rel = info.get(kind)
        norm = os.path.normpath(rel) if isinstance(rel, str) and rel else ""
        if not norm or os.path.isabs(norm) or norm == ".." or norm.startswith(".." + os.sep):
            raise SceneFormatError(
                f"{where}: key '{kind}' must name a scene folder inside {scene_dir}, got {short_repr(rel)}"
            )
        folders[kind] = scene_dir / norm
    raw = read_scene(scene_dir)
    bad = [f for f in context if not 0 <= f < raw.num_frames]
    if bad:
        raise OptionError(f"--context: {scene_dir} has frames 0..{raw.num_frames - 1}, got {context}")
    pick, best = None, 0
    for f in context:
        if raw.masks[f] is None:
            raise SceneFormatError(f"{scene_dir}: frame {f} has no instance mask to pick the edited object by")
        mask = torch.from_numpy(raw.masks[f] == k)
        if int(mask.sum()) >= max(MIN_PICK_PIXELS, best + 1):
            best, pick = int(mask.sum()), Pick(f, _interior_pixel(mask))
    if pick is None:
        return None
    return GroundTruth(
        f"{scene_dir.parent.name}/{scene_dir.name}",
        folders,
        k,
        pick,
        {"move": (float(offset[0]), float(offset[1]))},
        lift=lift,
    )


def _scored_masks(scene: Scene, folder: Path) -> torch.Tensor:
    """(V, H, W) instance masks of the scored views of ``scene`` (read from ``folder``)."""
    if scene.masks is None:
        raise SceneFormatError(f"{folder}: every view needs an instance mask (masks/) to score an edit by")
    return scene.masks


def score_scene(
    model: ParticleSplat, truth: GroundTruth, context: list[int], dilate: int, z_t_threshold: float | None = None
) -> dict:
    """Edit-fidelity PSNR of one scene against its ground-truth folders: {kind: {variant: {region: dB}}} for the
    scene's edit kinds, plus the pick's outcome."""
    enc = encode_scene(model, truth.folders["original"], context)
    others = [i for i in range(len(enc.all_cameras)) if i not in context]
    size = model.config.resolution
    noop = None
    out: dict = {
        "scene": truth.label,
        "object": truth.object - 1,
        "pick": list(truth.pick.pixel),
        "pick_frame": truth.pick.frame,
        "offsets": truth.offsets,
    }
    if truth.lift:
        out["lift_height"] = truth.lift
    k = truth.object
    orig_raw = read_scene(truth.folders["original"]).select(others, size)
    orig_masks = _scored_masks(orig_raw, truth.folders["original"])
    for kind in truth.kinds:
        gt_scene = read_scene(truth.folders[kind]).select(others, size)
        cams = gt_scene.cameras
        gt = gt_scene.rgb
        gt_masks = _scored_masks(gt_scene, truth.folders[kind])
        old = orig_masks == k
        new = gt_masks == {"move": k, "lift": k, "remove": -1, "duplicate": truth.copy, "scale": k}[kind]
        if kind == "duplicate":
            old = torch.zeros_like(old)  # the original stays: only the copy's place changes
        regions = {
            "changed": _dilate(old | new, dilate),
            "vacated": _dilate(old, dilate) & ~new,
            "view": torch.ones_like(old),
        }
        editor = SceneEditor(model, enc.particles, enc.all_cameras, context, z_t_threshold, enc.support)
        status = "ok"
        try:
            label = editor.pick(truth.pick)
            dx, dy = truth.offsets.get(kind, (0.0, 0.0))
            if kind == "move":
                editor.move_object(label, [dx, dy, 0.0])
            elif kind == "lift":  # the viewer's Ctrl + drag: along world z
                editor.move_object(label, [0.0, 0.0, truth.lift])
            elif kind == "remove":
                editor.remove_object(label)
            elif kind == "scale":
                editor.scale_object(label, SCALE)
            else:
                editor.duplicate_object(label, [dx, dy, 0.0])
        except (PickError, MoveError) as e:
            status = f"failed: {e}"
        if noop is None:
            noop = _renders(model, enc.particles, cams, z_t_threshold)
        if editor.particles is None:  # an editor made from particles keeps (edited) particles
            raise RuntimeError(f"{truth.label}: the editor has no particles to render")
        preds = {
            "edit": _renders(model, editor.particles, cams, z_t_threshold),
            "noop": noop,
            "ceiling": _renders(
                model, encode_scene(model, truth.folders[kind], context).particles, cams, z_t_threshold
            ),
        }
        row: dict[str, Any] = {"status": status, "pixels": {r: int(m.sum()) for r, m in regions.items()}}
        for variant, pred in preds.items():
            row[variant] = {}
            for region, m in regions.items():
                s, n = _sq_err(pred, gt, m)
                row[variant][region] = {"sse": s, "n": n, "psnr": psnr_of_mse(s / n) if n else float("nan")}
        out[kind] = row
    return out


def summarise(rows: list[dict]) -> dict:
    """Mean over the scenes that have each edit of the per-scene PSNR: {kind: {variant: {region: dB}}, "scenes":
    how many}; vacated is not defined for duplicate (nothing leaves) nor for a grown object."""
    table: dict = {}
    for kind in (k for k in KINDS if any(k in r for r in rows)):
        have = [r for r in rows if kind in r]
        table[kind] = {"scenes": len(have)}
        for variant in VARIANTS:
            table[kind][variant] = {}
            for region in REGIONS:
                vals = [r[kind][variant][region]["psnr"] for r in have if r[kind]["pixels"][region] > 0]
                table[kind][variant][region] = float(np.mean(vals)) if vals else float("nan")
        table[kind]["failed"] = sum(r[kind]["status"] != "ok" for r in have)
    return table


def format_table(table: dict, n: int) -> str:
    lines = [
        f"edit fidelity on {n} scenes the model never trained on (PSNR dB, mean over scenes; ceiling = the model's "
        "own encoding of the edited scene)",
        f"{'edit':<10} {'region':<8} {'edit':>6} {'no-op':>6} {'ceiling':>7} {'gap':>6}",
    ]
    for kind in (k for k in KINDS if k in table):
        for region in REGIONS:
            if kind in ("duplicate", "scale") and region == "vacated":
                continue
            e, o, c = (table[kind][v][region] for v in VARIANTS)
            lines.append(f"{kind:<10} {region:<8} {e:6.2f} {o:6.2f} {c:7.2f} {c - e:6.2f}")
        if table[kind]["scenes"] < n:
            why = "no room for it, or written before the lift" if kind == "lift" else "no room for it"
            lines.append(f"{kind:<10} on {table[kind]['scenes']} of the {n} scenes (the others: {why})")
        if table[kind]["failed"]:
            lines.append(f"{kind:<10} {table[kind]['failed']} edit(s) failed (pick or move refused; scored unedited)")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="particlesplat bench edits",
        description=__doc__.split("\n\n")[0],
        formatter_class=HelpFormatter,
    )
    parser.add_argument(
        "--checkpoint",
        default=None,
        help=checkpoint_help(),
    )
    parser.add_argument(
        "--data",
        default=None,
        help="score the ground-truth edits written beside the scenes of this folder (edits.json, edits/: the robot "
        "family's test split, e.g. DATA/test) instead of the tabletop generator's; --seed, --split, --res and "
        "--work are then unused",
    )
    parser.add_argument("--scenes", type=int, default=12, help="number of scenes (none the model trained on)")
    parser.add_argument(
        "--start", type=int, default=0, help="first scene: index of the split (with --data: of its scene folders)"
    )
    parser.add_argument("--seed", type=int, default=0, help="dataset seed (0 = the shipped model's dataset)")
    parser.add_argument("--split", default="test", choices=("val", "test"), help="held-out split of the generator")
    parser.add_argument("--res", type=int, default=128, help="stored image size of the generated scenes")
    parser.add_argument("--context", default="4,16", help="context frames")
    parser.add_argument(
        "--dilate", type=int, default=1, help="pixels (at the model's resolution) the object masks are grown by"
    )
    parser.add_argument("--work", default=None, help="folder for the generated scenes (default: a temporary one)")
    parser.add_argument(
        "--z-t-threshold",
        type=float,
        default=None,
        help="the particles that draw (default: the model's, as the viewer; 0 = every particle, "
        "the faint inactive ones too, as before they were dropped)",
    )
    parser.add_argument("--json", default=None, help="also write per-scene and mean results to this JSON file")
    args = parser.parse_args(argv)
    from particlesplat.core.atomic import check_writable
    from particlesplat.core.outputs import guard_outputs
    from particlesplat.model import load_model

    if args.scenes < 1:
        parser.error(f"--scenes must be >= 1, got {args.scenes}")
    from particlesplat.core.limits import check_option_range

    check_option_range(args.z_t_threshold, "--z-t-threshold", 0.0, 1.0)
    if args.start < 0:
        raise OptionError(f"--start must be >= 0 (the first scene's index), got {args.start}")
    if not 0 <= args.dilate <= MAX_DILATE:
        raise OptionError(f"--dilate must be in [0, {MAX_DILATE}] pixels, got {args.dilate}")
    context = parse_context(args.context)
    if context is None:  # an empty --context: parse_context's "use the default" has no meaning here
        raise OptionError(f"--context: expected comma-separated frame indices, got {args.context!r}")
    scene_dirs: list[Path] = []
    if args.data is not None:
        data = Path(args.data)
        if not data.is_dir():
            raise OptionError(f"--data {data}: not a folder")
        scene_dirs = sorted(p for p in data.iterdir() if (p / "edits.json").is_file())
        if not scene_dirs:
            raise OptionError(
                f"--data {data}: no scene folder in it has ground-truth edits (edits.json; the robot family writes "
                "them for its test split)"
            )
        if args.start >= len(scene_dirs):
            raise OptionError(
                f"--start {args.start}: --data {data} has {len(scene_dirs)} scene folders with edits "
                f"(0..{len(scene_dirs) - 1})"
            )
    checkpoint = Path(args.checkpoint) if args.checkpoint else default_checkpoint(args.data)
    guard_outputs([("--json", args.json), ("--work", args.work)], [("--checkpoint", checkpoint), ("--data", args.data)])
    if args.json:
        check_writable(args.json)  # before half an hour of work, not after it

    torch.set_num_threads(min(2, torch.get_num_threads()))
    model = load_model(checkpoint)
    rows: list[dict] = []
    skipped: list[str] = []
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(args.work) if args.work else Path(tmp)
        index = args.start
        while len(rows) < args.scenes and (args.data is None or index < len(scene_dirs)):
            if args.data is None:
                name = f"{args.split}/{index:05d}"
                row = bench_scene(
                    model, args.seed, args.split, index, args.res, context, args.dilate, work, args.z_t_threshold
                )
            else:
                name = str(scene_dirs[index])
                truth = read_edits(scene_dirs[index], context)
                row = None if truth is None else score_scene(model, truth, context, args.dilate, args.z_t_threshold)
            if row is None:
                skipped.append(name)
            else:
                rows.append(row)
                for kind in (k for k in ("move", "lift") if k in row):
                    print(
                        f"{name}: {kind} {row[kind]['edit']['changed']['psnr']:.2f} / ceiling "
                        f"{row[kind]['ceiling']['changed']['psnr']:.2f} dB (changed), {row[kind]['status']}",
                        file=sys.stderr,
                    )
            index += 1
    if not rows:
        raise OptionError(
            f"--data {args.data}: none of its scenes from --start {args.start} has an edit whose object shows in "
            f"the context frames {context}"
        )
    table = summarise(rows)
    print(format_table(table, len(rows)))
    source = {"data": str(args.data)} if args.data else {"seed": args.seed, "split": args.split, "res": args.res}
    out = {
        "checkpoint": str(checkpoint),  # the model that ran (the family's shipped one without --checkpoint)
        "z_t_threshold": args.z_t_threshold,
        **source,
        "context": context,
        "dilate": args.dilate,
        "skipped": skipped,
        "seconds": time.perf_counter() - t0,
        "machine": platform.machine(),
        "mean": table,
        "scenes": rows,
    }
    if args.json:
        with atomic_write(args.json, "w") as f:
            json.dump(out, f, indent=1)
        print(f"wrote {args.json}")
    return 0
