"""Pinhole camera in the OpenCV convention (x right, y down, +z forward).

Pixel ``(u, v)`` has its centre at ``(u + 0.5, v + 0.5)`` in the coordinates that ``K`` maps
to, so the ray through pixel ``(u, v)`` has direction ``R K^-1 [u + 0.5, v + 0.5, 1]``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from kornia.geometry.linalg import inverse_transformation, transform_points
from torch import Tensor

# OpenCV camera axes = OpenGL/nerfstudio camera axes with y and z flipped.
_FLIP_YZ = (1.0, -1.0, -1.0, 1.0)


@dataclass
class Camera:
    """A pinhole camera.

    Attributes:
        K: (3, 3) intrinsics in pixels.
        c2w: (4, 4) camera-to-world rigid transform, OpenCV axes, metres.
        width: image width in pixels.
        height: image height in pixels.
    """

    K: Tensor
    c2w: Tensor
    width: int
    height: int

    def __post_init__(self) -> None:
        if tuple(self.K.shape) != (3, 3):
            raise ValueError(f"Camera.K must have shape (3, 3), got {tuple(self.K.shape)}")
        if tuple(self.c2w.shape) != (4, 4):
            raise ValueError(f"Camera.c2w must have shape (4, 4), got {tuple(self.c2w.shape)}")
        if int(self.width) <= 0 or int(self.height) <= 0:
            raise ValueError(f"Camera size must be positive, got {self.width}x{self.height}")
        self.width = int(self.width)
        self.height = int(self.height)

    # ------------------------------------------------------------------ basic properties
    @property
    def device(self) -> torch.device:
        return self.c2w.device

    @property
    def dtype(self) -> torch.dtype:
        return self.c2w.dtype

    @property
    def fx(self) -> Tensor:
        return self.K[0, 0]

    @property
    def fy(self) -> Tensor:
        return self.K[1, 1]

    @property
    def cx(self) -> Tensor:
        return self.K[0, 2]

    @property
    def cy(self) -> Tensor:
        return self.K[1, 2]

    @property
    def R(self) -> Tensor:
        """(3, 3) camera-to-world rotation (columns: camera x, y, z axes in world)."""
        return self.c2w[:3, :3]

    @property
    def center(self) -> Tensor:
        """(3,) camera centre in world metres."""
        return self.c2w[:3, 3]

    @property
    def w2c(self) -> Tensor:
        """(4, 4) world-to-camera rigid transform."""
        return inverse_transformation(self.c2w)

    @property
    def fov_y(self) -> float:
        """Vertical field of view in degrees."""
        return math.degrees(2.0 * math.atan(0.5 * self.height / float(self.fy)))

    def to(self, device: torch.device | str | None = None, dtype: torch.dtype | None = None) -> Camera:
        return Camera(
            self.K.to(device=device, dtype=dtype), self.c2w.to(device=device, dtype=dtype), self.width, self.height
        )

    # ------------------------------------------------------------------ geometry
    def world_to_camera(self, points: Tensor) -> Tensor:
        """points: (..., 3) world -> (..., 3) camera coordinates (OpenCV)."""
        shape = points.shape
        out = transform_points(self.w2c[None].to(points.dtype), points.reshape(1, -1, 3))
        return out.reshape(shape)

    def camera_to_world(self, points: Tensor) -> Tensor:
        """points: (..., 3) camera -> (..., 3) world coordinates."""
        shape = points.shape
        out = transform_points(self.c2w[None].to(points.dtype), points.reshape(1, -1, 3))
        return out.reshape(shape)

    def project(self, points: Tensor) -> tuple[Tensor, Tensor]:
        """Project world points. points: (..., 3) -> (uv (..., 2) pixels, z (...) planar depth).

        ``uv`` is in continuous pixel coordinates (pixel ``u`` spans ``[u, u+1)``). Points
        with ``z <= 0`` get non-finite or mirrored ``uv``; check ``z`` before using them.
        """
        p = self.world_to_camera(points)
        z = p[..., 2]
        K = self.K.to(points.dtype)
        uv = (p[..., :2] / z[..., None]) * torch.stack([K[0, 0], K[1, 1]]) + torch.stack([K[0, 2], K[1, 2]])
        return uv, z

    def unproject(self, uv: Tensor, depth: Tensor) -> Tensor:
        """uv: (..., 2) pixels, depth: (...) planar z -> (..., 3) world points."""
        K = self.K.to(uv.dtype)
        xy = (uv - torch.stack([K[0, 2], K[1, 2]])) / torch.stack([K[0, 0], K[1, 1]])
        p = torch.cat([xy * depth[..., None], depth[..., None]], dim=-1)
        return self.camera_to_world(p)

    def pixel_centers(self) -> Tensor:
        """(H, W, 2) pixel-centre coordinates ``(u + 0.5, v + 0.5)``."""
        v, u = torch.meshgrid(
            torch.arange(self.height, device=self.device, dtype=self.dtype),
            torch.arange(self.width, device=self.device, dtype=self.dtype),
            indexing="ij",
        )
        return torch.stack([u + 0.5, v + 0.5], dim=-1)

    def rays(self, uv: Tensor | None = None) -> tuple[Tensor, Tensor]:
        """Rays through pixel centres (or through ``uv`` (..., 2)).

        Returns origins (H, W, 3) and unnormalised directions ``R K^-1 [u+.5, v+.5, 1]``
        (H, W, 3); a direction's camera z component is 1, so ``origin + z * dir`` is the
        point at planar depth ``z``.
        """
        if uv is None:
            uv = self.pixel_centers()
        ones = torch.ones_like(uv[..., :1])
        pix = torch.cat([uv, ones], dim=-1)
        d_cam = pix @ torch.linalg.inv(self.K.to(uv.dtype)).T
        dirs = d_cam @ self.R.to(uv.dtype).T
        origins = self.center.to(uv.dtype).expand_as(dirs)
        return origins, dirs

    # ------------------------------------------------------------------ conversions
    def resized(self, width: int, height: int) -> Camera:
        """Same view at another image size; intrinsics scale so pixel centres stay consistent.

        With pixel centres at ``u + 0.5``, scaling the image by ``s`` maps continuous
        coordinate ``x`` to ``s * x``, so ``fx, cx`` (and ``fy, cy``) scale by the same factor.
        """
        sx, sy = width / self.width, height / self.height
        S = torch.diag(torch.tensor([sx, sy, 1.0], dtype=self.K.dtype, device=self.K.device))
        return Camera(S @ self.K, self.c2w.clone(), width, height)

    def to_opengl_c2w(self) -> Tensor:
        """(4, 4) camera-to-world in the nerfstudio/OpenGL convention (y up, looking down -z)."""
        return self.c2w @ torch.diag(torch.tensor(_FLIP_YZ, dtype=self.dtype, device=self.device))

    @staticmethod
    def from_opengl_c2w(c2w_gl: Tensor, K: Tensor, width: int, height: int) -> Camera:
        """Build a camera from a nerfstudio/OpenGL camera-to-world matrix c2w_gl (4, 4) and K (3, 3) pixels."""
        flip = torch.diag(torch.tensor(_FLIP_YZ, dtype=c2w_gl.dtype, device=c2w_gl.device))
        return Camera(K, c2w_gl @ flip, width, height)

    # ------------------------------------------------------------------ constructors
    @staticmethod
    def intrinsics_from_fov(fov_y_deg: float, width: int, height: int, dtype: torch.dtype = torch.float32) -> Tensor:
        """(3, 3) K with square pixels, vertical field of view ``fov_y_deg`` and a centred principal point."""
        f = 0.5 * height / math.tan(math.radians(fov_y_deg) / 2.0)
        return torch.tensor([[f, 0.0, width / 2.0], [0.0, f, height / 2.0], [0.0, 0.0, 1.0]], dtype=dtype)

    @staticmethod
    def look_at(
        eye,
        target,
        up=(0.0, 0.0, 1.0),
        *,
        fov_y_deg: float = 40.0,
        width: int = 128,
        height: int = 128,
        dtype: torch.dtype = torch.float32,
    ) -> Camera:
        """Camera at ``eye`` (3,) looking at ``target`` (3,), with world ``up`` (3,) upward in the image."""
        eye_t = torch.as_tensor(eye, dtype=torch.float64)
        target_t = torch.as_tensor(target, dtype=torch.float64)
        up_t = torch.as_tensor(up, dtype=torch.float64)
        forward = target_t - eye_t
        if float(forward.norm()) < 1e-12:
            raise ValueError("look_at: eye and target coincide")
        forward = forward / forward.norm()
        right = torch.linalg.cross(forward, up_t)
        if float(right.norm()) < 1e-9:  # looking straight along up: use the world axis least along forward
            axis = torch.zeros(3, dtype=torch.float64)
            axis[int(forward.abs().argmin())] = 1.0
            right = torch.linalg.cross(forward, axis)
        right = right / right.norm()
        down = torch.linalg.cross(forward, right)
        c2w = torch.eye(4, dtype=torch.float64)
        c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = right, down, forward, eye_t
        K = Camera.intrinsics_from_fov(fov_y_deg, width, height, dtype=dtype)
        return Camera(K, c2w.to(dtype), width, height)

    @staticmethod
    def orbit_eye(target, azimuth_deg: float, elevation_deg: float, distance: float) -> Tensor:
        """(3,) eye position on a sphere about ``target`` in a +z-up world.

        Azimuth 0 puts the camera on the -y side looking along +y (world x points right in the
        image); positive azimuth turns the camera counter-clockwise seen from above.
        Elevation is the angle above the horizontal plane through ``target``.
        """
        az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
        offset = torch.tensor(
            [math.sin(az) * math.cos(el), -math.cos(az) * math.cos(el), math.sin(el)], dtype=torch.float64
        )
        return torch.as_tensor(target, dtype=torch.float64) + distance * offset

    @staticmethod
    def orbit(
        target,
        azimuth_deg: float,
        elevation_deg: float,
        distance: float,
        *,
        fov_y_deg: float = 40.0,
        width: int = 128,
        height: int = 128,
        dtype: torch.dtype = torch.float32,
    ) -> Camera:
        """Camera on an orbit about ``target`` (see :meth:`orbit_eye`), no roll, +z up."""
        eye = Camera.orbit_eye(target, azimuth_deg, elevation_deg, distance)
        return Camera.look_at(eye, target, fov_y_deg=fov_y_deg, width=width, height=height, dtype=dtype)


def camera_problem(K, c2w, width: int, height: int) -> str | None:
    """What makes a camera unusable (None when nothing does), checked in float64 for the float32 it is used in:
    K (3, 3) intrinsics with positive focal lengths, zero skew and the last row 0 0 1; c2w (4, 4) a rigid
    transform (orthonormal rotation, det +1, last row 0 0 0 1); every value finite and representable in float32
    with margin (:func:`particlesplat.core.limits.float32_problem`); width and height positive."""
    import numpy as np

    from particlesplat.core.limits import FLOAT32_MAX_ABS, float32_problem, rigid_problem

    K, c2w = np.asarray(K, dtype=np.float64), np.asarray(c2w, dtype=np.float64)
    if K.shape != (3, 3) or c2w.shape != (4, 4):
        return f"K must be 3x3 and c2w 4x4, got {K.shape} and {c2w.shape}"
    if not (np.isfinite(K).all() and np.isfinite(c2w).all()):
        return "K and c2w must be finite numbers"
    if max(np.abs(K).max(), np.abs(c2w).max()) > FLOAT32_MAX_ABS:
        return f"K and c2w values must lie within +-{FLOAT32_MAX_ABS:g} (float32 arithmetic on them overflows)"
    for name, v in (("fx", K[0, 0]), ("fy", K[1, 1])):
        problem = float32_problem(v, positive=True)
        if problem:
            return f"focal length {name} is {problem} (got {v:g})"
    if K[0, 1] != 0 or K[1, 0] != 0 or list(K[2]) != [0.0, 0.0, 1.0]:
        return "K must be [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]"
    problem = rigid_problem(c2w, max_metres=None)  # the rigid-pose check every pose gets (the robot's base too)
    if problem:
        return f"c2w {problem}"
    if int(width) < 1 or int(height) < 1:
        return f"width and height must be positive, got {width}x{height}"
    return None
