"""``particlesplat render``: render a (possibly edited) scene headless with the torch renderer.

The default camera is the viewer's default view (:func:`particlesplat.core.viewpoints.default_view`);
``--look AZ,EL,DIST`` and ``--fov DEG`` mean what they mean in ``particlesplat-viewer``. Several ``--mode`` and
``--view`` values render several images from one encode. Torch loads after the arguments were checked.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING, cast

from particlesplat.core.choices import MODES, NEEDS_PARTICLES
from particlesplat.core.errors import OptionError
from particlesplat.core.limits import check_option_range
from particlesplat.data.folders import check_existing, check_file
from particlesplat.editing.source_options import add_source_arguments, check_source_arguments
from particlesplat.formats.splat_files import SUFFIX_HELP
from particlesplat.rendering.choice import add_rasterizer_option, apply_rasterizer_option

if TYPE_CHECKING:
    from particlesplat.core.camera import Camera
    from particlesplat.core.choices import RenderMode
    from particlesplat.core.viewpoints import Framing, View

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
    return vals


def _modes(text: str) -> tuple[str, ...]:
    """``"rgb,depth"`` -> ("rgb", "depth"): each of :data:`MODES`, none twice."""
    modes = tuple(m.strip() for m in text.split(","))
    bad = [m for m in modes if m not in MODES]
    if bad or len(set(modes)) != len(modes):
        raise argparse.ArgumentTypeError(
            f"expected one or more of {', '.join(MODES)}, comma-separated, each once; got {text[:80]!r}"
        )
    return modes


def _views(text: str) -> tuple[int, ...]:
    """``"4,10,16"`` -> (4, 10, 16): input camera indices, each once."""
    try:
        views = tuple(int(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected camera indices I or I,J,..., got {text[:80]!r}") from None
    if len(set(views)) != len(views):
        raise argparse.ArgumentTypeError(f"a camera index given twice: {text[:80]!r}")
    return views


def output_paths(out: str, modes: tuple[str, ...], views: tuple[int, ...] | None) -> dict[tuple[str, int | None], Path]:
    """The PNG of each (mode, view): ``OUT`` for one image; several get ``OUT_STEM_viewI_MODE.png`` beside it (the
    view part with several views, the mode part with several modes)."""
    path = Path(out)
    keys = [(m, v) for v in (views or (None,)) for m in modes]
    if len(keys) == 1:
        return {keys[0]: path}
    several_views = views is not None and len(views) > 1
    out_paths = {}
    for m, v in keys:
        parts = ([f"view{v}"] if several_views else []) + ([m] if len(modes) > 1 else [])
        out_paths[(m, v)] = path.with_name(f"{path.stem}_{'_'.join(parts)}{path.suffix or '.png'}")
    return out_paths


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_source_arguments(
        parser, ply_help=f"render a Gaussian file ({SUFFIX_HELP}, or a bundle's manifest.json) instead of a model scene"
    )
    add_rasterizer_option(parser)
    cam = parser.add_mutually_exclusive_group()
    cam.add_argument(
        "--view",
        type=_views,
        help="render from input camera I of the scene (0-based); I,J,... renders one image a camera (OUT_viewI.png)",
    )
    cam.add_argument("--look", help="camera AZ,EL,DIST (degrees, degrees, metres) about the default target")
    cam.add_argument(
        "--camera-from",
        metavar="PNG",
        help="the camera of a viewer screenshot or a rendered PNG (its 'camera' chunk); --width/--height rescale it",
    )
    parser.add_argument(
        "--edits-from",
        metavar="PNG",
        help="replay the edit file a viewer screenshot or a rendered PNG carries (its 'edits' chunk), on the scene "
        "and context frames it names unless --scene / --context say otherwise; with --camera-from the same PNG, "
        "this reproduces the screenshot",
    )
    parser.add_argument(
        "--fov",
        type=float,
        help="vertical field of view in degrees (with --look or the default view); none = the scene's",
    )
    parser.add_argument(
        "--width",
        type=int,
        help="image width in pixels; none = 640 (with --view and --height: from the input camera's aspect)",
    )
    parser.add_argument(
        "--height",
        type=int,
        help="image height in pixels; none = 480 (with --view: from the "
        "width and the input camera's aspect, never stretched)",
    )
    parser.add_argument(
        "--background",
        type=_background,
        default=None,
        help="background colour R,G,B (default: what the model puts behind the scene: the colours its particles "
        "read from their views, or its learned colour; for a .ply, 0.12,0.14,0.18)",
    )
    parser.add_argument("--prune", type=float, default=0.0, help="drop Gaussians with opacity below this")
    parser.add_argument(
        "--out",
        required=True,
        help="output PNG (with --turntable: the animation, .gif or .webp; frames OUT_STEM_NNN.png beside it)",
    )
    parser.add_argument(
        "--mode",
        type=_modes,
        default=("rgb",),
        help=f"layer(s) to render, of {', '.join(MODES)}: the scene, depth (with a colour bar in metres), "
        "segmentation by particle or object, foreground or background alone, or the particles' 3D keypoints or "
        "boxes over the scene; M,N,... renders one image a mode from one encode (OUT_M.png) (default: rgb)",
    )
    parser.add_argument(
        "--turntable",
        type=int,
        default=0,
        help="N > 0: N frames orbiting the default target (or --look) once, as PNGs plus an animated GIF/WebP",
    )


def _scene_and_gaussians(args: argparse.Namespace):
    """(Gaussians, all input cameras, edits (the edit file's text, else {}), model name, source, what is behind the
    scene (:func:`~particlesplat.core.viewpoints.scene_backdrop`), particle arrays or None) for the arguments (the
    arrays only for a --mode that draws from the particles)."""
    from particlesplat.core.viewpoints import scene_backdrop, scene_background

    check_source_arguments(args)
    from particlesplat.editing.open_scene import load_ply_checked

    if args.ply:
        return load_ply_checked(args.ply), [], {}, "", str(args.ply), scene_background(None), None
    from particlesplat.editing.edited_scene import open_edited_scene

    scene = open_edited_scene(args.checkpoint, args.scene, args.context, args.edits, getattr(args, "edits_from", None))
    for warning in scene.warnings:
        print(f"particlesplat render: warning: {warning}", file=sys.stderr)
    model, enc, particles, edits, name = scene.model, scene.encoded, scene.particles, scene.edits, scene.model_name
    g = scene.gaussians()  # the crop box the edits set hides what lies outside it
    arrays = None
    if set(getattr(args, "mode", ("rgb",))) & set(NEEDS_PARTICLES):
        from particlesplat.analysis.particle_arrays import particle_arrays

        arrays = particle_arrays(model, particles, g, objects=scene.objects)  # the user's groups win
    return g, enc.all_cameras, edits, name, str(enc.path), scene_backdrop(model, particles), arrays


def resolve_camera(
    args: argparse.Namespace, cameras: list[Camera], gaussians, framing: Framing | None = None
) -> tuple[Camera, View | None]:
    """The camera of ``--view`` / ``--look`` / ``--fov`` / default view (framed by ``framing``, the scene's
    scene.json, else by its cameras) at --width x --height.

    With ``--view`` a missing --width or --height follows the input camera's aspect ratio (an
    input view is never stretched unless both are given).
    """
    from particlesplat.core.viewpoints import View, check_fov, default_view, parse_look

    for name in ("width", "height"):
        if getattr(args, name) is not None and not 1 <= getattr(args, name) <= MAX_SIDE:
            raise OptionError(f"--{name} must be in [1, {MAX_SIDE}], got {getattr(args, name)}")
    if getattr(args, "camera_from", None):
        from particlesplat.formats.png import camera_from_png

        if args.fov is not None:
            raise OptionError("--fov applies to --look or the default view, not to --camera-from")
        cam = camera_from_png(args.camera_from)
        width, height = args.width, args.height
        if width is None and height is None:
            return cam, None
        if height is None:
            height = max(1, round(width * cam.height / cam.width))
        elif width is None:
            width = max(1, round(height * cam.width / cam.height))
        return cam.resized(width, height), None
    if args.view is not None:
        if not cameras:
            raise OptionError("--view needs a scene with input cameras")
        if not 0 <= args.view < len(cameras):
            raise OptionError(f"--view {args.view}: the scene has {len(cameras)} cameras (0..{len(cameras) - 1})")
        if args.fov is not None:
            raise OptionError("--fov applies to --look or the default view, not to --view")
        cam = cameras[args.view]
        width, height = args.width, args.height
        if height is None:
            width = width or DEFAULT_WIDTH
            height = max(1, round(width * cam.height / cam.width))
        elif width is None:
            width = max(1, round(height * cam.width / cam.height))
        return cam.resized(width, height), None
    base = default_view(cameras or None, None if cameras else gaussians, framing)
    view = View(
        base.target,
        parse_look(args.look) if args.look else base.look,
        check_fov(args.fov) if args.fov is not None else base.fov,
    )
    return view.camera(args.width or DEFAULT_WIDTH, args.height or DEFAULT_HEIGHT), view


def _check_inputs(args: argparse.Namespace) -> None:
    """What the user named exists, and the options agree: checked before torch loads (a typo is one quick line)."""
    check_existing(args.scene, "--scene")
    for name in ("ply", "checkpoint", "edits", "camera_from", "edits_from"):
        check_file(getattr(args, name, None), f"--{name.replace('_', '-')}", shipped=name == "checkpoint")
    check_source_arguments(args)
    check_option_range(args.prune, "--prune", 0.0, 1.0)  # an opacity
    several = len(args.mode) > 1 or (args.view is not None and len(args.view) > 1)
    if args.turntable < 0:
        raise OptionError(f"--turntable must be >= 0 frames, got {args.turntable}")
    if args.turntable and args.view is not None:
        raise OptionError("--turntable orbits the default target: use --look (or nothing), not --view")
    if args.turntable and getattr(args, "camera_from", None):
        raise OptionError("--turntable orbits the default target: use --look (or nothing), not --camera-from")
    if args.turntable and several:
        raise OptionError("--turntable renders one mode: give one --mode")
    needs = [m for m in args.mode if m in NEEDS_PARTICLES]
    if needs and args.ply:
        raise OptionError(f"--mode {','.join(needs)} needs a model scene (particles), not --ply")


def run(args: argparse.Namespace) -> int:
    from particlesplat.core.errors import EXIT_USER, one_line

    try:
        _check_inputs(args)
    except (OSError, ValueError) as e:
        print(f"particlesplat render: {one_line(e)}", file=sys.stderr)
        return EXIT_USER
    apply_rasterizer_option(args)
    from particlesplat.core.atomic import check_writable
    from particlesplat.core.outputs import guard_outputs
    from particlesplat.formats.png import png_text, save_png

    targets = output_paths(args.out, args.mode, args.view)
    try:
        guard_outputs(
            [("--out", path) for path in targets.values()],
            [
                (f"--{k.replace('_', '-')}", getattr(args, k, None))
                for k in ("checkpoint", "scene", "ply", "edits", "edits_from", "camera_from")
            ],
        )
        for path in targets.values():
            try:
                check_writable(path)  # before the work, not after it
            except OSError as e:
                raise OSError(f"--out {one_line(e)}") from None
        g, cameras, edits, model_name, source, background, arrays = _scene_and_gaussians(args)
        from particlesplat.core.errors import blame
        from particlesplat.core.gaussians import BadGaussiansError

        with blame(f"{source}{' with ' + model_name if model_name else ''}", BadGaussiansError):
            g.check("the Gaussians it decodes")  # the renderer's own check, as one line naming the input
        from particlesplat.data.scene_meta import read_framing
        from particlesplat.rendering.budget import check_render_memory

        framing = read_framing(source) if cameras else None
        owners = int(g.owner.max()) + 2 if {"particles", "objects"} & set(args.mode) and g.num else 0
        shots = {}  # view (None: --look, --camera-from or the default) -> (camera, View or None)
        for v in args.view or (None,):
            shots[v] = resolve_camera(argparse.Namespace(**{**vars(args), "view": v}), cameras, g, framing)
            camera = shots[v][0]
            if camera.width > MAX_SIDE or camera.height > MAX_SIDE or camera.width * camera.height > MAX_PIXELS:
                raise OptionError(
                    f"--width/--height: {camera.width}x{camera.height} is beyond the largest image "
                    f"({MAX_SIDE} a side, {MAX_PIXELS} pixels)"
                )
            check_render_memory(g, camera, source, owners)  # the renderer's pairs, before it allocates them
        if args.turntable:
            from particlesplat.analysis.figures import check_turntable_targets, turntable_memory
            from particlesplat.core.limits import check_memory

            check_memory(
                turntable_memory(args.turntable, camera.width, camera.height),
                f"--turntable {args.turntable} frames of {camera.width}x{camera.height}",
            )
            check_turntable_targets(args.out, args.turntable)
    except (OSError, ValueError, KeyError) as e:
        print(f"particlesplat render: {one_line(e)}", file=sys.stderr)
        return EXIT_USER
    if args.prune > 0:
        g = g.subset(g.opacities >= args.prune)
    from particlesplat.analysis.figures import render_mode, write_turntable

    background = background if args.background is None else args.background
    try:
        if args.turntable:
            camera, view = shots[None]
            assert view is not None  # resolve_camera has one but for --view and --camera-from, refused above
            extra = {"scene": source, "mode": args.mode[0], **_look_text(view)}
            frames, anim = write_turntable(
                g,
                view,
                args.turntable,
                camera.width,
                camera.height,
                args.out,
                args.mode[0],
                background=background,
                arrays=arrays,
                save_frame=lambda p, rgb, c: save_png(p, rgb, png_text(c, edits, model_name, extra)),
            )
            print(f"saved {anim} and {len(frames)} frames {frames[0]} .. {frames[-1]} ({camera.width}x{camera.height})")
            return 0
        for (mode, v), target in targets.items():
            camera, view = shots[v]
            extra = {"scene": source, "mode": mode, **_look_text(view)}
            image = render_mode(
                g, camera, cast("RenderMode", mode), background=background, arrays=arrays, colour_bar=True
            )
            path = save_png(target, image, png_text(camera, edits, model_name, extra))
            print(f"saved {path} ({camera.width}x{camera.height}, {mode}, {g.num} Gaussians)")
    except OSError as e:
        print(f"particlesplat render: --out {args.out}: cannot write ({one_line(e.strerror or e)})", file=sys.stderr)
        return EXIT_USER
    return 0


def _look_text(view: View | None) -> dict[str, str]:
    """The ``look`` and ``fov`` text chunks of a view (none for an input camera)."""
    if view is None:
        return {}
    return {
        "look": f"{view.look.azimuth:.6g},{view.look.elevation:.6g},{view.look.distance:.6g}",
        "fov": f"{view.fov:.6g}",
    }
