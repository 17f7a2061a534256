"""The error a scene folder that does not follow the format raises (docs/dataset.md), apart from the readers so
that every reader of scene files can raise it."""

from __future__ import annotations

from particlesplat.core.errors import UserError


class SceneFormatError(UserError):
    """A scene folder does not follow the format; the message names the file and the key."""


__all__ = ["SceneFormatError"]
