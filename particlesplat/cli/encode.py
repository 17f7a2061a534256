"""``particlesplat encode``: write the particles of every scene folder under a folder as ``.npz`` arrays (the
work, resuming and what makes a file stale: :mod:`particlesplat.analysis.encode_folder`). Torch loads after the
arguments and paths were checked."""

from __future__ import annotations

import argparse
from pathlib import Path

from particlesplat.core.choices import OBJECT_CENTRES
from particlesplat.core.device import DEVICE_HELP
from particlesplat.core.errors import OptionError
from particlesplat.data.families import checkpoint_help
from particlesplat.data.folders import check_existing, check_file
from particlesplat.rendering.choice import add_rasterizer_option, apply_rasterizer_option


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--data",
        help="a scene folder, or a folder with scene folders below it (with --edits: the one scene, by default the "
        "edit file's)",
    )
    parser.add_argument("--out", required=True, help="output folder: OUT/<scene>.npz per scene")
    parser.add_argument(
        "--edits",
        metavar="E.yaml",
        help="encode one scene with this edit file replayed: its moves, removals, copies and scales, and its object "
        "groups (merges and splits win over the automatic grouping in 'object' and the object arrays); its "
        "scene and context frames unless --data / --context say otherwise",
    )
    parser.add_argument(
        "--checkpoint",
        help=checkpoint_help(),
    )
    parser.add_argument(
        "--context", help="context frame indices, e.g. 4,16; none = two frames 12 apart about the middle"
    )
    parser.add_argument("--device", default=None, help=DEVICE_HELP)
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
    parser.add_argument(
        "--force",
        action="store_true",
        help="encode every scene again (default: an existing .npz of the same checkpoint, --context, object "
        "centre and format version is kept)",
    )
    add_rasterizer_option(parser)


def run(args: argparse.Namespace) -> int:
    if args.data is None and args.edits is None:
        raise OptionError("--data: a scene folder or a folder of scenes is needed (or --edits E.yaml for one scene)")
    if args.data is not None:
        check_existing(args.data, "--data")  # before torch loads: a typo is one quick line
    check_file(args.checkpoint, "--checkpoint", shipped=True)
    check_file(args.edits, "--edits")
    apply_rasterizer_option(args)
    from particlesplat.core.outputs import guard_outputs

    inputs = [("--data", args.data), ("--checkpoint", args.checkpoint), ("--edits", args.edits)]
    guard_outputs([("--out", args.out)], inputs)
    if args.edits is not None:
        return _encode_edited(args)
    from particlesplat.analysis.encode_folder import encode_folder
    from particlesplat.analysis.particle_arrays import file_sha256
    from particlesplat.core.device import resolve_device
    from particlesplat.data.scene_meta import default_checkpoint
    from particlesplat.editing.source_options import parse_context
    from particlesplat.model import load_model
    from particlesplat.model.io import shipped_model_name

    device = resolve_device(args.device)
    checkpoint = Path(args.checkpoint) if args.checkpoint else default_checkpoint(args.data)
    model = load_model(checkpoint, device=device)
    meta = {"model": shipped_model_name(checkpoint), "checkpoint_sha256": file_sha256(checkpoint)}
    batch = args.batch if args.batch is not None else (8 if device.type == "cuda" else 1)
    from particlesplat.rendering.budget import render_budget

    with render_budget(f"{checkpoint} ({model.config.render_keys()})"):  # the refinement's renders, priced first
        stats = encode_folder(
            model,
            args.data,
            args.out,
            context=parse_context(args.context),
            batch=batch,
            object_centre=args.object_centre,
            meta=meta,
            progress=not args.no_progress,
            force=args.force,
        )
    rate = f", {stats['scenes_per_s']:.2f} scenes/s" if stats["written"] else ""
    again = f", {stats['replaced']} of them over a stale file" if stats["replaced"] else ""
    print(f"wrote {stats['written']} .npz files to {args.out}{again} ({stats['skipped']} existed){rate} on {device}")
    return 0


def _encode_edited(args: argparse.Namespace) -> int:
    """``encode --edits``: one scene's particles after its edit file, grouped as the file groups them."""
    import sys

    from particlesplat.analysis.particle_arrays import file_sha256, particle_arrays
    from particlesplat.editing.edited_scene import open_edited_scene

    scene = open_edited_scene(args.checkpoint, args.data, args.context, edits=args.edits)
    for line in scene.warnings:
        print(f"warning: {line}", file=sys.stderr)
    meta = {"model": scene.model_name, "edits": str(args.edits), "edits_sha256": file_sha256(args.edits)}
    arrays = particle_arrays(
        scene.model, scene.particles, object_centre=args.object_centre, meta=meta, objects=scene.objects
    )
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    target = arrays.save(out / f"{Path(scene.encoded.path).name}.npz")
    print(f"wrote {target}: {arrays.num_objects} objects after {args.edits}")
    return 0
