"""ParticleSplat: object-centric latent particles that decode into 3D Gaussians."""

from .camera import Camera
from .gaussians import Gaussians
from .renderer import RenderResult, render, render_batch

__all__ = ["Camera", "Gaussians", "RenderResult", "render", "render_batch"]
__version__ = "0.1.0"
