"""Screenshots and exports: PNG with text chunks (camera, edits, model), numbered names that
never overwrite, and .ply export."""

from __future__ import annotations

import json
import os
import tempfile
from os import PathLike
from pathlib import Path

import numpy as np
import yaml
from PIL import Image
from PIL.PngImagePlugin import PngInfo

from particlesplat.atomic import atomic_path
from particlesplat.camera import Camera
from particlesplat.edits import Edits
from particlesplat.gaussians import Gaussians


def camera_text(camera: Camera) -> str:
    """JSON of a camera: K, OpenCV c2w, width, height, vertical fov."""
    return json.dumps({"K": camera.K.detach().cpu().double().tolist(),
                       "c2w_opencv": camera.c2w.detach().cpu().double().tolist(),
                       "width": camera.width, "height": camera.height, "fov_y": camera.fov_y})


def png_text(camera: Camera, edits: Edits, model: str, extra: dict[str, str] | None = None) -> dict[str, str]:
    """The PNG text chunks of a screenshot."""
    text = {"Software": "ParticleSplat Studio viewer", "camera": camera_text(camera),
            "edits": yaml.safe_dump({int(i): {k: list(v) for k, v in a.items()} for i, a in edits.items()},
                                    sort_keys=True),
            "model": model}
    text.update(extra or {})
    return text


def _png_bytes_image(rgb: np.ndarray) -> Image.Image:
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"screenshot: expected an (H, W, 3) image, got {rgb.shape}")
    return Image.fromarray((np.clip(rgb, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8), "RGB")


def _info(text: dict[str, str]) -> PngInfo:
    info = PngInfo()
    for k, v in text.items():
        info.add_itxt(k, v)
    return info


def save_png(path: str | PathLike, rgb: np.ndarray, text: dict[str, str] | None = None) -> Path:
    """Write rgb (H, W, 3) floats in [0, 1] as an 8-bit PNG with text chunks, atomically."""
    path = Path(path)
    with atomic_path(path) as tmp:
        _png_bytes_image(rgb).save(tmp, format="PNG", pnginfo=_info(text or {}))
    return path


def save_numbered(folder: str | PathLike, prefix: str, suffix: str, write) -> Path:
    """Write a new file ``<prefix>NNNN<suffix>`` in ``folder`` with the first free number.

    ``write(tmp_path)`` writes the content to a temporary file; it is then hard-linked to the
    numbered name, which fails instead of overwriting if that name appeared meanwhile.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{prefix}", suffix=".tmp" + suffix, dir=folder)
    os.close(fd)
    try:
        write(Path(tmp))
        taken = {p.name for p in folder.glob(f"{prefix}*{suffix}")}
        n = 1
        while True:
            name = f"{prefix}{n:04d}{suffix}"
            if name not in taken:
                try:
                    os.link(tmp, folder / name)
                    return folder / name
                except FileExistsError:
                    pass
            n += 1
    finally:
        os.unlink(tmp)


def save_screenshot(folder: str | PathLike, rgb: np.ndarray, text: dict[str, str]) -> Path:
    """A numbered PNG screenshot (``particlesplat_NNNN.png``) in ``folder``."""
    img, info = _png_bytes_image(rgb), _info(text)
    return save_numbered(folder, "particlesplat_", ".png", lambda p: img.save(p, format="PNG", pnginfo=info))


def export_ply(folder: str | PathLike, gaussians: Gaussians) -> Path:
    """A numbered standard 3DGS .ply (``particlesplat_NNNN.ply``) of ``gaussians`` in ``folder``."""
    from particlesplat.ply import write_ply

    return save_numbered(folder, "particlesplat_", ".ply", lambda p: write_ply(gaussians, p))
