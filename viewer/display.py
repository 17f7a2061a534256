"""Whether there is a display to open the viewer's window on (checked before anything heavy loads)."""

from __future__ import annotations

import os
import sys

from particlesplat.core.errors import UserError


class NoDisplay(UserError):
    """No display to open a window on: the viewer ends with one line naming DISPLAY and xvfb-run."""


def check_display() -> None:
    """NoDisplay (one line) on Linux when neither DISPLAY nor WAYLAND_DISPLAY is set: before the scene loads."""
    if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        raise NoDisplay(
            "no display: DISPLAY is not set; on a machine without a screen run xvfb-run -a particlesplat-viewer"
        )
