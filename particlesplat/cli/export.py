"""``particlesplat export``: write a (possibly edited) scene, or convert a Gaussian file, to the formats other
splat tools open; or write it as an object bundle (a ``.ply`` per particle or object, ``rest.ply``, a manifest).

The format comes from ``--out``'s extension (:mod:`particlesplat.formats.splat_files`). The scene is what
``particlesplat render`` draws for the same ``--scene`` / ``--edits`` / ``--edits-from`` / ``--context`` /
``--checkpoint``, decoded with its background, inside a crop box: the one the edits set, else a robot scene's
workspace (its table and arm, :func:`particlesplat.editing.crop_box.workspace_box`), so that another viewer frames
the workspace rather than the walls of its room; ``--no-crop`` writes every Gaussian.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from particlesplat.core.errors import OptionError
from particlesplat.data.folders import check_existing, check_file
from particlesplat.editing.source_options import add_source_arguments, check_source_arguments
from particlesplat.formats.splat_files import SUFFIX_HELP

if TYPE_CHECKING:
    from particlesplat.core.gaussians import Gaussians
    from particlesplat.editing.edited_scene import EditedScene

PRUNE_DEFAULT = 1.0 / 255.0  # below half an 8-bit opacity step every compact format stores 0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_source_arguments(parser, ply_help=f"convert a Gaussian file ({SUFFIX_HELP}) instead of a model scene")
    parser.add_argument(
        "--edits-from",
        metavar="PNG",
        help="replay the edit file a viewer screenshot or a rendered PNG carries (its 'edits' chunk), on the scene "
        "and context frames it names unless --scene / --context say otherwise",
    )
    parser.add_argument(
        "--out",
        required=True,
        help=f"output file, its format from the extension ({SUFFIX_HELP}); with --by: the bundle's folder",
    )
    parser.add_argument(
        "--by",
        choices=("particle", "object"),
        help="write an object bundle to the folder --out: particle_<i>.ply or object_<k>.ply, rest.ply and "
        "manifest.json (centres, extents, presence, objects, members, context cameras)",
    )
    parser.add_argument(
        "--no-crop",
        action="store_true",
        help="write every Gaussian: no crop box (without it, the box the edits set, else a robot scene's workspace "
        "box about its table and arm)",
    )
    parser.add_argument(
        "--prune",
        type=float,
        nargs="?",
        const=PRUNE_DEFAULT,
        default=0.0,
        metavar="OPACITY",
        help="drop Gaussians with opacity below OPACITY first (alone: 1/255, what an 8-bit opacity stores as 0); "
        "none = keep all",
    )


def _guard(args: argparse.Namespace) -> None:
    """The output guard every command calls before its work (:func:`particlesplat.core.outputs.guard_outputs`):
    ``--out`` is none of the inputs (``--ply``, ``--scene``, ``--checkpoint`` or the shipped models it stands for,
    ``--edits``, ``--edits-from``), no existing file inside an input folder, and not in a run folder a live
    ``train`` holds; with ``--by`` it is a folder whose contents are replaced, so it must hold no input."""
    from particlesplat.core.outputs import guard_outputs

    inputs = [(f"--{k.replace('_', '-')}", getattr(args, k)) for k in ("ply", "scene", "checkpoint", "edits")]
    inputs.append(("--edits-from", args.edits_from))
    if not args.ply and not args.checkpoint:  # the scene's family chooses one of the shipped models
        from particlesplat.data.families import families

        inputs += [("the shipped model", str(f.shipped_model_path())) for f in families()]
    guard_outputs([("--out", args.out)], inputs, [("--out", args.out)] if args.by else [])


def _cropped(scene: EditedScene, no_crop: bool) -> tuple[Gaussians, str]:
    """(the scene's Gaussians to write, a line saying what a crop box left out or ""): the box the edits set, else
    the scene's workspace box (:func:`particlesplat.editing.crop_box.workspace_box`: a robot scene's table and
    arm); none with ``no_crop``."""
    from particlesplat.editing.crop_box import workspace_box

    g = scene.model.decode(scene.particles).detach().to("cpu")
    box, whose = scene.crop, "the edits' crop box"
    if box is None:
        box, whose = workspace_box(scene.encoded.path), "the workspace box (the table and the arm)"
    if no_crop or box is None or not box.bounded:
        return g, ""
    kept = box.crop(g)
    return kept, f"cropped to {whose}, {box.text()}: {g.num - kept.num} of {g.num} Gaussians outside left out " + (
        "(--no-crop keeps them)"
    )


def run(args: argparse.Namespace) -> int:
    from particlesplat.core.atomic import check_writable
    from particlesplat.core.errors import EXIT_USER, UserError, one_line

    prog = "particlesplat export"
    scene, cropped = None, ""
    try:
        check_source_arguments(args)
        if args.ply and args.edits_from:
            raise OptionError("--edits-from needs a model scene, not --ply")
        if args.edits and args.edits_from:
            raise OptionError("--edits and --edits-from: give one edit file")
        if args.ply and args.by == "object":
            raise OptionError("--by object needs a model scene (its particles' objects), not --ply: use --by particle")
        if not 0.0 <= args.prune <= 1.0:
            raise OptionError(f"--prune must be an opacity in [0, 1], got {args.prune:g}")
        check_existing(args.scene, "--scene")  # before torch loads: a typo is one quick line
        for name in ("ply", "checkpoint", "edits", "edits_from"):
            check_file(getattr(args, name), f"--{name.replace('_', '-')}", shipped=name == "checkpoint")
        _guard(args)  # before any work, as every command
        from particlesplat.formats.splat_files import SUFFIXES, format_for

        if args.by is None:
            fmt = format_for(args.out)  # before the work, not after it
            try:
                check_writable(args.out)
            except OSError as e:
                raise OSError(f"--out {one_line(e)}") from None
        else:
            from particlesplat.formats.bundle import check_bundle_target

            suffix = next((x for x in sorted(SUFFIXES, key=len, reverse=True) if args.out.lower().endswith(x)), None)
            if suffix is not None:  # x.spz -> x_particles/, next to it
                folder = Path(args.out).with_name(f"{Path(args.out).name[: -len(suffix)]}_{args.by}s")
                raise OptionError(
                    f"--out {args.out}: --by writes a folder of .ply parts and a manifest, not a {suffix} file: "
                    f"give a folder, e.g. --out {folder}/"
                )
            check_bundle_target(args.out)
        if args.ply:
            from particlesplat.editing.open_scene import load_ply_checked

            g = load_ply_checked(args.ply)
            source = str(args.ply)
        else:
            from particlesplat.editing.edited_scene import open_edited_scene

            scene = open_edited_scene(args.checkpoint, args.scene, args.context, args.edits, args.edits_from)
            for warning in scene.warnings:
                print(f"{prog}: warning: {warning}", file=sys.stderr)
            g, cropped = _cropped(scene, args.no_crop)
            source = str(scene.encoded.path)
    except (UserError, OSError) as e:  # the project's user errors; anything else is a bug and keeps its traceback
        print(f"{prog}: {one_line(e)}", file=sys.stderr)
        return EXIT_USER
    if cropped:
        print(cropped)
    total = g.num
    if args.prune > 0:
        g = g.subset(g.opacities >= args.prune)
    pruned = f", {total - g.num} below opacity {args.prune:.4g} dropped" if args.prune > 0 else ""
    try:
        if args.by is not None:
            from particlesplat.analysis.bundle_parts import bundle_header, bundle_parts
            from particlesplat.formats.bundle import write_bundle

            arrays = None
            if scene is not None:
                from particlesplat.analysis.particle_arrays import particle_arrays

                arrays = particle_arrays(scene.model, scene.particles, objects=scene.objects)  # user groups win
            parts = bundle_parts(g, args.by, arrays)
            header = (
                bundle_header(source, None)
                if scene is None
                else bundle_header(
                    source, scene.model_name, scene.particles, scene.encoded.context, edited=bool(scene.edits)
                )
            )
            manifest = write_bundle(args.out, args.by, parts, header)
            print(
                f"saved {args.out}/: {len(parts) - 1} {args.by} part(s) + rest.ply and manifest.json, "
                f"{manifest['gaussians']} Gaussians{pruned}"
            )
            return 0
        if fmt.suffix == ".sog" and g.sh.shape[1] > 1:
            from particlesplat.formats.sog import MAX_PALETTE, keeps_sh

            if not keeps_sh(g.num, g.sh.shape[1]):
                print(
                    f"{prog}: warning: .sog keeps SH above degree 0 for up to {MAX_PALETTE} Gaussians, not "
                    f"{g.num}: higher bands dropped",
                    file=sys.stderr,
                )
        if fmt.suffix == ".splat" and g.sh.shape[1] > 1:
            print(f"{prog}: warning: .splat holds no SH: higher bands dropped", file=sys.stderr)
        fmt.write(g, args.out)
    except (UserError, OSError) as e:
        message = one_line(e)
        named = message if str(args.out) in message else f"--out {args.out}: {message}"
        print(f"{prog}: {named}", file=sys.stderr)
        return EXIT_USER
    size = os.path.getsize(args.out)
    per = f", {size / g.num:.1f} bytes a Gaussian" if g.num else ""
    print(f"saved {Path(args.out)} ({fmt.description}, {g.num} Gaussians{pruned}, {size} bytes{per})")
    return 0
