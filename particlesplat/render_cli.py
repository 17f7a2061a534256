"""``particlesplat render``: render a (possibly edited) scene headless with the torch renderer.

The default camera is the viewer's default view (:func:`particlesplat.views.default_view`);
``--look AZ,EL,DIST`` and ``--fov DEG`` mean what they mean in ``particlesplat-viewer``.
"""

from __future__ import annotations

import argparse
import sys
import torch

from .camera import Camera
from .encode_scene import add_source_arguments, check_source_arguments, load_model_scene, load_ply_checked
from .views import View, check_fov, default_view, parse_look, scene_background

DEFAULT_WIDTH, DEFAULT_HEIGHT = 640, 480  # pixels, when --width / --height are not given
MAX_SIDE = 8192  # pixels, as the viewer's --size
MAX_PIXELS = 4096 * 4096  # the torch renderer holds ~20 floats a pixel: ~1.3 GB at this size


def _background(text: str) -> tuple[float, float, float]:
    try:
        vals = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"--background: expected R,G,B numbers in [0, 1], got {text!r}") from None
    if len(vals) != 3 or not all(0.0 <= v <= 1.0 for v in vals):
        raise argparse.ArgumentTypeError(f"--background: expected R,G,B numbers in [0, 1], got {text!r}")
    return vals  # type: ignore[return-value]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_source_arguments(parser, ply_help="render a 3DGS .ply instead of a model scene")
    cam = parser.add_mutually_exclusive_group()
    cam.add_argument("--view", type=int, help="render from input camera I of the scene (0-based)")
    cam.add_argument("--look", help="camera AZ,EL,DIST (degrees, degrees, metres) about the default target")
    parser.add_argument("--fov", type=float, help="vertical field of view in degrees (with --look or the default "
                                                  "view); none = the scene's")
    parser.add_argument("--width", type=int, help="image width in pixels; none = 640 (with --view and --height: "
                                                  "from the input camera's aspect)")
    parser.add_argument("--height", type=int, help="image height in pixels; none = 480 (with --view: from the "
                                                   "width and the input camera's aspect, never stretched)")
    parser.add_argument("--background", type=_background, default=None,
                        help="background colour R,G,B (default: the model's learned background colour, if it "
                             "has one, else 0.12,0.14,0.18)")
    parser.add_argument("--prune", type=float, default=0.0, help="drop Gaussians with opacity below this")
    parser.add_argument("--out", required=True, help="output PNG")


def _scene_and_gaussians(args: argparse.Namespace):
    """(Gaussians, all input cameras, edits dict, model name, source, background colour) for the arguments."""
    check_source_arguments(args)
    if args.ply:
        return load_ply_checked(args.ply), [], {}, "", str(args.ply), scene_background(None)
    from .edit_ops import SceneEditor, load_edit_file, scene_mismatch

    model, enc, name = load_model_scene(args.checkpoint, args.scene, args.context)
    particles, edits = enc.particles, {}
    if args.edits:  # version 1 (particle values) or 2 (object operations, replayed as the viewer did them)
        file = load_edit_file(args.edits)
        warning = scene_mismatch(file, enc.path, enc.context)
        if warning:
            print(f"particlesplat render: warning: {args.edits}: {warning}", file=sys.stderr)
        editor = SceneEditor(model, particles, enc.all_cameras, enc.context)
        editor.apply_file(file, str(args.edits))
        particles, edits = editor.particles, editor.edits()
    return (model.decode(particles).detach().to("cpu"), enc.all_cameras, edits, name, str(enc.path),
            scene_background(model))


def resolve_camera(args: argparse.Namespace, cameras: list[Camera], gaussians) -> tuple[Camera, View | None]:
    """The camera of ``--view`` / ``--look`` / ``--fov`` / default view at --width x --height.

    With ``--view`` a missing --width or --height follows the input camera's aspect ratio (an
    input view is never stretched unless both are given).
    """
    for name in ("width", "height"):
        if getattr(args, name) is not None and not 1 <= getattr(args, name) <= MAX_SIDE:
            raise ValueError(f"--{name} must be in [1, {MAX_SIDE}], got {getattr(args, name)}")
    if args.view is not None:
        if not cameras:
            raise ValueError("--view needs a scene with input cameras")
        if not 0 <= args.view < len(cameras):
            raise ValueError(f"--view {args.view}: the scene has {len(cameras)} cameras (0..{len(cameras) - 1})")
        if args.fov is not None:
            raise ValueError("--fov applies to --look or the default view, not to --view")
        cam = cameras[args.view]
        width, height = args.width, args.height
        if height is None:
            width = width or DEFAULT_WIDTH
            height = max(1, round(width * cam.height / cam.width))
        elif width is None:
            width = max(1, round(height * cam.width / cam.height))
        return cam.resized(width, height), None
    base = default_view(cameras or None, None if cameras else gaussians)
    view = View(base.target, parse_look(args.look) if args.look else base.look,
                check_fov(args.fov) if args.fov is not None else base.fov)
    return view.camera(args.width or DEFAULT_WIDTH, args.height or DEFAULT_HEIGHT), view


def run(args: argparse.Namespace) -> int:
    from . import render
    from .png import png_text, save_png

    from .atomic import check_writable
    from .errors import EXIT_USER, one_line

    try:
        try:
            check_writable(args.out)  # before the work, not after it
        except OSError as e:
            raise OSError(f"--out {one_line(e)}") from None
        g, cameras, edits, model_name, source, background = _scene_and_gaussians(args)
        camera, view = resolve_camera(args, cameras, g)
        if camera.width > MAX_SIDE or camera.height > MAX_SIDE or camera.width * camera.height > MAX_PIXELS:
            raise ValueError(f"--width/--height: {camera.width}x{camera.height} is beyond the largest image "
                             f"({MAX_SIDE} a side, {MAX_PIXELS} pixels)")
    except (OSError, ValueError, KeyError) as e:
        print(f"particlesplat render: {one_line(e)}", file=sys.stderr)
        return EXIT_USER
    if args.prune > 0:
        g = g.subset(g.opacities >= args.prune)
    with torch.no_grad():
        res = render(g, camera, background=background if args.background is None else args.background)
    extra = {"scene": source}
    if view is not None:
        extra.update(look=f"{view.look.azimuth:.6g},{view.look.elevation:.6g},{view.look.distance:.6g}",
                     fov=f"{view.fov:.6g}")
    try:
        path = save_png(args.out, res.rgb.numpy(), png_text(camera, edits, model_name, extra))
    except OSError as e:
        print(f"particlesplat render: --out {args.out}: cannot write ({one_line(e.strerror or e)})", file=sys.stderr)
        return EXIT_USER
    print(f"saved {path} ({camera.width}x{camera.height}, {g.num} Gaussians)")
    return 0
