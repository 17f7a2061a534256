"""PNG output with text chunks (camera, edits, model), shared by the viewer and ``particlesplat render``."""

from __future__ import annotations

import json
from os import PathLike
from pathlib import Path

import numpy as np
import torch
import yaml
from PIL import Image
from PIL.PngImagePlugin import PngInfo

from particlesplat.core.atomic import atomic_path
from particlesplat.core.camera import Camera, camera_problem
from particlesplat.core.errors import UserError, one_line
from particlesplat.core.jsonfile import parse_json


class PngError(UserError):
    """A PNG whose text chunks cannot be used; the message names the file and the chunk."""


def camera_text(camera: Camera) -> str:
    """JSON of a camera: K, OpenCV c2w, width, height, vertical fov (degrees)."""
    return json.dumps(
        {
            "K": camera.K.detach().cpu().double().tolist(),
            "c2w_opencv": camera.c2w.detach().cpu().double().tolist(),
            "width": camera.width,
            "height": camera.height,
            "fov_y": camera.fov_y,
        }
    )


def png_text(camera: Camera, edits: str | dict, model: str, extra: dict[str, str] | None = None) -> dict[str, str]:
    """Text chunks: Software, camera (JSON), edits, model, extras. ``edits``: a whole edit file as YAML text (what
    ``particlesplat render --edits-from`` replays), or version 1 edits (particle index -> values) written as one."""
    if isinstance(edits, str):
        edits_text = edits
    else:
        edits_text = yaml.safe_dump(
            {int(i): {k: list(v) for k, v in a.items()} for i, a in edits.items()}, sort_keys=True
        )
    text = {
        "Software": "ParticleSplat Studio",
        "camera": camera_text(camera),
        "edits": edits_text,
        "model": model,
    }
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


def _png_chunks(path: str | PathLike) -> dict[str, str]:
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: PNG not found")
    try:
        with Image.open(path) as img:
            return dict(getattr(img, "text", {}) or {})
    except (OSError, ValueError) as e:  # Pillow: ValueError for a text chunk that inflates past its limit
        raise PngError(f"{path}: not a readable image ({one_line(e, 160)})") from None


def edits_text_from_png(path: str | PathLike) -> str:
    """The edit file a viewer screenshot or ``particlesplat render`` image carries (its ``edits`` text chunk, YAML).
    Errors name the file."""
    text = _png_chunks(path)
    if "edits" not in text:
        raise PngError(
            f"{path}: no 'edits' text chunk (only viewer screenshots and particlesplat render images carry one)"
        )
    return text["edits"]


def camera_from_png(path: str | PathLike) -> Camera:
    """The camera a viewer screenshot or ``particlesplat render`` image was taken with (its ``camera`` text
    chunk, :func:`camera_text`). Errors name the file and the field."""
    path = Path(path)
    text = _png_chunks(path)
    if "camera" not in text:
        raise PngError(
            f"{path}: no 'camera' text chunk (only viewer screenshots and particlesplat render images carry one)"
        )
    where = f"{path}: camera chunk: expected JSON with K, c2w_opencv, width, height"
    data = parse_json(text["camera"], where, PngError)  # the checked JSON reader: "(nested too deeply)"
    if not isinstance(data, dict):
        raise PngError(f"{where} (got a JSON {type(data).__name__})")
    try:
        K = np.asarray(data["K"], dtype=np.float64)
        c2w = np.asarray(data["c2w_opencv"], dtype=np.float64)
        width, height = int(data["width"]), int(data["height"])
    except (ValueError, KeyError, TypeError, OverflowError, RecursionError) as e:
        detail = "nested too deeply" if isinstance(e, RecursionError) else one_line(e, 120)
        raise PngError(f"{path}: camera chunk: expected JSON with K, c2w_opencv, width, height ({detail})") from None
    problem = camera_problem(K, c2w, width, height)
    if problem:
        raise PngError(f"{path}: camera chunk: {problem}")
    if not (1 <= width <= 16384 and 1 <= height <= 16384):
        raise PngError(f"{path}: camera chunk: width and height must be in [1, 16384], got {width}x{height}")
    return Camera(torch.from_numpy(K).float(), torch.from_numpy(c2w).float(), width, height)
