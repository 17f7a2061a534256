"""Where an inserted object may go on a scene's floor: the footprints of the objects there, whether a point is
inside one, and a free spot near the scene's objects when the user names none."""

from __future__ import annotations

from dataclasses import dataclass

import torch

from particlesplat.editing.grouping import arm_state, object_centres
from particlesplat.editing.scene_objects import SceneObjects
from particlesplat.model import Particles, ParticleSplat

FOOTPRINT_SIGMAS = 2.0  # an object's footprint radius: this many standard deviations of its Gaussians in x, y
GRID_STEP = 0.05  # metres between the candidate spots of free_spot
MIN_RADIUS = 0.03  # metres: the smallest footprint radius (a flat or tiny object still takes some floor)


@dataclass(frozen=True)
class Footprint:
    """An object's place on the floor: its centre (x, y) and radius, world metres."""

    x: float
    y: float
    radius: float

    def clearance(self, x: float, y: float) -> float:
        """Metres from (x, y) to the edge of the footprint (negative inside)."""
        return ((x - self.x) ** 2 + (y - self.y) ** 2) ** 0.5 - self.radius


def footprints(model: ParticleSplat, particles: Particles, members: list[int] | None = None) -> list[Footprint]:
    """The footprints of the scene's objects (drawing particles grouped as ``particlesplat encode`` numbers them),
    or of the one object made of ``members``."""
    g = model.decode(particles).detach().to("cpu")
    p = particles.detach().to("cpu")
    if members is None:
        objects = SceneObjects.group(p, g, model.config.bg_mask_threshold, arm=arm_state(model, p)).labels
    else:
        objects = torch.full((p.num,), -1, dtype=torch.int64)
        objects[members] = 0
    k = int(objects.max()) + 1 if objects.numel() and bool((objects >= 0).any()) else 0
    if k == 0:
        return []
    centre, extent = object_centres(g, objects, k, "resting")
    return [
        Footprint(float(c[0]), float(c[1]), max(MIN_RADIUS, FOOTPRINT_SIGMAS * float(e[:2].max())))
        for c, e in zip(centre, extent, strict=True)
    ]


def overlapping(feet: list[Footprint], at: tuple[float, float], radius: float) -> int | None:
    """The index of the first footprint that an object of ``radius`` metres centred at ``at`` overlaps, or None."""
    for i, f in enumerate(feet):
        if f.clearance(*at) < radius:
            return i
    return None


def free_spot(feet: list[Footprint], radius: float) -> tuple[float, float] | None:
    """A floor point (x, y) where an object of ``radius`` metres overlaps none of ``feet``: the free grid point
    (every :data:`GRID_STEP` metres, within the objects' bounds widened by twice ``radius``) nearest to the
    objects' mean centre, so it stays in the views that frame them. (0, 0) on an empty scene; None when there is
    no room."""
    if not feet:
        return (0.0, 0.0)
    xs, ys = torch.tensor([f.x for f in feet]), torch.tensor([f.y for f in feet])
    r = torch.tensor([f.radius for f in feet])
    pad = float(r.max()) + 2.0 * radius
    gx = torch.arange(float(xs.min()) - pad, float(xs.max()) + pad + 1e-9, GRID_STEP)
    gy = torch.arange(float(ys.min()) - pad, float(ys.max()) + pad + 1e-9, GRID_STEP)
    px, py = torch.meshgrid(gx, gy, indexing="ij")
    px, py = px.reshape(-1), py.reshape(-1)
    dist = torch.hypot(px[:, None] - xs[None], py[:, None] - ys[None]) - r[None]  # (N, K) clearance
    free = (dist >= radius).all(1)
    if not bool(free.any()):
        return None
    d_mid = torch.hypot(px - float(xs.mean()), py - float(ys.mean()))
    d_mid[~free] = float("inf")
    i = int(d_mid.argmin())
    return (round(float(px[i]), 3), round(float(py[i]), 3))
