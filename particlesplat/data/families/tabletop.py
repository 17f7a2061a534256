"""The tabletop scene family: draw a scene and ray-cast it analytically (numpy, float64).

The family of the project's dataset spec (docs/dataset.md).
World: metres, +z up, floor z = 0.
Rays use unnormalised directions whose camera-z component is 1, so a hit's ray parameter
``t`` *is* its planar camera depth.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from types import MappingProxyType

import numpy as np

FLOOR_HALF = 2.0
CHECKER_CELL = 0.5
FLOOR_GREYS = (0.55, 0.65)
BACKGROUND = (0.12, 0.14, 0.18)
COLOURS: Mapping[str, tuple[float, float, float]] = MappingProxyType(
    {
        "red": (0.85, 0.2, 0.2),
        "green": (0.2, 0.7, 0.3),
        "blue": (0.2, 0.35, 0.85),
        "yellow": (0.9, 0.8, 0.2),
        "cyan": (0.2, 0.75, 0.8),
        "magenta": (0.8, 0.25, 0.7),
        "orange": (0.95, 0.5, 0.15),
        "white": (0.9, 0.9, 0.9),
    }
)
SHAPES = ("sphere", "box", "cylinder")
NUM_OBJECTS = (2, 5)
SIZE_RANGE = (0.12, 0.30)
CENTRE_RADIUS = 1.0
LIGHT = tuple(np.array([0.4, 0.3, 1.0]) / np.linalg.norm([0.4, 0.3, 1.0]))
AMBIENT, DIFFUSE = 0.35, 0.65
NUM_VIEWS = 21
AZIMUTH_RANGE = (-120.0, 120.0)
ELEVATION_RANGE = (25.0, 40.0)
DISTANCE_RANGE = (3.0, 3.6)
LOOK_AT = (0.0, 0.0, 0.15)
FOV_Y_DEG = 40.0
FRONT_VIEW = 10
_GAP = 0.02  # minimum clearance between object footprints, metres
_EPS = 1e-9


@dataclass
class TabletopObject:
    """One object resting on the floor.

    Attributes:
        shape: "sphere", "box" or "cylinder".
        center: (x, y, z) metres; z is the half height, so the object touches z = 0.
        size: sphere (r, r, r); box half-extents (hx, hy, hz) before yaw; cylinder (r, r, half height).
        yaw: rotation about +z in radians (boxes; 0 for the others).
        colour: name in ``COLOURS``.
    """

    shape: str
    center: tuple[float, float, float]
    size: tuple[float, float, float]
    yaw: float
    colour: str

    @property
    def footprint_radius(self) -> float:
        """Radius of a vertical cylinder about the centre that contains the object."""
        if self.shape == "box":
            return math.hypot(self.size[0], self.size[1])
        return self.size[0]


@dataclass
class TabletopScene:
    """A drawn scene: objects (instance id = list position + 1) and the camera arc."""

    objects: list[TabletopObject]
    elevation_deg: float
    distance: float

    def azimuths_deg(self) -> np.ndarray:
        """(NUM_VIEWS,) azimuths, evenly from -120 to +120 degrees; frame 10 is 0."""
        return np.linspace(AZIMUTH_RANGE[0], AZIMUTH_RANGE[1], NUM_VIEWS)

    def to_json(self) -> dict:
        return {
            "objects": [asdict(o) for o in self.objects],
            "elevation_deg": self.elevation_deg,
            "distance": self.distance,
            "look_at": list(LOOK_AT),
            "azimuths_deg": self.azimuths_deg().tolist(),
            "fov_y_deg": FOV_Y_DEG,
        }


def sample_scene(rng: np.random.Generator) -> TabletopScene:
    """Draw a scene: 2-5 non-intersecting objects with centres within 1 m of the origin."""
    while True:
        count = int(rng.integers(NUM_OBJECTS[0], NUM_OBJECTS[1] + 1))
        objects: list[TabletopObject] = []
        for _ in range(count):
            placed = _place_object(rng, objects)
            if placed is None:
                break
            objects.append(placed)
        if len(objects) == count:
            break
    elevation = float(rng.uniform(*ELEVATION_RANGE))
    distance = float(rng.uniform(*DISTANCE_RANGE))
    return TabletopScene(objects, elevation, distance)


def _place_object(rng: np.random.Generator, others: list[TabletopObject], tries: int = 200) -> TabletopObject | None:
    shape = SHAPES[int(rng.integers(len(SHAPES)))]
    colour = list(COLOURS)[int(rng.integers(len(COLOURS)))]
    if shape == "sphere":
        r = float(rng.uniform(*SIZE_RANGE))
        size, yaw = (r, r, r), 0.0
    elif shape == "box":
        sx, sy, sz = (float(s) for s in rng.uniform(*SIZE_RANGE, size=3))
        size, yaw = (sx, sy, sz), float(rng.uniform(-math.pi, math.pi))
    else:
        r, h = (float(s) for s in rng.uniform(*SIZE_RANGE, size=2))
        size, yaw = (r, r, h), 0.0
    for _ in range(tries):
        rad = CENTRE_RADIUS * math.sqrt(float(rng.uniform()))
        ang = float(rng.uniform(-math.pi, math.pi))
        obj = TabletopObject(shape, (rad * math.cos(ang), rad * math.sin(ang), size[2]), size, yaw, colour)
        if all(
            math.hypot(obj.center[0] - o.center[0], obj.center[1] - o.center[1])
            >= obj.footprint_radius + o.footprint_radius + _GAP
            for o in others
        ):
            return obj
    return None


# ---------------------------------------------------------------------------- ray casting
def _hit_floor(o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """o: (3,), d: (N, 3) -> (t (N,) inf on miss, normal (N, 3))."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(d[:, 2] < 0, -o[2] / d[:, 2], np.inf)
    p = o + t[:, None] * d
    t = np.where((t > _EPS) & (np.abs(p[:, 0]) <= FLOOR_HALF) & (np.abs(p[:, 1]) <= FLOOR_HALF), t, np.inf)
    return t, np.broadcast_to(np.array([0.0, 0.0, 1.0]), d.shape)


def _hit_sphere(o: np.ndarray, d: np.ndarray, obj: TabletopObject) -> tuple[np.ndarray, np.ndarray]:
    """o: (3,), d: (N, 3) -> (t (N,) inf on miss, normal (N, 3))."""
    c, r = np.array(obj.center), obj.size[0]
    oc = o - c
    a = np.einsum("ij,ij->i", d, d)
    b = 2.0 * d @ oc
    disc = b * b - 4.0 * a * (oc @ oc - r * r)
    t = (-b - np.sqrt(np.maximum(disc, 0.0))) / (2.0 * a)
    t = np.where((disc >= 0) & (t > _EPS), t, np.inf)
    p = o + np.where(np.isfinite(t), t, 0.0)[:, None] * d
    return t, (p - c) / r


def _rot_z(yaw: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _hit_box(o: np.ndarray, d: np.ndarray, obj: TabletopObject) -> tuple[np.ndarray, np.ndarray]:
    """Slab test in the box frame (rotated by -yaw about z). o: (3,), d: (N, 3) -> (t (N,) inf on
    miss, normal (N, 3))."""
    rot = _rot_z(obj.yaw)
    ol = rot.T @ (o - np.array(obj.center))
    dl = d @ rot  # == (rot.T @ d.T).T
    dl = np.where(np.abs(dl) < 1e-15, 1e-15, dl)
    h = np.array(obj.size)
    t1, t2 = (-h - ol) / dl, (h - ol) / dl
    tnear, tfar = np.minimum(t1, t2), np.maximum(t1, t2)
    t_in, t_out = tnear.max(axis=1), tfar.min(axis=1)
    t = np.where((t_out >= t_in) & (t_in > _EPS), t_in, np.inf)
    axis = tnear.argmax(axis=1)
    nl = np.zeros_like(dl)
    rows = np.arange(len(dl))
    nl[rows, axis] = -np.sign(dl[rows, axis])
    return t, nl @ rot.T


def _hit_cylinder(o: np.ndarray, d: np.ndarray, obj: TabletopObject) -> tuple[np.ndarray, np.ndarray]:
    """Upright cylinder: side (quadratic in x, y) and the two caps z = 0, z = 2 * half height.
    o: (3,), d: (N, 3) -> (t (N,) inf on miss, normal (N, 3))."""
    cx, cy, _ = obj.center
    r, top = obj.size[0], 2.0 * obj.size[2]
    ox, oy = o[0] - cx, o[1] - cy
    a = d[:, 0] ** 2 + d[:, 1] ** 2
    b = 2.0 * (ox * d[:, 0] + oy * d[:, 1])
    disc = b * b - 4.0 * a * (ox * ox + oy * oy - r * r)
    with np.errstate(divide="ignore", invalid="ignore"):
        t_side = (-b - np.sqrt(np.maximum(disc, 0.0))) / (2.0 * a)
        z_side = o[2] + t_side * d[:, 2]
        t_side = np.where((a > 1e-15) & (disc >= 0) & (t_side > _EPS) & (z_side >= 0) & (z_side <= top), t_side, np.inf)
        caps = []
        for zc in (top, 0.0):
            tc = (zc - o[2]) / d[:, 2]
            px, py = ox + tc * d[:, 0], oy + tc * d[:, 1]
            caps.append(np.where(np.isfinite(tc) & (tc > _EPS) & (px * px + py * py <= r * r), tc, np.inf))
    t = np.minimum(t_side, np.minimum(*caps))
    p = o + np.where(np.isfinite(t), t, 0.0)[:, None] * d
    n_side = np.stack([(p[:, 0] - cx) / r, (p[:, 1] - cy) / r, np.zeros_like(t)], axis=1)
    n = np.where(
        (t == t_side)[:, None],
        n_side,
        np.where((t == caps[0])[:, None], np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.0, -1.0])),
    )
    return t, n


_HITTERS = MappingProxyType({"sphere": _hit_sphere, "box": _hit_box, "cylinder": _hit_cylinder})


def _bounding_radius(obj: TabletopObject) -> float:
    """Radius of a sphere about ``obj.center`` that contains the object."""
    if obj.shape == "box":
        return float(np.linalg.norm(obj.size))
    if obj.shape == "cylinder":
        return math.hypot(obj.size[0], obj.size[2])
    return obj.size[0]


def trace(
    scene: TabletopScene, origin: np.ndarray, dirs: np.ndarray, shade: bool = True
) -> tuple[np.ndarray | None, np.ndarray, np.ndarray]:
    """Cast rays from one origin.

    Each object is intersected exactly, but only for the rays that hit its bounding sphere.

    Args:
        origin: (3,) camera centre, world metres.
        dirs: (N, 3) directions with camera-z component 1 (``t`` is planar depth).
        shade: compute colours (else the first result is None).

    Returns:
        colour (N, 3) shaded in [0, 1]; depth (N,) planar metres, 0 where nothing is hit;
        instance (N,) int64: -1 nothing (background colour), 0 floor, k >= 1 object k.
    """
    t_best, n_floor = _hit_floor(origin, dirs)
    n_best = np.array(n_floor)
    inst = np.where(np.isfinite(t_best), 0, -1)
    dd = np.einsum("ij,ij->i", dirs, dirs)
    for k, obj in enumerate(scene.objects, start=1):
        oc = origin - np.asarray(obj.center)
        half_b = dirs @ oc
        cand = np.flatnonzero(half_b * half_b - dd * (oc @ oc - _bounding_radius(obj) ** 2) > 0)
        if cand.size == 0:
            continue
        t, n = _HITTERS[obj.shape](origin, dirs[cand], obj)
        closer = t < t_best[cand]
        sel = cand[closer]
        t_best[sel], n_best[sel], inst[sel] = t[closer], n[closer], k
    depth = np.where(inst >= 0, t_best, 0.0)
    if not shade:
        return None, depth, inst.astype(np.int64)
    p = origin + depth[:, None] * dirs
    checker = (np.floor(p[:, 0] / CHECKER_CELL) + np.floor(p[:, 1] / CHECKER_CELL)).astype(np.int64) % 2
    albedo = np.asarray(FLOOR_GREYS)[checker][:, None].repeat(3, axis=1)
    for k, obj in enumerate(scene.objects, start=1):
        albedo[inst == k] = COLOURS[obj.colour]
    lit = AMBIENT + DIFFUSE * np.maximum(0.0, n_best @ np.asarray(LIGHT))
    colour = np.clip(albedo * lit[:, None], 0.0, 1.0)
    colour[inst < 0] = BACKGROUND
    return colour, depth, inst.astype(np.int64)


def pixel_rays(K: np.ndarray, c2w: np.ndarray, width: int, height: int, offsets: tuple[float, ...]) -> np.ndarray:
    """Ray directions through sub-pixel points ``(u + ou, v + ov)`` for ``ou, ov`` in ``offsets``.

    Args:
        K: (3, 3) intrinsics; c2w: (4, 4) OpenCV camera-to-world.

    Returns:
        (H, S, W, S, 3) directions with camera-z 1, S = len(offsets).
    """
    off = np.asarray(offsets)
    u = (np.arange(width)[:, None] + off[None, :]).reshape(-1)
    v = (np.arange(height)[:, None] + off[None, :]).reshape(-1)
    uu, vv = np.meshgrid(u, v, indexing="xy")
    pix = np.stack([uu, vv, np.ones_like(uu)], axis=-1)
    d_cam = pix @ np.linalg.inv(K).T
    dirs = d_cam @ c2w[:3, :3].T
    s = len(offsets)
    return dirs.reshape(height, s, width, s, 3)


def render_view(
    scene: TabletopScene, K: np.ndarray, c2w: np.ndarray, width: int, height: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Render one view: colour from 2x2 supersampling, depth and instances from the pixel-centre ray.

    Args:
        K: (3, 3) intrinsics in pixels; c2w: (4, 4) OpenCV camera-to-world.

    Returns:
        rgb (H, W, 3) float in [0, 1]; depth (H, W) planar metres (0 = nothing);
        mask (H, W) int64 instance ids (0 = floor or background, k = object k).
    """
    origin = c2w[:3, 3]
    sub = pixel_rays(K, c2w, width, height, (0.25, 0.75))
    colour, _, _ = trace(scene, origin, sub.reshape(-1, 3))
    assert colour is not None  # traced with shading
    rgb = colour.reshape(height, 2, width, 2, 3).mean(axis=(1, 3))
    centre = pixel_rays(K, c2w, width, height, (0.5,))
    _, depth, inst = trace(scene, origin, centre.reshape(-1, 3), shade=False)
    return rgb, depth.reshape(height, width), np.maximum(inst, 0).reshape(height, width)
