"""``particlesplat-viewer``'s start: its options, and what it answers before anything heavy loads (``--help``, a bad
option or path, no display), in a fraction of a second; then the app (:mod:`viewer.app`: torch, moderngl, glfw,
imgui) runs the viewer. ``python -m viewer`` is the same command."""

from __future__ import annotations

import argparse
import sys

from particlesplat.core.options import attach_option_values
from particlesplat.editing.source_options import add_source_arguments, check_source_arguments
from particlesplat.formats.splat_files import SUFFIX_HELP

from .display import check_display
from .gl.caps import COMPOSITING, COMPOSITING_HELP
from .signals import raise_on_stop_signals


def parse_size(text: str) -> tuple[int, int]:
    """``"WxH"`` -> (W, H)."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"--size: expected WxH, e.g. 1024x768, got {text!r}") from None
    if not (16 <= w <= 8192 and 16 <= h <= 8192):
        raise argparse.ArgumentTypeError(f"--size: width and height must be in [16, 8192], got {text!r}")
    return w, h


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="particlesplat-viewer",
        description="View and edit ParticleSplat scenes: orbit, select and drag particles, segment, screenshot.",
    )
    add_source_arguments(
        p, ply_help=f"open a Gaussian file ({SUFFIX_HELP}) instead of a model scene (no particle editing)"
    )
    p.add_argument("--frames", type=int, help="run N frames, print the median frame time and exit")
    p.add_argument("--screenshot", help="with --frames: save the last render (no UI) to this PNG")
    p.add_argument("--size", type=parse_size, default=(1280, 800), help="window size WxH (default: 1280x800)")
    p.add_argument(
        "--orbit",
        action="store_true",
        help="with --frames: turn the camera a little every frame, as a drag does (frames at the moving "
        "render scale), then draw the still full-scale frame",
    )
    p.add_argument("--look", help="camera AZ,EL,DIST (degrees, degrees, metres) about the default target")
    p.add_argument("--fov", type=float, help="vertical field of view in degrees (default: the scene's cameras', or 40)")
    p.add_argument(
        "--primitive",
        choices=("auto", "quads", "points"),
        default="auto",
        help="splat primitive: auto = point sprites when every splat fits 255 px, else oriented quads "
        "(both exact; the default); points = always sprites (large splats clipped)",
    )
    p.add_argument("--compositing", choices=COMPOSITING, default="auto", help=COMPOSITING_HELP)
    p.add_argument(
        "--output-dir",
        help="folder for screenshots, .ply exports and edit files (default: ~/.local/share/particlesplat, or "
        "$XDG_DATA_HOME/particlesplat; printed at start); unsaved edits are autosaved in "
        "~/.local/state/particlesplat/autosave ($XDG_STATE_HOME)",
    )
    p.add_argument("--no-ui", action="store_true", help="start with the panel hidden (H toggles)")
    return p


def main(argv: list[str] | None = None) -> int:
    """The viewer under the error policy (:func:`particlesplat.core.errors.run_command`): a bad file or argument is
    one line and exit code 2, Ctrl-C one line and 130 (the process then ends at once, its edits autosaved); a bug
    keeps its traceback."""
    from particlesplat.core.errors import end_at_once_if_interrupted, run_command

    return end_at_once_if_interrupted(run_command("particlesplat-viewer", lambda: _main(argv)))


def parse_options(argv: list[str] | None = None) -> argparse.Namespace | int:
    """The viewer's options, checked without loading anything heavy: the parsed arguments, or the exit code of a
    bad one (its line printed). Raises :class:`NoDisplay` when there is no display to open a window on."""
    args = build_parser().parse_args(attach_option_values(list(sys.argv[1:] if argv is None else argv)))
    if args.screenshot and args.frames is None:
        print("particlesplat-viewer: --screenshot needs --frames", file=sys.stderr)
        return 2
    try:
        check_source_arguments(args)
    except ValueError as e:
        print(f"particlesplat-viewer: {e}", file=sys.stderr)
        return 2
    if args.frames is not None and args.frames < 1:
        print("particlesplat-viewer: --frames must be >= 1", file=sys.stderr)
        return 2
    check_display()  # before the heavy imports and the scene
    return args


def _main(argv: list[str] | None = None) -> int:
    raise_on_stop_signals()  # until the window is up: Ctrl-C, SIGTERM, SIGHUP end with one line
    args = parse_options(argv)
    if isinstance(args, int):
        return args
    from .app import run_viewer  # torch, moderngl, glfw, imgui: only now

    return run_viewer(args)
