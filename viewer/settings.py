"""The viewer's remembered settings: a small JSON file in the user's config folder
(:func:`particlesplat.core.userdirs.config_dir`, ``viewer.json``). For now the panel's width, which the user sets by
dragging the panel's edge. A missing, unreadable or malformed file gives the defaults (and one line on the terminal
for a malformed one); the file is written whole under a temporary name, so a crash never leaves half of it."""

from __future__ import annotations

import json
import math
import sys
from dataclasses import asdict, dataclass
from pathlib import Path

from particlesplat.core.atomic import atomic_write
from particlesplat.core.jsonfile import read_json
from particlesplat.core.userdirs import config_dir

PANEL_WIDTH = 340.0  # window points: the panel's default width (about a quarter of a 1280-point window)
PANEL_WIDTH_RANGE = (240.0, 1200.0)  # window points: what a width is kept within


@dataclass
class ViewerSettings:
    """What the viewer remembers between runs. panel_width: window points."""

    panel_width: float = PANEL_WIDTH


def settings_path() -> Path:
    return config_dir() / "viewer.json"


def clamp_width(width: float) -> float:
    lo, hi = PANEL_WIDTH_RANGE
    return float(min(max(width, lo), hi)) if math.isfinite(width) else PANEL_WIDTH


def load_settings(path: Path | None = None) -> ViewerSettings:
    """The settings in ``path`` (default :func:`settings_path`); defaults for what it lacks or cannot give."""
    path = path or settings_path()
    try:
        data = read_json(path)  # the checked reader: bounded, nesting
    except FileNotFoundError:
        return ViewerSettings()
    except (OSError, ValueError) as e:
        print(f"particlesplat-viewer: warning: {path}: not read ({e}); using the default settings", file=sys.stderr)
        return ViewerSettings()
    width = data.get("panel_width") if isinstance(data, dict) else None
    if not isinstance(width, (int, float)) or isinstance(width, bool):
        print(f"particlesplat-viewer: warning: {path}: panel_width is not a number; using the default", file=sys.stderr)
        return ViewerSettings()
    return ViewerSettings(panel_width=clamp_width(float(width)))


def save_settings(settings: ViewerSettings, path: Path | None = None) -> Path:
    """Write ``settings`` to ``path`` (default :func:`settings_path`, its folder created); returns the path."""
    path = path or settings_path()
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_write(path, "w") as f:
        json.dump(asdict(settings), f, indent=1)
    return path
