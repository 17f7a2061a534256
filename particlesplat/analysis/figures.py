"""Figures of the decomposition: a scene rendered as one of its layers, and turntables.

Modes (``particlesplat render --mode``):

- ``rgb``: the scene; ``depth``: expected planar depth, near bright, far dark (2nd-98th percentile of the
  covered pixels), black where nothing draws;
- ``particles`` / ``objects``: the per-pixel argmax over particles / objects (colour per index, the
  background dark grey);
- ``foreground`` / ``background``: only the particles' / only the background's Gaussians over the background
  colour;
- ``keypoints``: the scene dimmed, with each drawing particle's ``anchor`` (z_p at depth d) as a dot and its
  ``centroid`` as a ring, coloured by object; ``boxes``: the scene dimmed, with each drawing particle's 3D box
  ``centroid`` +- 2 ``extent`` (world axes) projected as 12 edges, coloured by object.

The overlays come from :class:`particlesplat.analysis.particle_arrays.ParticleArrays`, projected into the view.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from os import PathLike
from pathlib import Path
from typing import Literal

import numpy as np
import torch
from PIL import Image, ImageDraw

from particlesplat.analysis.particle_arrays import ParticleArrays
from particlesplat.core import palette
from particlesplat.core.atomic import atomic_path
from particlesplat.core.camera import Camera
from particlesplat.core.choices import MODES, NEEDS_PARTICLES, RenderMode
from particlesplat.core.errors import OptionError
from particlesplat.core.gaussians import Gaussians
from particlesplat.core.viewpoints import Backdrop, Look, View, backdrop_for
from particlesplat.rendering.api import render

DIM = 0.55  # the scene's brightness under the keypoint and box overlays
BOX_SIGMAS = 2.0  # a particle's box reaches this many standard deviations (extent) from its centroid
ANIMATIONS = (".gif", ".webp")
FRAME_MS = 80  # per turntable frame


def depth_span(depth: np.ndarray, alpha: np.ndarray) -> tuple[float, float] | None:
    """The planar depths (metres) the grey of :func:`depth_image` spans: the 2nd and 98th percentiles of the covered
    pixels (accumulated opacity > 0.5); None when nothing is covered."""
    covered = alpha > 0.5
    if not covered.any():
        return None
    lo, hi = np.percentile(depth[covered], [2.0, 98.0])
    return float(lo), float(hi)


def depth_grey(depth: np.ndarray, span: tuple[float, float]) -> np.ndarray:
    """Planar metres -> grey in [0.15, 1]: 1 at ``span[0]`` (near) to 0.15 at ``span[1]`` (far), clipped."""
    lo, hi = span
    return 0.15 + 0.85 * np.clip((hi - depth) / max(hi - lo, 1e-6), 0.0, 1.0)


def depth_image(depth: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """(H, W) planar metres and accumulated opacity -> (H, W, 3) grey: near bright, far dark, nothing black."""
    span = depth_span(depth, alpha)
    if span is None:
        return np.zeros(depth.shape + (3,))
    grey = np.where(alpha > 0.5, depth_grey(depth, span), 0.0)  # the depth alone: a semi-transparent floor is no darker
    return np.repeat(grey[..., None], 3, axis=-1)


BAR_GAP, BAR_WIDTH, BAR_LABELS = 6, 12, 56  # pixels: before the colour bar, the bar, its labels


def with_depth_bar(image: np.ndarray, span: tuple[float, float] | None) -> np.ndarray:
    """``image`` (H, W, 3) in [0, 1] with a colour bar on its right (H, W + 74, 3): the greys of
    :func:`depth_grey` from ``span[0]`` (top, near) to ``span[1]`` (bottom, far), row r at depth
    ``lo + (hi - lo) * r / (H - 1)``, labelled in metres at the top, middle and bottom. No span (nothing
    covered): the bar is black and labelled "no depth"."""
    H, W = image.shape[:2]
    out = np.zeros((H, W + BAR_GAP + BAR_WIDTH + BAR_LABELS, 3))
    out[:, :W] = image
    x0 = W + BAR_GAP
    if span is not None:
        rows = span[0] + (span[1] - span[0]) * np.arange(H) / max(H - 1, 1)
        out[:, x0 : x0 + BAR_WIDTH] = depth_grey(rows, span)[:, None, None]
    canvas = Image.fromarray((np.clip(out, 0.0, 1.0) * 255.0).round().astype(np.uint8))
    draw = ImageDraw.Draw(canvas)
    tx = x0 + BAR_WIDTH + 3
    if span is None:
        draw.text((tx, 0), "no depth", fill=(255, 255, 255))
    else:
        ticks = (0, H // 2, H - 1) if H >= 48 else (0, H - 1)
        for r in ticks:
            z = span[0] + (span[1] - span[0]) * r / max(H - 1, 1)
            y = min(max(r - 5, 0), max(H - 11, 0))
            draw.line([(x0 + BAR_WIDTH, r), (tx - 1, r)], fill=(255, 255, 255))
            draw.text((tx, y), f"{z:.2f} m", fill=(255, 255, 255))
    return np.asarray(canvas, dtype=np.float64) / 255.0


def _object_labels(arrays: ParticleArrays) -> torch.Tensor:
    """(P,) object index per particle for the segmentation (inactive particles draw nothing: label 0)."""
    return torch.as_tensor(np.maximum(arrays.object, 0), dtype=torch.int64)


def _project(camera: Camera, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    uv, z = camera.project(torch.as_tensor(points, dtype=torch.float64))
    return uv.numpy(), z.numpy()


@dataclass(frozen=True)
class Mark:
    """One overlay mark in image pixels: a filled ``dot`` or a ``ring`` at ``points[0]`` with ``radius``, or a
    ``line`` from ``points[0]`` to ``points[1]``; ``colour`` RGB in [0, 1]; ``width`` of outlines in pixels."""

    kind: Literal["dot", "ring", "line"]
    points: tuple[tuple[float, float], ...]
    colour: tuple[float, float, float]
    radius: float = 0.0
    width: float = 1.0


def overlay_marks(arrays: ParticleArrays, camera: Camera, mode: Literal["keypoints", "boxes"]) -> list[Mark]:
    """The marks of ``mode`` for the drawing particles seen by ``camera`` (pixels of its image), coloured by
    object: keypoints = a dot at each ``anchor`` and a ring at each ``centroid``; boxes = the 12 edges of
    ``centroid`` +- ``BOX_SIGMAS`` x ``extent``. Points behind the camera are left out (and edges touching
    them). Mark sizes grow with the image (one unit per 160 pixels of its smaller side)."""
    scale = max(1.0, min(camera.width, camera.height) / 160.0)
    cam = camera.to("cpu", torch.float64)
    marks: list[Mark] = []
    for i in np.flatnonzero(arrays.active):
        colour = palette.colour(int(arrays.object[i]))
        if mode == "keypoints":
            uv, z = _project(cam, np.stack([arrays.anchor[i], arrays.centroid[i]]))
            if z[0] > 0:
                marks.append(
                    Mark("dot", ((float(uv[0, 0]), float(uv[0, 1])),), colour, 2.5 * scale, max(1.0, scale / 2))
                )
            if z[1] > 0:
                marks.append(Mark("ring", ((float(uv[1, 0]), float(uv[1, 1])),), colour, 4.0 * scale, max(1.0, scale)))
        else:
            c, e = arrays.centroid[i].astype(np.float64), BOX_SIGMAS * arrays.extent[i].astype(np.float64)
            corners = np.array(
                [
                    [c[0] + sx * e[0], c[1] + sy * e[1], c[2] + sz * e[2]]
                    for sx in (-1, 1)
                    for sy in (-1, 1)
                    for sz in (-1, 1)
                ]
            )
            uv, z = _project(cam, corners)
            for a in range(8):
                for b in range(a + 1, 8):
                    if (a ^ b).bit_count() == 1 and z[a] > 0 and z[b] > 0:  # corners one axis apart: an edge
                        marks.append(
                            Mark(
                                "line",
                                ((float(uv[a, 0]), float(uv[a, 1])), (float(uv[b, 0]), float(uv[b, 1]))),
                                colour,
                                0.0,
                                max(1.0, scale),
                            )
                        )
    return marks


def _overlay(
    base: np.ndarray, camera: Camera, arrays: ParticleArrays, mode: Literal["keypoints", "boxes"]
) -> np.ndarray:
    img = Image.fromarray((np.clip(base * DIM, 0, 1) * 255 + 0.5).astype(np.uint8), "RGB")
    draw = ImageDraw.Draw(img)
    for m in overlay_marks(arrays, camera, mode):
        colour = tuple(int(255 * c) for c in m.colour)
        (u, v), r, w = m.points[0], m.radius, int(m.width)
        if m.kind == "dot":
            draw.ellipse([u - r, v - r, u + r, v + r], fill=colour, outline=(0, 0, 0), width=w)
        elif m.kind == "ring":
            draw.ellipse([u - r, v - r, u + r, v + r], outline=colour, width=w)
        else:
            draw.line([m.points[0], m.points[1]], fill=colour, width=w)
    return np.asarray(img).astype(np.float64) / 255.0


@torch.no_grad()
def render_mode(
    gaussians: Gaussians,
    camera: Camera,
    mode: RenderMode,
    *,
    background: Backdrop = (0.0, 0.0, 0.0),
    arrays: ParticleArrays | None = None,
    colour_bar: bool = False,
) -> np.ndarray:
    """One view of ``gaussians`` (the decoded scene, owner = particle index) as ``mode`` -> (H, W, 3) in [0, 1].

    ``background``: a colour, or a function of the camera giving (H, W, 3)
    (:func:`~particlesplat.core.viewpoints.scene_backdrop`).
    ``arrays``: the scene's particle arrays, needed by every mode but rgb and depth (ValueError without).
    ``colour_bar``: depth gets its colour bar in metres on the right (:func:`with_depth_bar`: wider by 74 px).
    """
    if mode not in MODES:
        raise OptionError(f"--mode must be one of {', '.join(MODES)}, got {mode!r}")
    if mode in NEEDS_PARTICLES and arrays is None:
        raise OptionError(f"--mode {mode} needs a model scene (particles), not a .ply")
    g = gaussians.detach().to("cpu")
    if mode == "foreground":
        g = g.subset(g.owner >= 0)
    elif mode == "background":
        g = g.subset(g.owner < 0)
    segment = mode in ("particles", "objects")
    P = arrays.num_particles if arrays is not None else None
    back = backdrop_for(background, camera)
    r = render(g, camera, background=back, owner_weights=segment, num_owners=P if segment else None)
    if mode in ("rgb", "foreground", "background"):
        return r.rgb.numpy().astype(np.float64)
    if mode == "depth":
        depth, alpha = r.depth.numpy(), r.alpha.numpy()
        image = depth_image(depth, alpha)
        return with_depth_bar(image, depth_span(depth, alpha)) if colour_bar else image
    assert arrays is not None  # every other mode needs the particles (checked above)
    if segment:
        labels = r.segmentation(_object_labels(arrays) if mode == "objects" else None).numpy()
        return palette.colour_map(labels)
    return _overlay(r.rgb.numpy().astype(np.float64), camera, arrays, "keypoints" if mode == "keypoints" else "boxes")


def turntable_cameras(view: View, frames: int, width: int, height: int) -> list[Camera]:
    """``frames`` cameras orbiting ``view``'s target once (azimuth += 360 / frames each; elevation, distance
    and field of view kept), starting at ``view``."""
    if frames < 1:
        raise OptionError(f"--turntable must be >= 1 frames, got {frames}")
    return [
        View(
            view.target, Look(view.look.azimuth + 360.0 * i / frames, view.look.elevation, view.look.distance), view.fov
        ).camera(width, height)
        for i in range(frames)
    ]


def turntable_paths(out: str | PathLike, frames: int) -> tuple[list[Path], Path]:
    """Where a turntable goes: frames ``<stem>_NNN.png`` beside ``out``, and the animation at ``out`` when it
    ends in .gif or .webp, else ``<stem>.gif``."""
    out = Path(out)
    stem = out.with_suffix("") if out.suffix.lower() in (*ANIMATIONS, ".png") else out
    digits = max(3, len(str(frames - 1)))
    anim = out if out.suffix.lower() in ANIMATIONS else stem.with_suffix(".gif")
    return [stem.parent / f"{stem.name}_{i:0{digits}d}.png" for i in range(frames)], anim


def save_animation(frames: Sequence[np.ndarray | Path], path: str | PathLike, frame_ms: int = FRAME_MS) -> Path:
    """Write frames as a looping animated GIF or WebP (by suffix), atomically. A frame is an (H, W, 3) array in
    [0, 1] or the path of a PNG, read when the writer gets to it (a turntable streams its frames from disk)."""
    path = Path(path)
    fmt = {".gif": "GIF", ".webp": "WEBP"}.get(path.suffix.lower())
    if fmt is None:
        raise OptionError(f"{path}: an animation must end in .gif or .webp")

    def image(f: np.ndarray | Path) -> Image.Image:
        if isinstance(f, (str, Path)):
            with Image.open(f) as img:
                return img.convert("RGB")
        return Image.fromarray((np.clip(f, 0, 1) * 255 + 0.5).astype(np.uint8), "RGB")

    extra = {"lossless": True} if fmt == "WEBP" else {"optimize": False}
    rest = (image(f) for f in frames[1:])
    with atomic_path(path) as tmp:
        image(frames[0]).save(tmp, format=fmt, save_all=True, append_images=rest, duration=frame_ms, loop=0, **extra)
    return path


def turntable_memory(frames: int, width: int, height: int) -> float:
    """Estimated peak bytes of a turntable: one frame rendered (~80 bytes a pixel: the renderer's ~20 floats) and
    every frame held by the animation writer (a GIF keeps each as 1 byte a pixel; frames themselves are
    written to disk as they are rendered)."""
    return width * height * (80.0 + frames)


def check_turntable_targets(out: str | PathLike, frames: int) -> None:
    """OptionError naming the first turntable frame path (:func:`turntable_paths`) that exists and is not an
    image this program rendered (its ``Software`` chunk): a turntable never replaces another file."""
    for p in turntable_paths(out, frames)[0]:
        if not os.path.lexists(p):
            continue
        try:
            with Image.open(p) as img:
                ours = (getattr(img, "text", {}) or {}).get("Software") == "ParticleSplat Studio"
        except (OSError, ValueError):
            ours = False
        if not ours:
            raise OptionError(
                f"--turntable: {p} exists and is not a frame rendered by particlesplat; refusing to replace it "
                "(move it, or choose another --out)"
            )


def write_turntable(
    gaussians: Gaussians,
    view: View,
    frames: int,
    width: int,
    height: int,
    out: str | PathLike,
    mode: RenderMode = "rgb",
    *,
    background: Backdrop = (0.0, 0.0, 0.0),
    arrays: ParticleArrays | None = None,
    save_frame: Callable[[Path, np.ndarray, Camera], object] | None = None,
    progress: bool = False,
) -> tuple[list[Path], Path]:
    """Render a turntable of ``frames`` views (:func:`turntable_cameras`) in ``mode``; write each frame as a
    PNG (``save_frame(path, rgb, camera)``, default a plain PNG) and the animation (:func:`turntable_paths`).
    Returns (frame paths, animation path)."""
    from tqdm import tqdm

    from particlesplat.formats.png import save_png

    paths, anim = turntable_paths(out, frames)
    for path, cam in tqdm(
        list(zip(paths, turntable_cameras(view, frames, width, height), strict=False)),
        desc="turntable",
        unit="frame",
        disable=not progress,
    ):
        rgb = render_mode(gaussians, cam, mode, background=background, arrays=arrays)
        (save_frame or (lambda p, x, c: save_png(p, x)))(path, rgb, cam)
        del rgb  # streamed: the animation reads the frames back from disk
    save_animation(paths, anim, FRAME_MS if frames > 1 else 1000)
    return paths, anim
