"""What the viewer and ``particlesplat render`` open, as command-line options (light to import: no torch, so
``--help`` and argument errors are quick): ``--checkpoint``, ``--scene`` | ``--ply``, ``--context``, ``--edits``."""

from __future__ import annotations

import argparse

from particlesplat.core.errors import OptionError
from particlesplat.data.families import DEFAULT_FAMILY, get_family, shipped_models_text


def add_source_arguments(parser: argparse.ArgumentParser, ply_help: str) -> None:
    """``--checkpoint``, ``--scene`` | ``--ply``, ``--context``, ``--edits``: what the viewer and
    ``particlesplat render`` open (see :func:`load_model_scene`)."""
    parser.add_argument(
        "--checkpoint",
        help=f"model checkpoint; none = the shipped model of the scene's family ({shipped_models_text()})",
    )
    src = parser.add_mutually_exclusive_group()
    demos = f"assets/{get_family(DEFAULT_FAMILY).demo_scenes}"
    src.add_argument("--scene", help=f"scene folder to encode; none = the first demo scene in {demos}")
    src.add_argument("--ply", help=ply_help)
    parser.add_argument(
        "--context", help="context frame indices of the scene, e.g. 4,16; none = two frames 12 apart about the middle"
    )
    parser.add_argument(
        "--edits",
        help="edits YAML to apply: version 2 object operations (pick by a pixel of an "
        "input frame; translate, remove, duplicate) or version 1 particle values",
    )


def check_source_arguments(args: argparse.Namespace) -> None:
    """ValueError when ``--ply`` is combined with what only a model scene has (--edits, --context)."""
    if getattr(args, "ply", None):
        for name in ("edits", "context"):
            if getattr(args, name, None):
                raise OptionError(f"--{name} needs a model scene, not --ply")


def parse_context(text: str | None) -> list[int] | None:
    """``"4,16"`` -> [4, 16]; None stays None (use the default)."""
    if text is None or str(text).strip() == "":
        return None
    try:
        return [int(v) for v in str(text).split(",")]
    except ValueError:
        raise OptionError(f"--context: expected comma-separated frame indices, got {text!r}") from None
