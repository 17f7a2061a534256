"""ParticleSplat model: latent particles encoded from posed RGB(-D) views and decoded into 3D Gaussians.

Names are imported on first use (PEP 562), so importing one submodule does not load the others.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from particlesplat.core.lazy import lazy_exports

_EXPORTS = {
    "ConfigError": ".config",
    "EDITABLE": ".particles",
    "ModelConfig": ".config",
    "ParticleSplat": ".particlesplat",
    "Posterior": ".posterior",
    "Particles": ".particles",
    "TrainConfig": ".config",
    "load_config": ".config",
    "load_model": ".io",
    "read_checkpoint": ".io",
    "save_checkpoint": ".io",
}
__all__ = [
    "ConfigError",
    "EDITABLE",
    "ModelConfig",
    "ParticleSplat",
    "Particles",
    "Posterior",
    "TrainConfig",
    "load_config",
    "load_model",
    "read_checkpoint",
    "save_checkpoint",
]


__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)


if TYPE_CHECKING:
    from particlesplat.model.config import ConfigError, ModelConfig, TrainConfig, load_config
    from particlesplat.model.io import load_model, read_checkpoint, save_checkpoint
    from particlesplat.model.particles import EDITABLE, Particles
    from particlesplat.model.particlesplat import ParticleSplat
    from particlesplat.model.posterior import Posterior
