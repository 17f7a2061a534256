"""ParticleSplat model: latent particles encoded from posed RGB(-D) views and decoded into 3D Gaussians."""

from .config import ConfigError, ModelConfig, TrainConfig, load_config
from .io import load_model, read_checkpoint, save_checkpoint
from .particles import EDITABLE, Particles
from .particlesplat import ParticleSplat

__all__ = [
    "ConfigError",
    "EDITABLE",
    "ModelConfig",
    "ParticleSplat",
    "Particles",
    "TrainConfig",
    "load_config",
    "load_model",
    "read_checkpoint",
    "save_checkpoint",
]
