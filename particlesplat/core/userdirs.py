"""Where the app keeps what is the user's and not the project's (XDG base directories): autosaves in the state folder,
settings in the config folder, screenshots, exports and edit files in the output folder, what was measured about the
machine in the cache folder. Nothing goes to the current directory unless the user names it.

Each folder is ``$XDG_*_HOME/particlesplat``, else the XDG default under the home folder; a relative or empty
``$XDG_*_HOME`` is ignored, as the specification says.
"""

from __future__ import annotations

import os
from pathlib import Path

APP = "particlesplat"


def _base(variable: str, default: str) -> Path:
    value = os.environ.get(variable, "")
    return Path(value) if value and Path(value).is_absolute() else Path.home() / default


def state_dir() -> Path:
    """``$XDG_STATE_HOME/particlesplat`` (default ``~/.local/state/particlesplat``): autosaved edits."""
    return _base("XDG_STATE_HOME", ".local/state") / APP


def config_dir() -> Path:
    """``$XDG_CONFIG_HOME/particlesplat`` (default ``~/.config/particlesplat``): the viewer's settings."""
    return _base("XDG_CONFIG_HOME", ".config") / APP


def output_dir() -> Path:
    """``$XDG_DATA_HOME/particlesplat`` (default ``~/.local/share/particlesplat``): the viewer's screenshots, ``.ply``
    exports and edit files when no ``--output-dir`` is given."""
    return _base("XDG_DATA_HOME", ".local/share") / APP


def cache_dir() -> Path:
    """``$XDG_CACHE_HOME/particlesplat`` (default ``~/.cache/particlesplat``): what the program measured about this
    machine (the rasterizer it chose), safe to delete."""
    return _base("XDG_CACHE_HOME", ".cache") / APP


def autosave_dir() -> Path:
    """Where unsaved edits are kept when a scene closes: ``state_dir() / "autosave"``."""
    return state_dir() / "autosave"
