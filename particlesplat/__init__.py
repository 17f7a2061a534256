"""ParticleSplat: object-centric latent particles that decode into 3D Gaussians.

Names are imported on first use (PEP 562), so importing one submodule does not load the others.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from particlesplat.core.lazy import lazy_exports

_EXPORTS = {
    "Camera": ".core.camera",
    "Gaussians": ".core.gaussians",
    "RenderResult": ".rendering.api",
    "render": ".rendering.api",
    "render_batch": ".rendering.api",
}
__all__ = ["Camera", "Gaussians", "RenderResult", "render", "render_batch"]
__version__ = "0.1.0"


__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)


if TYPE_CHECKING:
    from particlesplat.core.camera import Camera
    from particlesplat.core.gaussians import Gaussians
    from particlesplat.rendering.api import RenderResult, render, render_batch
