"""Read scene folders in the ``transforms.json`` format (described in docs/dataset.md) into tensors.

Reading is two steps: :func:`read_scene` decodes and validates the files into a compact
:class:`RawScene` (uint8 colour, float32 metres, native size), and :meth:`RawScene.select`
turns any subset of its frames into a :class:`Scene` of float tensors at any resolution.
:func:`load_scene` does both for all frames.
"""

from __future__ import annotations

import math
import os
import warnings
from dataclasses import dataclass
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from PIL import Image
from torch import Tensor

from particlesplat.core.camera import Camera
from particlesplat.core.errors import UserError, one_line, short_repr
from particlesplat.core.jsonfile import read_json
from particlesplat.core.viewpoints import View, default_view
from particlesplat.data.folders import TRANSFORMS
from particlesplat.data.scene_errors import SceneFormatError

_RIGID_TOL = 1e-3
# Largest image a scene may hold: 4096 x 4096 (decoded RGB 50 MB). Checked from the PNG header before decoding,
# so a decompression bomb (a few KB declaring 10^10 pixels) is refused without allocating it.
MAX_IMAGE_PIXELS = 4096 * 4096
MAX_TRANSFORMS_BYTES = 64 << 20  # transforms.json: ~100,000 frames


@dataclass
class Scene:
    """Decoded views of one scene.

    Attributes:
        rgb: (V, 3, H, W) float32 in [0, 1].
        depth: (V, 1, H, W) float32 planar camera-z metres, 0 = no depth; None if the scene has none.
        masks: (V, H, W) int64 instance ids, 0 = background; None if the scene has none.
        cameras: V cameras (OpenCV convention) matching the image size.
        path: the scene folder.
        frame_indices: (V,) positions of these views in the folder's frame list.
    """

    rgb: Tensor
    depth: Tensor | None
    masks: Tensor | None
    cameras: list[Camera]
    path: Path
    frame_indices: list[int]

    @property
    def num_views(self) -> int:
        return int(self.rgb.shape[0])

    def pose(self, model) -> Tensor | None:
        """What ``model`` (a :class:`~particlesplat.model.ParticleSplat`) reads of the robot from this scene's
        ``scene.json`` (its ``bg_static_pose``: the arm's joint angles, or the packed robot state), to pass to
        ``model.encode``; None for a model that reads nothing, or a scene that records nothing (with a warning)."""
        from particlesplat.data.scene_meta import scene_pose

        cfg = model.config
        return scene_pose(self.path, cfg.bg_static_pose, cfg.bg_static_pose_dims, model.input_ranges)

    def default_view(self) -> View:
        """The scene's default view (:func:`particlesplat.core.viewpoints.default_view`), as the viewer and
        ``particlesplat render`` open it: about where its cameras look (``scene.json``'s ``look_at``), at their
        distance (a tabletop's about 3.3 m, a robot table's about 1 m, backed off until the arm shows), from its
        middle camera's direction. ``view.camera(width, height)`` is its :class:`Camera`."""
        from particlesplat.data.scene_meta import read_framing

        return default_view(self.cameras, framing=read_framing(self.path))

    @property
    def height(self) -> int:
        return int(self.rgb.shape[2])

    @property
    def width(self) -> int:
        return int(self.rgb.shape[3])

    def K(self) -> Tensor:
        """(V, 3, 3) intrinsics."""
        return torch.stack([c.K for c in self.cameras])

    def c2w(self) -> Tensor:
        """(V, 4, 4) OpenCV camera-to-world."""
        return torch.stack([c.c2w for c in self.cameras])


@dataclass
class RawScene:
    """A validated scene folder, decoded at native size (kept compact for caching).

    Attributes:
        path: the scene folder.
        rgb: V arrays (H_i, W_i, 3) uint8.
        depth: V arrays (H_i, W_i) float32 metres (0 = none) or None per frame.
        masks: V arrays (H_i, W_i) of integer ids (uint8 as stored, to stay small) or None per frame.
        cameras: V cameras at the native size of each frame.
    """

    path: Path
    rgb: list[np.ndarray]
    depth: list[np.ndarray | None]
    masks: list[np.ndarray | None]
    cameras: list[Camera]

    @property
    def nbytes(self) -> int:
        """Bytes its decoded arrays hold (what a scene cache keeps)."""
        arrays = [*self.rgb, *self.depth, *self.masks]
        return sum(a.nbytes for a in arrays if a is not None)

    @property
    def num_frames(self) -> int:
        return len(self.rgb)

    @property
    def has_depth(self) -> bool:
        return any(d is not None for d in self.depth)

    @property
    def has_masks(self) -> bool:
        return all(m is not None for m in self.masks)

    def select(self, indices: list[int] | None = None, resolution: int | tuple[int, int] | None = None) -> Scene:
        """Views ``indices`` (default: all) as a :class:`Scene`, resized to ``resolution``.

        Args:
            resolution: None (native; all chosen frames must share a size), an int ``S``
                for ``S x S``, or ``(W, H)``. Colour is area-averaged when shrinking and
                antialiased-bilinear otherwise; depth and masks use nearest (pixel centres).
                Intrinsics scale with the image so pixel centres stay consistent.
        """
        idx = list(range(self.num_frames)) if indices is None else [int(i) for i in indices]
        if not idx:
            raise ValueError(f"{self.path}: no views selected")
        for i in idx:
            if not 0 <= i < self.num_frames:
                raise IndexError(f"{self.path}: view {i} out of range (scene has {self.num_frames} frames)")
        size = _target_size(self, idx, resolution)
        rgb = torch.stack([_resize_rgb(self.rgb[i], size) for i in idx])
        depth = None
        if self.has_depth:
            depth = torch.stack(
                [
                    torch.zeros(size[1], size[0])
                    if (d := self.depth[i]) is None
                    else _resize_nearest(d, size, torch.float32)
                    for i in idx
                ]
            )[:, None]
        masks = None
        if self.has_masks:  # every frame has one
            present = [m for m in (self.masks[i] for i in idx) if m is not None]
            masks = torch.stack([_resize_nearest(m, size, torch.int64) for m in present])
        cams = [self.cameras[i].resized(*size) for i in idx]  # new objects: the cache stays untouched
        return Scene(rgb, depth, masks, cams, self.path, idx)


def load_scene(path: str | PathLike, resolution: int | tuple[int, int] | None = None) -> Scene:
    """Load every view of a scene folder (or its ``transforms.json``).

    Args:
        path: the scene folder, or the path of its ``transforms.json``.
        resolution: None, an int ``S`` (``S x S``) or ``(W, H)``; see :meth:`RawScene.select`.

    Raises:
        FileNotFoundError / SceneFormatError naming the file and the key.
    """
    return read_scene(path).select(None, resolution)


# ---------------------------------------------------------------------------- resizing
def _target_size(raw: RawScene, idx: list[int], resolution: int | tuple[int, int] | None) -> tuple[int, int]:
    if resolution is None:
        sizes = {(raw.cameras[i].width, raw.cameras[i].height) for i in idx}
        if len(sizes) > 1:
            raise SceneFormatError(
                f"{raw.path / TRANSFORMS}: frames have different sizes {sorted(sizes)}; "
                "pass a resolution to resize them to one size"
            )
        return sizes.pop()
    if isinstance(resolution, int):
        resolution = (resolution, resolution)
    w, h = (int(v) for v in resolution)
    if w <= 0 or h <= 0:
        raise ValueError(f"resolution must be positive, got {resolution}")
    return w, h


def _resize_rgb(img: np.ndarray, size: tuple[int, int]) -> Tensor:
    """img: (H, W, 3) uint8 -> (3, H', W') float32 in [0, 1] at size (W', H')."""
    x = torch.from_numpy(img).permute(2, 0, 1).float().div_(255.0)
    w, h = size
    if (x.shape[2], x.shape[1]) == (w, h):
        return x
    if w <= x.shape[2] and h <= x.shape[1]:
        y = F.interpolate(x[None], size=(h, w), mode="area")
    else:
        y = F.interpolate(x[None], size=(h, w), mode="bilinear", align_corners=False, antialias=True)
    return y[0].clamp_(0.0, 1.0)


def _resize_nearest(img: np.ndarray, size: tuple[int, int], dtype: torch.dtype) -> Tensor:
    """img: (H, W) -> (H', W') ``dtype`` by nearest pixel centre."""
    x = torch.from_numpy(np.ascontiguousarray(img))
    w, h = size
    if (x.shape[1], x.shape[0]) == (w, h):
        return x.to(dtype)
    y = F.interpolate(x[None, None].double(), size=(h, w), mode="nearest-exact")[0, 0]
    return y.to(dtype)


# ---------------------------------------------------------------------------- reading
def read_scene(path: str | PathLike) -> RawScene:
    """Read and validate a scene folder (or its ``transforms.json``) at native size."""
    path = Path(path)
    if path.name == TRANSFORMS and path.is_file():
        path = path.parent
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such scene folder")
    tf_path = path / TRANSFORMS
    if not tf_path.is_file():
        raise FileNotFoundError(f"{tf_path}: no {TRANSFORMS} in the scene folder")
    meta = read_json(tf_path, MAX_TRANSFORMS_BYTES, SceneFormatError)
    if not isinstance(meta, dict):
        raise SceneFormatError(f"{tf_path}: the top level must be an object")
    frames = meta.get("frames")
    if frames is None:
        raise SceneFormatError(f"{tf_path}: missing key 'frames'")
    if not isinstance(frames, list) or not frames:
        raise SceneFormatError(f"{tf_path}: key 'frames' must be a non-empty list")
    for i, frame in enumerate(frames):
        if not isinstance(frame, dict):
            raise SceneFormatError(f"{tf_path}: frames[{i}] must be an object")
    _check_scene_memory(path, tf_path, meta, frames)
    rgb, depth, masks, cams = [], [], [], []
    for i, frame in enumerate(frames):
        where = f"{tf_path}: frames[{i}]"
        image = _read_rgb(path, frame, where)
        cam = _frame_camera(meta, frame, image.shape[1], image.shape[0], where)
        rgb.append(image)
        depth.append(_read_depth(path, meta, frame, (cam.width, cam.height), where))
        masks.append(_read_mask(path, frame, (cam.width, cam.height), where))
        cams.append(cam)
    _warn_implausible(tf_path, cams, depth)
    have = [m is not None for m in masks]
    if any(have) and not all(have):
        raise SceneFormatError(
            f"{tf_path}: frames[{have.index(False)}] has no 'instance_mask_path' but other frames have one"
        )
    return RawScene(path, rgb, depth, masks, cams)


# bytes a decoded frame holds per pixel while it is read: RGB (3 uint8) and its float copy while resizing, depth
# (float64 while scaled, float32 kept), a mask
BYTES_PER_PIXEL = 3 + 12 + 8 + 4 + 8
# beyond these a scene is legal but probably wrong (a depth in millimetres read as metres, a focal length in
# metres, a principal point far outside the image): a warning names the file and the field
PLAUSIBLE_DEPTH_M = (1e-3, 200.0)  # median depth of a frame's valid pixels
PLAUSIBLE_FOCAL = (0.05, 100.0)  # focal length / image width


def _check_scene_memory(folder: Path, tf_path: Path, meta: dict, frames: list) -> None:
    """Refuse a scene whose frames would not fit the memory limit, from the image headers, before any decoding
    (200 frames naming one 4096 x 4096 image are 200 decoded images)."""
    from particlesplat.core.limits import check_memory

    total = 0
    sizes: dict[Path, int] = {}
    for i, frame in enumerate(frames):
        rel = frame.get("file_path")
        if not isinstance(rel, str) or not rel:
            continue  # reported with its frame when it is read
        try:
            p = _resolve(folder, rel, "file_path", f"{tf_path}: frames[{i}]")
        except (OSError, UserError):
            continue
        if p not in sizes:
            try:
                with Image.open(p) as img:
                    sizes[p] = img.size[0] * img.size[1]
            except (OSError, Image.DecompressionBombError, ValueError):
                sizes[p] = 0  # reported with its frame when it is read
        total += sizes[p]
    check_memory(
        total * BYTES_PER_PIXEL, f"{tf_path}: {len(frames)} frames of {total / max(len(frames), 1):,.0f} pixels each"
    )


def _warn_implausible(tf_path: Path, cams: list[Camera], depth: list[np.ndarray | None]) -> None:
    """Warn (once per field) about a legal scene whose numbers are probably wrong."""
    from particlesplat.core.errors import warn_input

    lo, hi = PLAUSIBLE_FOCAL
    for i, cam in enumerate(cams):
        fx, fy = float(cam.K[0, 0]), float(cam.K[1, 1])
        if not (lo * cam.width <= fx <= hi * cam.width and lo * cam.height <= fy <= hi * cam.height):
            warn_input(
                f"{tf_path}: frames[{i}]: 'fl_x'/'fl_y' {fx:.4g}/{fy:.4g} pixels for a {cam.width}x{cam.height} "
                f"image (a field of view of {cam.fov_y:.3g} degrees); is the focal length in pixels?"
            )
            break
    for i, cam in enumerate(cams):
        cx, cy = float(cam.K[0, 2]), float(cam.K[1, 2])
        if not (-cam.width <= cx <= 2 * cam.width and -cam.height <= cy <= 2 * cam.height):
            warn_input(
                f"{tf_path}: frames[{i}]: 'cx'/'cy' {cx:.4g}/{cy:.4g} lie far outside the {cam.width}x{cam.height} "
                "image; the scene will be off screen"
            )
            break
    for i, d in enumerate(depth):
        if d is None or not (d > 0).any():
            continue
        median = float(np.median(d[d > 0]))
        if not PLAUSIBLE_DEPTH_M[0] <= median <= PLAUSIBLE_DEPTH_M[1]:
            warn_input(
                f"{tf_path}: frames[{i}]: 'depth_unit_scale_factor' makes the median depth {median:.4g} m; "
                "is it the size of one depth unit in metres (0.001 for millimetres)?"
            )
            break


def _get(meta: dict, frame: dict, key: str) -> Any:
    """A frame's own value for ``key``, else the top-level one, else None."""
    return frame[key] if key in frame else meta.get(key)


def _number(value: Any, key: str, where: str, positive: bool = False) -> float:
    """A number, finite and usable in float32 (:func:`particlesplat.core.limits.float32_problem`)."""
    from particlesplat.core.limits import float32_problem

    try:
        x = float(value)
    except (TypeError, ValueError, OverflowError):
        raise SceneFormatError(f"{where}: key '{key}' must be a number, got {short_repr(value)}") from None
    if not math.isfinite(x) or (positive and x <= 0):
        raise SceneFormatError(
            f"{where}: key '{key}' must be a finite{' positive' if positive else ''} number, got {short_repr(value)}"
        )
    problem = float32_problem(x, positive)
    if problem:
        raise SceneFormatError(f"{where}: key '{key}' is {problem}, got {short_repr(value)}")
    return x


def _frame_camera(meta: dict, frame: dict, img_w: int, img_h: int, where: str) -> Camera:
    """The frame's camera; ``w``/``h`` default to the image size and must agree with it."""
    w = img_w if _get(meta, frame, "w") is None else _number(_get(meta, frame, "w"), "w", where, True)
    h = img_h if _get(meta, frame, "h") is None else _number(_get(meta, frame, "h"), "h", where, True)
    if (w, h) != (img_w, img_h):
        raise SceneFormatError(
            f"{where}: image '{frame['file_path']}' is {img_w}x{img_h} but keys 'w', 'h' say {w:g}x{h:g}"
        )
    fl_x, fl_y = _get(meta, frame, "fl_x"), _get(meta, frame, "fl_y")
    angle_x, angle_y = _get(meta, frame, "camera_angle_x"), _get(meta, frame, "camera_angle_y")
    if fl_x is None and angle_x is not None:  # NeRF "blender" style
        fl_x = 0.5 * w / math.tan(0.5 * _number(angle_x, "camera_angle_x", where, True))
        if fl_y is None:
            fl_y = (
                fl_x if angle_y is None else 0.5 * h / math.tan(0.5 * _number(angle_y, "camera_angle_y", where, True))
            )
    if fl_x is None:
        raise SceneFormatError(f"{where}: missing key 'fl_x' (or 'camera_angle_x')")
    if fl_y is None:
        raise SceneFormatError(f"{where}: missing key 'fl_y'")
    fx, fy = _number(fl_x, "fl_x", where, True), _number(fl_y, "fl_y", where, True)
    cx = w / 2 if _get(meta, frame, "cx") is None else _number(_get(meta, frame, "cx"), "cx", where)
    cy = h / 2 if _get(meta, frame, "cy") is None else _number(_get(meta, frame, "cy"), "cy", where)
    K = torch.tensor([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]], dtype=torch.float32)
    c2w_gl = _rigid_matrix(frame.get("transform_matrix"), where)
    return Camera.from_opengl_c2w(torch.from_numpy(c2w_gl).float(), K, int(w), int(h))


def _rigid_matrix(value: Any, where: str) -> np.ndarray:
    """A (4, 4) float64 rigid transform from a 4x4 (or 3x4) nested list."""
    key = "transform_matrix"
    if value is None:
        raise SceneFormatError(f"{where}: missing key '{key}'")
    try:
        m = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise SceneFormatError(f"{where}: key '{key}' must be a 4x4 list of numbers") from None
    if m.shape == (3, 4):
        m = np.concatenate([m, [[0.0, 0.0, 0.0, 1.0]]])
    from particlesplat.core.limits import WORLD_MAX_METRES, rigid_problem

    problem = rigid_problem(m, _RIGID_TOL, max_metres=None)  # the check every pose gets (the robot's base too)
    if problem:
        raise SceneFormatError(f"{where}: key '{key}' {problem}")
    if np.abs(m[:3, 3]).max() > WORLD_MAX_METRES:
        raise SceneFormatError(
            f"{where}: key '{key}' puts the camera {np.abs(m[:3, 3]).max():.3g} m from the origin, beyond the "
            f"{WORLD_MAX_METRES:g} m where float32 keeps millimetres; translate the scene near the origin"
        )
    return m


def _resolve(folder: Path, rel: Any, key: str, where: str) -> Path:
    """The file ``rel`` names, relative to the scene folder and inside it (no absolute path, no ``..`` out)."""
    if not isinstance(rel, str) or not rel:
        raise SceneFormatError(f"{where}: key '{key}' must be a file path, got {short_repr(rel)}")
    if len(rel) > 4096:  # PATH_MAX: the OS would echo it whole in its error
        raise SceneFormatError(f"{where}: key '{key}' is a path of {len(rel)} characters ({short_repr(rel)})")
    norm = os.path.normpath(rel)
    if os.path.isabs(rel) or norm == ".." or norm.startswith(".." + os.sep) or "\0" in rel:
        raise SceneFormatError(
            f"{where}: key '{key}' names {short_repr(rel)}, outside the scene folder "
            "(paths must be relative and stay inside it)"
        )
    p = folder / rel
    if not p.is_file() and not p.suffix and p.with_suffix(".png").is_file():  # NeRF "blender" paths
        p = p.with_suffix(".png")
    if not p.is_file():
        what = "a folder, not an image file" if p.is_dir() else "which does not exist"
        raise FileNotFoundError(f"{where}: key '{key}' names {p}, {what}")
    real, inside = os.path.realpath(p), os.path.realpath(folder)
    if os.path.commonpath([real, inside]) != inside:  # a symbolic link inside the folder pointing out of it
        raise SceneFormatError(
            f"{where}: key '{key}' names {short_repr(rel)}, a link to {short_repr(real)} outside the scene folder "
            "(files must stay inside it)"
        )
    return p


def _open(p: Path, key: str, where: str) -> Image.Image:
    """Decode image ``p``; its size is checked against :data:`MAX_IMAGE_PIXELS` from the header first."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            img = Image.open(p)
            w, h = img.size
            if w * h > MAX_IMAGE_PIXELS:
                raise SceneFormatError(
                    f"{where}: key '{key}': image {p} is {w}x{h} pixels, more than the "
                    f"{MAX_IMAGE_PIXELS} an image may have (a decompression bomb?)"
                )
            img.load()
    except (Image.DecompressionBombError, Image.DecompressionBombWarning):
        raise SceneFormatError(
            f"{where}: key '{key}': image {p} declares more pixels than the "
            f"{MAX_IMAGE_PIXELS} an image may have (a decompression bomb?)"
        ) from None
    except (OSError, ValueError) as e:  # Pillow: ValueError for a text chunk that inflates past its limit
        if isinstance(e, SceneFormatError):
            raise
        raise SceneFormatError(f"{where}: key '{key}': cannot read image {p} ({one_line(e, 200)})") from None
    return img


def _read_rgb(folder: Path, frame: dict, where: str) -> np.ndarray:
    """(H, W, 3) uint8. Alpha, if any, is dropped; 16-bit images are scaled to 8 bits."""
    if "file_path" not in frame:
        raise SceneFormatError(f"{where}: missing key 'file_path'")
    img = _open(_resolve(folder, frame["file_path"], "file_path", where), "file_path", where)
    if img.mode in ("I;16", "I;16B", "I"):
        a = np.asarray(img).astype(np.float64) / 65535.0 * 255.0
        img = Image.fromarray(np.round(a).astype(np.uint8))
    return np.array(img.convert("RGB"))


def _check_size(arr: np.ndarray, size: tuple[int, int], key: str, p: Path, where: str) -> None:
    """arr: (H, W) image of file ``p``; SceneFormatError unless (W, H) == ``size``."""
    if (arr.shape[1], arr.shape[0]) != size:
        raise SceneFormatError(
            f"{where}: key '{key}': {p} is {arr.shape[1]}x{arr.shape[0]} but the frame is {size[0]}x{size[1]}"
        )


def _read_depth(folder: Path, meta: dict, frame: dict, size: tuple[int, int], where: str) -> np.ndarray | None:
    """(H, W) float32 metres or None. Integer images need ``depth_unit_scale_factor``."""
    key = "depth_file_path"
    if frame.get(key) is None:
        return None
    p = _resolve(folder, frame[key], key, where)
    scale_value = _get(meta, frame, "depth_unit_scale_factor")
    if scale_value is None:
        raise SceneFormatError(f"{where}: has '{key}' but no key 'depth_unit_scale_factor' (metres per unit)")
    scale = _number(scale_value, "depth_unit_scale_factor", where, True)
    img = _open(p, key, where)
    if img.mode in ("L", "P", "1"):
        raise SceneFormatError(
            f"{where}: key '{key}': {p} is an 8-bit image; depth must be 16-bit (or float) "
            "in units of depth_unit_scale_factor (8 bits would read as 16-bit units)"
        )
    if img.mode not in ("I;16", "I;16B", "I", "F"):
        raise SceneFormatError(f"{where}: key '{key}': {p} must be a single-channel image, got mode {img.mode}")
    arr = np.asarray(img).astype(np.float64) * scale
    _check_size(arr, size, key, p, where)
    if not np.isfinite(arr).all() or (arr < 0).any():
        raise SceneFormatError(f"{where}: key '{key}': {p} has negative or non-finite depth")
    from particlesplat.core.limits import WORLD_MAX_METRES

    if arr.size and float(arr.max()) > WORLD_MAX_METRES:
        raise SceneFormatError(
            f"{where}: key '{key}': {p} has depths up to {float(arr.max()):.3g} m (with depth_unit_scale_factor "
            f"{scale:g}), beyond the {WORLD_MAX_METRES:g} m a depth may hold"
        )
    return arr.astype(np.float32)


def _read_mask(folder: Path, frame: dict, size: tuple[int, int], where: str) -> np.ndarray | None:
    """(H, W) integer instance ids (the stored dtype) or None."""
    key = "instance_mask_path"
    if frame.get(key) is None:
        return None
    p = _resolve(folder, frame[key], key, where)
    img = _open(p, key, where)
    if img.mode not in ("L", "P", "I;16", "I;16B", "I"):
        raise SceneFormatError(f"{where}: key '{key}': {p} must be a single-channel image, got mode {img.mode}")
    arr = np.array(img)
    _check_size(arr, size, key, p, where)
    if arr.dtype.kind == "i" and arr.size and int(arr.min()) < 0:
        raise SceneFormatError(
            f"{where}: key '{key}': {p} has negative instance ids (min {int(arr.min())}); ids are 0 (background) "
            "or positive"
        )
    return arr
