"""``particlesplat object``: export one object to a 3DGS ``.ply``; insert an object of one scene into another.

Objects are numbered as in ``particlesplat encode``'s ``object`` array (0..K-1, the groups of drawing
particles in order of their smallest particle index).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from particlesplat.core.choices import OBJECT_CENTRES
from particlesplat.data.families import checkpoint_help


def _xy(text: str) -> tuple[float, float]:
    try:
        x, y = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"--at: expected X,Y world metres, got {text!r}") from None
    return x, y


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from particlesplat.cli.main import HelpFormatter

    sub = parser.add_subparsers(dest="action", required=True)
    exp = sub.add_parser(
        "export",
        help="write one object's Gaussians as a standard 3DGS .ply",
        formatter_class=HelpFormatter,
    )
    exp.add_argument("--scene", required=True, help="scene folder")
    exp.add_argument("--object", type=int, required=True, help="object index (as in particlesplat encode)")
    exp.add_argument("--out", required=True, help="output .ply")
    ins = sub.add_parser(
        "insert",
        help="insert an object of --from into --scene at a free spot on its table or floor; writes the "
        "composed scene as a .ply (and a PNG)",
        formatter_class=HelpFormatter,
    )
    ins.add_argument("--scene", required=True, help="scene folder B that receives the object")
    ins.add_argument("--from", dest="source", required=True, help="scene folder A the object comes from")
    ins.add_argument("--from-context", help="context frames of A, e.g. 4,16; none = the default")
    ins.add_argument("--object", type=int, required=True, help="object index in A (as in particlesplat encode)")
    ins.add_argument(
        "--at",
        type=_xy,
        help="X,Y world metres for the object's centre on B's surface there (the table, or the floor past its edge); "
        "a spot another object takes moves to the nearest free one (said on stderr); none = the free spot nearest "
        "B's objects",
    )
    ins.add_argument("--centre", choices=OBJECT_CENTRES, default="resting", help="which object centre goes there")
    ins.add_argument("--out", required=True, help="output .ply of the composed scene (B with the object)")
    ins.add_argument("--png", help="also render the composed scene from B's default view to this PNG")
    for p in (exp, ins):
        p.add_argument(
            "--checkpoint",
            help=checkpoint_help(),
        )
        p.add_argument(
            "--context", help="context frames of --scene, e.g. 4,16; none = two frames 12 apart about the middle"
        )


def run(args: argparse.Namespace) -> int:
    from particlesplat.core.errors import OptionError
    from particlesplat.core.outputs import guard_outputs
    from particlesplat.data.scene_meta import default_checkpoint
    from particlesplat.editing.compose import export_object_ply, insert_object
    from particlesplat.editing.open_scene import encode_scene
    from particlesplat.editing.source_options import parse_context
    from particlesplat.formats.ply import write_ply
    from particlesplat.model import load_model

    guard_outputs(
        [("--out", args.out), ("--png", getattr(args, "png", None))],
        [("--checkpoint", args.checkpoint), ("--scene", args.scene), ("--from", getattr(args, "source", None))],
    )
    if getattr(args, "at", None) is not None:
        from particlesplat.core.limits import WORLD_MAX_METRES

        if not all(math.isfinite(v) and abs(v) <= WORLD_MAX_METRES for v in args.at):
            raise OptionError(
                f"--at: X,Y must be finite metres within +-{WORLD_MAX_METRES:g} of the origin, got "
                f"{args.at[0]:g},{args.at[1]:g}"
            )
    if args.action == "insert":  # one model encodes both scenes: they must be of one family
        from particlesplat.data.scene_meta import read_family

        theirs, ours = read_family(args.source), read_family(args.scene)
        if theirs and ours and theirs != ours:
            raise OptionError(
                f"--from {args.source} is a {theirs} scene and --scene {args.scene} a {ours} scene; one model "
                "encodes both: insert objects between scenes of one family"
            )
    from particlesplat.model.io import shipped_model_name

    checkpoint = args.checkpoint or default_checkpoint(args.scene)  # recorded in the PNG: the model that ran
    model = load_model(checkpoint)
    enc = encode_scene(model, args.scene, parse_context(args.context))
    if args.action == "export":
        path = export_object_ply(model, enc.particles, args.object, args.out)
        print(f"saved {path} (object {args.object} of {enc.path})")
        return 0
    src = encode_scene(model, args.source, parse_context(args.from_context))
    from particlesplat.editing.compose import object_members
    from particlesplat.editing.placement import footprints, insert_spot

    radius = footprints(model, src.particles, object_members(model, src.particles, args.object))[0].radius
    args.at, note = insert_spot(enc.support, footprints(model, enc.particles), radius, args.at)
    if note:  # where it went instead of --at: a spot taken, or past the table's edge
        print(f"particlesplat object insert: {note}", file=sys.stderr)
    support = enc.support.height_at(*args.at)
    particles, new = insert_object(
        model, enc.particles, src.particles, args.object, args.at, method=args.centre, support=support
    )
    g = model.decode(particles).detach().to("cpu")
    write_ply(g, Path(args.out))
    print(
        f"saved {args.out}: {enc.path} with object {args.object} of {src.path} as particles {new[0]}..{new[-1]} "
        f"at ({args.at[0]:g}, {args.at[1]:g})"
    )
    if args.png:
        import torch

        from particlesplat.core.viewpoints import default_view
        from particlesplat.data.scene_meta import read_framing
        from particlesplat.formats.png import png_text, save_png
        from particlesplat.rendering.api import render

        camera = default_view(enc.all_cameras, framing=read_framing(enc.path)).camera(640, 480)
        from particlesplat.rendering.budget import check_render_memory

        check_render_memory(g, camera, f"--png of {enc.path} with object {args.object}")
        from particlesplat.core.errors import blame
        from particlesplat.core.gaussians import BadGaussiansError

        with torch.no_grad(), blame(f"{enc.path} with object {args.object} of {src.path}", BadGaussiansError):
            res = render(g, camera, background=model.backdrop_image(enc.particles, camera).cpu())
        text = png_text(camera, {}, shipped_model_name(checkpoint), {"scene": str(enc.path)})
        print(f"saved {save_png(args.png, res.rgb.numpy(), text)}")
    return 0
