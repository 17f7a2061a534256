"""ParticleSplat: object-centric latent particles that decode into 3D Gaussians.

Names are imported on first use (PEP 562), so importing one submodule does not load the others.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

_EXPORTS = {
    "Camera": ".camera",
    "Gaussians": ".gaussians",
    "RenderResult": ".renderer",
    "render": ".renderer",
    "render_batch": ".renderer",
}
__all__ = ["Camera", "Gaussians", "RenderResult", "render", "render_batch"]
__version__ = "0.1.0"


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        value = getattr(importlib.import_module(_EXPORTS[name], __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *_EXPORTS])


if TYPE_CHECKING:
    from .camera import Camera
    from .gaussians import Gaussians
    from .renderer import RenderResult, render, render_batch
