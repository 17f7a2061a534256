"""PNG output with text chunks (camera, edits, model), shared by the viewer and ``particlesplat render``."""

from __future__ import annotations

import json
from os import PathLike
from pathlib import Path

import numpy as np
import yaml
from PIL import Image
from PIL.PngImagePlugin import PngInfo

from .atomic import atomic_path
from .camera import Camera


def camera_text(camera: Camera) -> str:
    """JSON of a camera: K, OpenCV c2w, width, height, vertical fov (degrees)."""
    return json.dumps({"K": camera.K.detach().cpu().double().tolist(),
                       "c2w_opencv": camera.c2w.detach().cpu().double().tolist(),
                       "width": camera.width, "height": camera.height, "fov_y": camera.fov_y})


def png_text(camera: Camera, edits: dict, model: str, extra: dict[str, str] | None = None) -> dict[str, str]:
    """Text chunks: Software, camera (JSON), edits (YAML, particle index -> values), model, extras."""
    text = {"Software": "ParticleSplat Studio", "camera": camera_text(camera),
            "edits": yaml.safe_dump({int(i): {k: list(v) for k, v in a.items()} for i, a in edits.items()},
                                    sort_keys=True),
            "model": model}
    text.update(extra or {})
    return text


def to_image(rgb: np.ndarray) -> Image.Image:
    """rgb: (H, W, 3) floats in [0, 1] -> 8-bit RGB image (rounded)."""
    rgb = np.asarray(rgb)
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"expected an (H, W, 3) image, got {rgb.shape}")
    return Image.fromarray((np.clip(rgb, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8), "RGB")


def png_info(text: dict[str, str]) -> PngInfo:
    info = PngInfo()
    for k, v in text.items():
        info.add_itxt(k, v)
    return info


def save_png(path: str | PathLike, rgb: np.ndarray, text: dict[str, str] | None = None) -> Path:
    """Write rgb (H, W, 3) in [0, 1] as an 8-bit PNG with text chunks, atomically (temp file + rename)."""
    path = Path(path)
    with atomic_path(path) as tmp:
        to_image(rgb).save(tmp, format="PNG", pnginfo=png_info(text or {}))
    return path
