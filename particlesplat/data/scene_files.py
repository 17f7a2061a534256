"""Write a scene folder's files (the format of ``docs/dataset.md``): one writer for every scene generator."""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from PIL import Image

from particlesplat.core.camera import Camera

DEPTH_UNIT = 0.0002  # metres per 16-bit depth step: 0.2 mm resolution, 13.1 m range


def write_scene_files(
    folder: Path,
    cameras: Sequence[Camera],
    rgb: Sequence[np.ndarray] | np.ndarray,
    depth: Sequence[np.ndarray] | np.ndarray,
    masks: Sequence[np.ndarray] | np.ndarray,
    meta: dict,
) -> None:
    """Write views into the existing folder ``folder``: ``rgb/``, ``depth/``, ``masks/`` PNGs,
    ``transforms.json`` (the cameras; the intrinsics of the first) and ``scene.json`` (``meta``).

    rgb: V arrays (H, W, 3) uint8; depth: V arrays (H, W) planar metres (0 = nothing); masks: V arrays (H, W)
    uint8 instance ids (each may also be one array of the V stacked). Raises ValueError when a depth exceeds the
    16-bit range.
    """
    for sub in ("rgb", "depth", "masks"):
        (folder / sub).mkdir()
    frames = []
    for i, cam in enumerate(cameras):
        steps = np.round(np.asarray(depth[i], dtype=np.float64) / DEPTH_UNIT)
        if steps.max() > np.iinfo(np.uint16).max:
            raise ValueError(f"depth {float(np.max(depth[i])):.2f} m exceeds the 16-bit range at {DEPTH_UNIT} m/step")
        Image.fromarray(np.asarray(rgb[i], dtype=np.uint8), mode="RGB").save(folder / "rgb" / f"{i:03d}.png")
        Image.fromarray(steps.astype(np.uint16)).save(folder / "depth" / f"{i:03d}.png")
        Image.fromarray(np.asarray(masks[i], dtype=np.uint8), mode="L").save(folder / "masks" / f"{i:03d}.png")
        frames.append(
            {
                "file_path": f"rgb/{i:03d}.png",
                "depth_file_path": f"depth/{i:03d}.png",
                "instance_mask_path": f"masks/{i:03d}.png",
                "transform_matrix": cam.to_opengl_c2w().tolist(),
            }
        )
    K0 = cameras[0].K
    transforms = {
        "camera_model": "OPENCV",
        "w": cameras[0].width,
        "h": cameras[0].height,
        "fl_x": float(K0[0, 0]),
        "fl_y": float(K0[1, 1]),
        "cx": float(K0[0, 2]),
        "cy": float(K0[1, 2]),
        "depth_unit_scale_factor": DEPTH_UNIT,
        "frames": frames,
    }
    (folder / "transforms.json").write_text(json.dumps(transforms, indent=1))
    (folder / "scene.json").write_text(json.dumps(meta, indent=1))
