"""Shared helpers of the GL and viewer tests: a headless EGL context, a small random model, the robot demo scene
encoded by its shipped model, and an action target that records what the actions say."""

from __future__ import annotations

import numpy as np
import torch
from model_data import TINY_MODEL

from particlesplat.model import ModelConfig, ParticleSplat

# the recipe's branches (static floor layer, learned background, back layer, cubic cells, refinement), shrunk
SMALL_MODEL = {**TINY_MODEL, "patch_gaussians": 3, "patch_base": 0}  # odd 3x3 patches, no base grid


def egl_context():
    import moderngl

    return moderngl.create_standalone_context(backend="egl")


def small_model(seed: int = 0) -> ParticleSplat:
    """An untrained model (random weights, fixed seed): enough to exercise encode/decode/edit."""
    torch.manual_seed(seed)
    model = ParticleSplat(ModelConfig(**SMALL_MODEL)).eval()
    with torch.no_grad():  # a learned background colour far from the viewer's default
        model.background_logit.copy_(torch.logit(torch.tensor([0.7, 0.4, 0.2])))
    return model


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2))
    return float("inf") if mse == 0 else 10.0 * np.log10(1.0 / mse)


def encoded_robot_demo():
    """The bundled robot demo scene encoded by its shipped model: ``(model, encoded, scene folder)``."""
    from particlesplat.data.scene_meta import default_checkpoint
    from particlesplat.editing.open_scene import demo_scenes, encode_scene
    from particlesplat.model import load_model

    scene = next(p for p in demo_scenes() if "robot" in str(p))
    model = load_model(default_checkpoint(scene))
    return model, encode_scene(model, scene), scene


def recording_target(scene):
    """An ``ActionTarget`` on ``scene`` (a fresh view state and requests) and the list its messages go to."""
    from viewer.actions import ActionTarget
    from viewer.state import ViewState
    from viewer.ui.fields import UiRequests

    said: list[str] = []
    return ActionTarget(scene, ViewState(), UiRequests(), said.append, (0.3, 0.0, 0.0)), said
