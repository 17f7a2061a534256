"""The default view and the ``--look AZ,EL,DIST`` / ``--fov DEG`` camera semantics shared by the
viewer and ``particlesplat render``.

A view is an orbit about a target point in a +z-up world (see :meth:`Camera.orbit_eye`):
azimuth 0 looks along +y, positive azimuth turns counter-clockwise seen from above, elevation
is the angle above the horizontal plane through the target, distance is in metres. ``fov`` is
the vertical field of view in degrees.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import torch
from torch import Tensor

from particlesplat.core.camera import Camera
from particlesplat.core.errors import OptionError
from particlesplat.core.gaussians import Gaussians
from particlesplat.core.limits import float32_problem
from particlesplat.core.vectors import float3

DEFAULT_FOV = 40.0  # degrees, vertical
DEFAULT_ELEVATION = 25.0  # degrees, for scenes without cameras
FALLBACK_DISTANCE = 3.0  # metres: the view distance when neither cameras nor Gaussians tell the scene's scale
DEFAULT_BACKGROUND = (0.12, 0.14, 0.18)  # the viewer's and ``particlesplat render``'s background colour


def scene_background(model=None, particles=None) -> tuple[float, float, float]:
    """The colour behind a scene: the colour its ``particles`` read from their context views or else the model's
    learned background colour (``ParticleSplat.backdrop``), else :data:`DEFAULT_BACKGROUND` (for a .ply,
    ``model`` None)."""
    if model is not None:
        return float3(model.backdrop(particles).detach().cpu())
    return DEFAULT_BACKGROUND


Backdrop = Sequence[float] | Callable[[Camera], Tensor]
"""What a render of a scene composites over: one colour, or a function of the camera giving (H, W, 3) RGB."""


def scene_backdrop(model=None, particles=None) -> Backdrop:
    """What is behind a scene in any camera: where its ``particles`` carry a support map
    (``background.support_map``), a function of the camera giving (H, W, 3) RGB on the CPU
    (``ParticleSplat.backdrop_image``), else :func:`scene_background`'s colour."""
    if model is None or particles is None or particles.support_map is None:
        return scene_background(model, particles)
    return lambda camera: model.backdrop_image(particles, camera).detach().cpu()


def backdrop_for(backdrop: Backdrop, camera: Camera) -> Sequence[float] | Tensor:
    """What ``backdrop`` puts behind ``camera``'s render: its colour, or its (H, W, 3) image for that camera."""
    return backdrop(camera) if callable(backdrop) else backdrop


@dataclass(frozen=True)
class Look:
    """Orbit parameters: azimuth and elevation in degrees, distance in metres."""

    azimuth: float
    elevation: float
    distance: float


@dataclass(frozen=True)
class View:
    """A full orbit view: target (x, y, z) metres, look, vertical fov in degrees."""

    target: tuple[float, float, float]
    look: Look
    fov: float

    def camera(self, width: int, height: int) -> Camera:
        """The camera of this view at ``width`` x ``height`` pixels."""
        return Camera.orbit(
            self.target,
            self.look.azimuth,
            self.look.elevation,
            self.look.distance,
            fov_y_deg=self.fov,
            width=width,
            height=height,
        )


def parse_look(text: str) -> Look:
    """``"AZ,EL,DIST"`` (degrees, degrees, metres) -> :class:`Look`; ValueError names the field."""
    parts = [p.strip() for p in str(text).split(",")]
    if len(parts) != 3:
        raise OptionError(f"--look: expected AZ,EL,DIST (three comma-separated numbers), got {text!r}")
    try:
        az, el, dist = (float(p) for p in parts)
    except ValueError as e:
        raise OptionError(f"--look: expected numbers AZ,EL,DIST, got {text!r}") from e
    if not all(math.isfinite(v) for v in (az, el, dist)):
        raise OptionError(f"--look: values must be finite, got {text!r}")
    if not -90.0 < el < 90.0:
        raise OptionError(f"--look: elevation must be in (-90, 90) degrees, got {el}")
    if dist <= 0:
        raise OptionError(f"--look: distance must be positive, got {dist}")
    for name, v in (("azimuth", az), ("distance", dist)):
        problem = float32_problem(v, positive=name == "distance")
        if problem:
            raise OptionError(f"--look: {name} is {problem}, got {v:g}")
    return Look(az, el, dist)


def check_fov(fov: float) -> float:
    """Validate a vertical field of view in degrees."""
    if not (math.isfinite(fov) and 1.0 <= fov <= 170.0):
        raise OptionError(f"--fov: vertical field of view must be in [1, 170] degrees, got {fov}")
    return float(fov)


def look_from_eye(target: Tensor, eye: Tensor) -> Look:
    """Inverse of :meth:`Camera.orbit_eye`: target, eye (3,) -> Look."""
    off = (eye.double() - target.double()).tolist()
    dist = math.sqrt(sum(v * v for v in off))
    if dist < 1e-9:
        raise ValueError("look_from_eye: eye and target coincide")
    el = math.degrees(math.asin(max(-1.0, min(1.0, off[2] / dist))))
    az = math.degrees(math.atan2(off[0], -off[1]))
    return Look(az, el, dist)


def focus_point(cameras: list[Camera]) -> Tensor:
    """(3,) the point closest (least squares) to all cameras' optical axes; for one camera (or parallel axes)
    the point where the first camera's axis meets the support plane z = 0 (both scene families' table or floor
    top), or :data:`FALLBACK_DISTANCE` in front of it when it does not look down."""
    A = torch.zeros(3, 3, dtype=torch.float64)
    b = torch.zeros(3, dtype=torch.float64)
    for cam in cameras:
        c2w = cam.c2w.detach().double().cpu()
        d = c2w[:3, 2] / c2w[:3, 2].norm()
        P = torch.eye(3, dtype=torch.float64) - torch.outer(d, d)
        A += P
        b += P @ c2w[:3, 3]
    if len(cameras) >= 2 and float(torch.linalg.cond(A)) < 1e6:
        return torch.linalg.solve(A, b)
    c2w = cameras[0].c2w.detach().double().cpu()
    eye, axis = c2w[:3, 3], c2w[:3, 2] / c2w[:3, 2].norm()
    t = float(-eye[2] / axis[2]) if float(axis[2]) < -1e-3 and float(eye[2]) > 0 else FALLBACK_DISTANCE
    return eye + t * axis


@dataclass(frozen=True)
class Framing:
    """Where a scene's cameras look, as its generator records it in ``scene.json``: ``target`` (x, y, z) world
    metres (``look_at``) and ``distance`` metres from it (None: the cameras' median distance); ``keep``: world
    points (metres) the default view must show, such as a robot arm's joints (the view backs off until they fit)."""

    target: tuple[float, float, float]
    distance: float | None = None
    source: str = field(default="scene.json", compare=False)  # the file it was read from, for messages
    keep: tuple[tuple[float, float, float], ...] = ()


FRAMING_TOLERANCE = 10.0  # a framing's target farther than this many camera distances from the cameras' focus, or a
# distance this many times theirs (or a tenth), is implausible: warned
KEEP_MARGIN = 0.9  # a framing's keep points stay within this fraction of the half field of view
KEEP_BACKOFF = (1.0, 2.5, 0.05)  # the default view's distance grows by these factors (from, to, step) to show them


def framed_to_keep(target: Tensor, look: Look, fov_y: float, keep: Tensor) -> tuple[Tensor, Look]:
    """The orbit about ``target`` (3,) with ``look``, changed to show every point of ``keep`` (N, 3) world metres
    within :data:`KEEP_MARGIN` of the half field of view ``fov_y`` (degrees, vertical; a landscape window shows
    more across), in front of the camera: the target rises halfway to the highest point (a robot's arm stands
    over its table), then the camera backs off along its direction (azimuth and elevation kept) by the least
    factor of :data:`KEEP_BACKOFF` that shows them all, or the largest. Returns (target (3,), look)."""
    pts = keep.double()
    target = target.double().clone()
    target[2] = 0.5 * (target[2] + max(float(pts[:, 2].max()), float(target[2])))
    start, stop, step = KEEP_BACKOFF
    size = 1000  # a square image, in pixels: the margin is a share of its half side
    factor = start
    while True:
        distance = look.distance * factor
        cam = Camera.orbit(target, look.azimuth, look.elevation, distance, fov_y_deg=fov_y, width=size, height=size)
        uv, z = cam.to(dtype=torch.float64).project(pts)
        fits = bool((z > 0).all()) and bool(((uv - size / 2).abs() <= KEEP_MARGIN * size / 2).all())
        if fits or factor + step > stop + 1e-9:
            return target, replace(look, distance=distance)
        factor += step


def default_view(
    cameras: list[Camera] | None = None, gaussians: Gaussians | None = None, framing: Framing | None = None
) -> View:
    """The default view of a scene.

    With cameras (a scene folder): orbit about ``framing.target`` (else :func:`focus_point` of all cameras) at
    ``framing.distance`` (else the cameras' median distance from the target), from the middle camera's
    direction, with its vertical field of view: a scene's own scale (a tabletop 3 m away, a robot table 1 m away);
    raised and backed off until ``framing.keep`` (a robot's arm) is in view (:func:`framed_to_keep`).
    With Gaussians only (a .ply): about the median of the means, azimuth 0, elevation 25°, at a
    distance that frames the 90th-percentile radius in a 40° view.
    """
    if cameras:
        target = torch.tensor(framing.target, dtype=torch.float64) if framing else focus_point(cameras)
        centres = torch.stack([c.center.detach().double().cpu() for c in cameras])
        distance = framing.distance if framing and framing.distance else None
        seen_from = float((centres - target).norm(dim=-1).median())
        if distance is None:
            distance = seen_from
        if framing is not None:  # a framing far from what the cameras see renders an empty view
            scale = float((centres - focus_point(cameras)).norm(dim=-1).median())
            off = float((target - focus_point(cameras)).norm())
            if off > FRAMING_TOLERANCE * max(scale, 1e-6) or not (
                1 / FRAMING_TOLERANCE <= distance / max(seen_from, 1e-9) <= FRAMING_TOLERANCE
            ):
                from particlesplat.core.errors import warn_input

                warn_input(
                    f"{framing.source}: look_at {','.join(f'{v:g}' for v in framing.target)} and distance "
                    f"{distance:.3g} m frame a point "
                    f"{off:.3g} m from where the cameras look, {distance / max(seen_from, 1e-9):.3g} x their distance; "
                    "the default view may show nothing of the scene"
                )
        mid = cameras[len(cameras) // 2]
        look = replace(look_from_eye(target, mid.center.detach().cpu()), distance=distance)
        if framing is not None and framing.keep:
            target, look = framed_to_keep(target, look, mid.fov_y, torch.tensor(framing.keep, dtype=torch.float64))
        return View(float3(target), look, round(mid.fov_y, 6))
    if gaussians is not None and gaussians.num:
        means = gaussians.means.detach().double().cpu()
        target = means.median(0).values
        radius = float(torch.quantile((means - target).norm(dim=-1), 0.9)) if means.shape[0] > 1 else 1.0
        dist = max(radius, 1e-3) / math.tan(math.radians(DEFAULT_FOV) / 2.0) * 1.1
        return View(float3(target), Look(0.0, DEFAULT_ELEVATION, dist), DEFAULT_FOV)
    return View((0.0, 0.0, 0.0), Look(0.0, DEFAULT_ELEVATION, FALLBACK_DISTANCE), DEFAULT_FOV)


def default_context_views(num_frames: int) -> list[int]:
    """The context frames the viewer and ``particlesplat render`` encode by default: two frames
    12 apart about the middle of the trajectory (4 and 16 of 21), clipped to what exists."""
    if num_frames < 1:
        raise ValueError("a scene needs at least one frame")
    if num_frames == 1:
        return [0]
    mid = num_frames // 2
    left = max(0, mid - 6)
    right = min(num_frames - 1, mid + 6)
    return [left, right] if right > left else [left]
