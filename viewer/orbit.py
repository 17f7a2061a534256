"""Orbit camera about a target (+z up world): orbit, pan, zoom, snap, reset."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import torch

from particlesplat.core.camera import Camera
from particlesplat.core.vectors import float3
from particlesplat.core.viewpoints import Look, View, look_from_eye

ZOOM_RANGE = (0.02, 50.0)  # the nearest and farthest zoom, as factors of the home view's distance


@dataclass
class OrbitCamera:
    """The viewer's camera state; ``view`` is immutable, every change replaces it.

    Attributes:
        view: the current view; home: the view :meth:`reset` returns to.
        snapped: (input camera index, the view snapping to it gave) of the last :meth:`snap` that named its camera,
            or None: :attr:`current_camera` is that camera while the view is still the one it gave.
    """

    view: View
    home: View
    snapped: tuple[int, View] | None = field(default=None, compare=False)

    @staticmethod
    def from_view(view: View) -> OrbitCamera:
        return OrbitCamera(view, view)

    def camera(self, width: int, height: int) -> Camera:
        """(width x height) camera of the current view."""
        return self.view.camera(width, height)

    def orbit(self, dx_px: float, dy_px: float, degrees_per_px: float = 0.3) -> None:
        """Turn about the target: dragging right turns the scene right, dragging down tilts up."""
        look = self.view.look
        el = max(-89.0, min(89.0, look.elevation + dy_px * degrees_per_px))
        self.view = replace(self.view, look=Look(look.azimuth - dx_px * degrees_per_px, el, look.distance))

    def turn(self, degrees: float) -> None:
        """Add ``degrees`` of azimuth (the ``--orbit`` animation)."""
        look = self.view.look
        self.view = replace(self.view, look=Look(look.azimuth + degrees, look.elevation, look.distance))

    def pan(self, dx_px: float, dy_px: float, viewport_height: int) -> None:
        """Move the target in the image plane so the scene follows the mouse."""
        cam = self.camera(max(viewport_height, 1), max(viewport_height, 1))
        metres_per_px = (
            self.view.look.distance * 2.0 * math.tan(math.radians(self.view.fov) / 2.0) / max(viewport_height, 1)
        )
        R = cam.c2w[:3, :3].double()
        shift = R[:, 0] * (-dx_px * metres_per_px) + R[:, 1] * (-dy_px * metres_per_px)
        target = torch.tensor(self.view.target, dtype=torch.float64) + shift
        self.view = replace(self.view, target=float3(target))

    def zoom(self, wheel_steps: float, factor: float = 0.9) -> None:
        """Scale the distance by ``factor`` per wheel step (positive = closer), within :data:`ZOOM_RANGE` of the
        home view's distance (the scene's own scale: a tabletop 3 m away, a robot table 1 m away)."""
        look = self.view.look
        lo, hi = (f * self.home.look.distance for f in ZOOM_RANGE)
        dist = min(max(look.distance * factor**wheel_steps, lo), hi)
        self.view = replace(self.view, look=Look(look.azimuth, look.elevation, dist))

    def reset(self) -> None:
        self.view = self.home

    def snap(self, camera: Camera, index: int | None = None) -> None:
        """Look from ``camera``'s centre along its axis (target moved onto the axis, at the point
        closest to the current target) with its vertical field of view; ``index``: which input camera it is (the
        panel marks it while the view stays there: :attr:`current_camera`)."""
        c2w = camera.c2w.detach().double().cpu()
        eye, axis = c2w[:3, 3], c2w[:3, 2] / c2w[:3, 2].norm()
        t = float(torch.dot(torch.tensor(self.home.target, dtype=torch.float64) - eye, axis))
        target = eye + max(t, 0.1) * axis
        self.view = View(float3(target), look_from_eye(target, eye), camera.fov_y)
        if index is not None:
            self.snapped = (index, self.view)

    @property
    def current_camera(self) -> int | None:
        """The input camera the view is at: the last one snapped to, until the view moves (orbit, pan, zoom,
        reset); None when it is at none."""
        if self.snapped is None or self.snapped[1] != self.view:
            return None
        return self.snapped[0]

    def step_camera(self, cameras: list[Camera], by: int) -> int | None:
        """Snap to the input camera ``by`` places after the current one (the last one snapped to when the view
        has moved since; before camera 0 when there was none), wrapping around ``cameras``; returns its index (None
        without cameras)."""
        if not cameras:
            return None
        last = self.snapped[0] if self.snapped is not None else (-1 if by > 0 else 0)
        index = (last + by) % len(cameras)
        self.snap(cameras[index], index)
        return index
