"""Where an object may go in a scene's world: the footprints of the objects there, the surface under a point (the
table where there is one, else the floor: :class:`particlesplat.core.world.Support`), and the free spot on it
nearest to where the user put the object (a drag's end, a copy's offset, ``object insert --at``), or near the
scene's objects when the user names none.

An object's footprint is a disc on the surface it rests on: centred on its resting centre (x, y), wide enough to
hold nearly all of its opaque Gaussians (:data:`FOOTPRINT_QUANTILE` of their distances from the centre, plus
their own size). Two objects are clear of each other when their discs on one surface are :data:`GAP` apart; an
object on the floor is also clear of the table's side by as much.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import torch

from particlesplat.core.errors import UserError
from particlesplat.core.gaussians import Gaussians
from particlesplat.core.world import SUPPORT_Z, Support
from particlesplat.editing.edited import RESTING_TOLERANCE
from particlesplat.editing.grouping import OPAQUE, arm_state
from particlesplat.editing.scene_objects import SceneObjects
from particlesplat.model import Particles, ParticleSplat

if TYPE_CHECKING:
    from particlesplat.editing.edited import EditedParticles

FOOTPRINT_QUANTILE = 0.9  # an object's footprint holds this share of its opaque Gaussians' centres (x, y)
GAP = 0.01  # metres between two objects' footprints, and between an object on the floor and the table's side
GRID_STEP = 0.02  # metres between the candidate spots
NEAR = 0.4  # metres: the farthest a free spot may lie from where the user put an object (a small one)
NEAR_RADII = 3.0  # ... or this many times its footprint radius (a large one)
MIN_RADIUS = 0.01  # metres: the smallest footprint radius (a flat or tiny object still takes some room)
SAME_SURFACE = 0.05  # metres: two objects whose supports differ by less rest on one surface
DROP_NOTE = 0.05  # metres: a placement that lowers or raises an object more than this says so


@dataclass(frozen=True)
class Footprint:
    """An object's place on its surface: its centre (x, y) and radius, and the height of that surface (world
    metres)."""

    x: float
    y: float
    radius: float
    support: float = SUPPORT_Z

    def clearance(self, x: float, y: float) -> float:
        """Metres from (x, y) to the edge of the footprint (negative inside)."""
        return math.hypot(x - self.x, y - self.y) - self.radius


def footprint_of(gaussians: Gaussians, support: float = SUPPORT_Z) -> Footprint | None:
    """The footprint of one object whose Gaussians are ``gaussians`` (resting on a surface at height ``support``):
    centred on the opacity-weighted mean (x, y) of its opaque ones (opacity >= :data:`OPAQUE`, as its resting
    centre), radius the :data:`FOOTPRINT_QUANTILE` of their distances from it plus their median largest standard
    deviation (at least :data:`MIN_RADIUS`). None when none is opaque."""
    keep = gaussians.opacities >= OPAQUE
    if not bool(keep.any()):
        return None
    xy = gaussians.means[keep, :2].detach().double().cpu()
    w = gaussians.opacities[keep].detach().double().cpu()
    centre = (w[:, None] * xy).sum(0) / w.sum()
    spread = float(torch.quantile((xy - centre).norm(dim=-1), FOOTPRINT_QUANTILE))
    size = float(gaussians.scales[keep].detach().double().cpu().amax(-1).median())
    return Footprint(float(centre[0]), float(centre[1]), max(MIN_RADIUS, spread + size), float(support))


def scene_footprints(
    gaussians: Gaussians, labels: torch.Tensor, supports: torch.Tensor, skip: int | None = None
) -> dict[int, Footprint]:
    """The footprint of every object of a scene: ``gaussians`` its decode (owner = particle), ``labels`` (P,) the
    object of each particle (-1: none), ``supports`` (P,) the height of the surface under each particle; object
    ``skip`` (a label) left out. {object label: footprint} for the objects with opaque Gaussians."""
    own = gaussians.owner.cpu()
    valid = (own >= 0) & (own < labels.shape[0])
    group = torch.full_like(own, -1)
    group[valid] = labels.cpu()[own[valid]]
    out = {}
    for k in sorted({int(v) for v in labels.tolist() if v >= 0 and v != skip}):
        members = torch.nonzero(labels == k).flatten()
        found = footprint_of(gaussians.subset(group == k), float(supports[members].max()))
        if found is not None:
            out[k] = found
    return out


def footprints(model: ParticleSplat, particles: Particles, members: list[int] | None = None) -> list[Footprint]:
    """The footprints of the scene's objects (drawing particles grouped as ``particlesplat encode`` numbers them),
    in that order, or the one footprint of the object made of ``members``."""
    g = model.decode(particles).detach().to("cpu")
    p = particles.detach().to("cpu")
    supports = p.support_heights()[:, 0]
    if members is not None:
        labels = torch.full((p.num,), -1, dtype=torch.int64)
        labels[members] = 0
    else:
        labels = SceneObjects.group(p, g, model.config.bg_mask_threshold, arm=arm_state(model, p)).labels
    return list(scene_footprints(g, labels, supports).values())


def overlapping(feet: Sequence[Footprint], at: tuple[float, float], radius: float, support: float) -> int | None:
    """The index of the first footprint on the surface at height ``support`` that an object of ``radius`` metres
    centred at ``at`` comes nearer than :data:`GAP` to, or None."""
    for i, f in enumerate(feet):
        if abs(f.support - support) < SAME_SURFACE and f.clearance(*at) < radius + GAP:
            return i
    return None


def fits_all(
    world: Support, feet: Sequence[Footprint], spots: torch.Tensor, radius: float, height: float
) -> torch.Tensor:
    """(N,) bool: whether an object of ``radius`` metres centred at each of ``spots`` (N, 2) (x, y metres) rests on
    the surface at ``height`` there (the table top: its centre over the table; the floor: clear of the table's side
    by :data:`GAP`) and comes no nearer than :data:`GAP` to any footprint on that surface."""
    x, y = spots[:, 0].double(), spots[:, 1].double()
    ok = torch.ones(spots.shape[0], dtype=torch.bool)
    if world.table_half is not None:
        hx, hy = world.table_half
        over = (x.abs() <= hx) & (y.abs() <= hy)
        gap = torch.hypot((x.abs() - hx).clamp_min(0.0), (y.abs() - hy).clamp_min(0.0))
        ok &= over if abs(height - SUPPORT_Z) < 1e-9 else ~over & (gap >= radius + GAP)
    elif abs(height - SUPPORT_Z) > 1e-9:
        return torch.zeros_like(ok)
    for f in feet:
        if abs(f.support - height) < SAME_SURFACE:
            ok &= torch.hypot(x - f.x, y - f.y) - f.radius >= radius + GAP
    return ok


def fits(world: Support, feet: Sequence[Footprint], at: tuple[float, float], radius: float, height: float) -> bool:
    """Whether an object of ``radius`` metres centred at ``at`` rests on the surface at ``height`` there clear of
    every footprint on it (:func:`fits_all`)."""
    return bool(fits_all(world, feet, torch.tensor([at], dtype=torch.float64), radius, height)[0])


def search_radius(radius: float) -> float:
    """How far from where it was put a free spot may be for an object of ``radius`` metres: :data:`NEAR`, or
    :data:`NEAR_RADII` times its radius for a large one."""
    return max(NEAR, NEAR_RADII * radius)


def nearest_free(
    world: Support,
    feet: Sequence[Footprint],
    radius: float,
    wanted: tuple[float, float],
    near: float | None = None,
) -> tuple[float, float] | None:
    """The spot nearest to ``wanted`` (x, y) where an object of ``radius`` metres rests on the surface under
    ``wanted`` clear of ``feet`` (:func:`fits_all`): ``wanted`` itself when it fits, else the nearest point of a
    :data:`GRID_STEP` grid about it within ``near`` metres (default :func:`search_radius`); None when none is. An
    object over the floor past a table's edge finds its spot on the floor, clear of the table's side."""
    x0, y0 = float(wanted[0]), float(wanted[1])
    height = world.height_at(x0, y0)
    if fits(world, feet, (x0, y0), radius, height):
        return (x0, y0)
    near = search_radius(radius) if near is None else near
    steps = int(near / GRID_STEP)
    ij = torch.arange(-steps, steps + 1, dtype=torch.float64) * GRID_STEP
    dx, dy = (t.reshape(-1) for t in torch.meshgrid(ij, ij, indexing="ij"))
    d = torch.hypot(dx, dy)
    spots = torch.stack([x0 + dx, y0 + dy], -1)
    ok = fits_all(world, feet, spots, radius, height) & (d <= near + 1e-9)
    if not bool(ok.any()):
        return None
    d[~ok] = math.inf
    i = int(d.argmin())
    return (round(float(spots[i, 0]), 4), round(float(spots[i, 1]), 4))


def free_spot(feet: Sequence[Footprint], radius: float, world: Support | None = None) -> tuple[float, float] | None:
    """A spot (x, y) where an object of ``radius`` metres rests on the scene's main surface (the table where there
    is one, wholly on it; else the floor) clear of ``feet``: the one nearest to the objects' mean centre (so it
    stays in the views that frame them); the table's (or the floor's) centre on an empty scene. None when there is
    no room within the objects' bounds widened by twice ``radius`` (and on the table)."""
    world = world or Support()
    main = [f for f in feet if abs(f.support - SUPPORT_Z) < SAME_SURFACE]
    if not main:
        return (0.0, 0.0)
    xs, ys = [f.x for f in main], [f.y for f in main]
    pad = max(f.radius for f in main) + 2.0 * radius + GAP
    lo_x, hi_x, lo_y, hi_y = min(xs) - pad, max(xs) + pad, min(ys) - pad, max(ys) + pad
    if world.table_half is not None:  # wholly on the table
        hx, hy = world.table_half[0] - radius, world.table_half[1] - radius
        lo_x, hi_x, lo_y, hi_y = max(lo_x, -hx), min(hi_x, hx), max(lo_y, -hy), min(hi_y, hy)
    if lo_x > hi_x or lo_y > hi_y:
        return None
    gx = torch.arange(lo_x, hi_x + 1e-9, GRID_STEP, dtype=torch.float64)
    gy = torch.arange(lo_y, hi_y + 1e-9, GRID_STEP, dtype=torch.float64)
    px, py = (t.reshape(-1) for t in torch.meshgrid(gx, gy, indexing="ij"))
    spots = torch.stack([px, py], -1)
    ok = fits_all(world, main, spots, radius, SUPPORT_Z)
    if not bool(ok.any()):
        return None
    d = torch.hypot(px - sum(xs) / len(xs), py - sum(ys) / len(ys))
    d[~ok] = math.inf
    i = int(d.argmin())
    return (round(float(px[i]), 3), round(float(py[i]), 3))


@dataclass(frozen=True)
class Placement:
    """Where a placement puts an object: ``offset`` (3,) metres to move it by (from where it is, or from the object
    a copy copies), the ``surface`` it then rests on (``"table"`` or ``"floor"``) and ``note``, what the user should
    be told ("" when it went where it was put)."""

    offset: tuple[float, float, float]
    surface: str
    note: str


def place(
    scene: EditedParticles, members: list[int], shift: Sequence[float], resting: bool, copy: bool = False
) -> Placement | None:
    """Where the object of particles ``members``, moved by ``shift`` (3,) metres (a copy's offset; zeros after a
    drag), comes to rest: on the surface under its resting centre there (the table, or the floor past its edge), at
    the free spot nearest to it (:func:`nearest_free`, clear of the other objects on that surface; of every object
    with ``copy``, the copied one included). Its bottom goes onto that surface when it was ``resting`` (else it
    keeps its height, never below the surface; one resting within :data:`RESTING_TOLERANCE` of the surface there
    already stays at its height). When no spot within :data:`NEAR` is free it stays where it was put
    and the note says which object is in the way. None when the object draws nothing."""
    g = scene.decode()
    labels = scene.objects().labels
    own = scene.model.decode(scene.particles, torch.tensor(members), background=False).detach().to("cpu")
    foot = footprint_of(own, scene.support_height(members))
    bottom = scene.bottom(members)
    if foot is None or bottom is None:
        return None
    skip = None if copy else int(labels[members[0]])
    feet = scene_footprints(g, labels, scene.particles.support_heights()[:, 0], skip)
    keys, values = list(feet), list(feet.values())
    world = scene.world
    wanted = (foot.x + float(shift[0]), foot.y + float(shift[1]))
    spot = nearest_free(world, values, foot.radius, wanted)
    height = world.height_at(*(spot or wanted))
    surface = world.surface_at(*(spot or wanted)) if world.table_half is not None else "floor"
    lifted = float(shift[2]) if copy else 0.0
    # a resting object already on this surface (as encoded: within a few cm) stays at its height; one over another
    # surface is set down on it; a lifted one keeps its height, never below the surface
    settle = 0.0 if abs(height - bottom) <= RESTING_TOLERANCE else height - bottom
    dz = settle + max(lifted, 0.0) if resting else max(lifted, height - bottom)
    notes = []
    if spot is None:
        spot = wanted
        hit = overlapping(values, wanted, foot.radius, height)
        what = f"object {keys[hit]}" if hit is not None else "the table's side"
        notes.append(f"no free spot within {search_radius(foot.radius):.2f} m on the {surface}: it overlaps {what}")
    elif math.hypot(spot[0] - wanted[0], spot[1] - wanted[1]) > 1e-6:
        notes.append(
            f"moved {math.hypot(spot[0] - wanted[0], spot[1] - wanted[1]):.2f} m to the nearest free spot on the "
            f"{surface}, clear of the objects there"
        )
    if abs(dz - lifted) > DROP_NOTE:  # fell off the table's edge, or climbed onto it
        past = " (past the table's edge)" if surface == "floor" and world.table_half is not None else ""
        notes.append(
            f"it rests on the {surface}{past}, {abs(dz - lifted):.2f} m {'lower' if dz < lifted else 'higher'}"
        )
    offset = (spot[0] - foot.x, spot[1] - foot.y, dz)
    return Placement(offset, surface, "; ".join(notes))


class PlacementError(UserError):
    """No free spot for an object near where it was asked for."""


def insert_spot(
    world: Support, feet: Sequence[Footprint], radius: float, at: tuple[float, float] | None, what: str = "--at"
) -> tuple[tuple[float, float], str]:
    """Where an inserted object of ``radius`` metres goes, and a note for the user ("" when it goes to ``at``): at
    ``at`` (x, y) when it is free, else the free spot nearest to it on the surface there (:func:`nearest_free`);
    without ``at``, the free spot on the scene's main surface nearest its objects (:func:`free_spot`). Raises
    :class:`PlacementError` (one line naming ``what``) when there is none."""
    if at is None:
        spot = free_spot(feet, radius, world)
        if spot is None:
            raise PlacementError(f"{what}: no free spot for the object near the scene's objects: give {what} X,Y")
        return spot, ""
    height = world.height_at(*at)
    surface = world.surface_at(*at) if world.table_half is not None else "floor"
    spot = nearest_free(world, feet, radius, at)
    if spot is None:
        hit = overlapping(feet, at, radius, height)
        what_is_there = f"object {hit} is there" if hit is not None else "the table's side is in the way"
        raise PlacementError(
            f"{what} {at[0]:g},{at[1]:g}: no free spot within {search_radius(radius):.2f} m of it on the {surface} "
            f"({what_is_there}): "
            f"give another {what}, or leave it out for a free spot"
        )
    d = math.hypot(spot[0] - at[0], spot[1] - at[1])
    note = (
        f"{what} {at[0]:g},{at[1]:g} is taken: moved {d:.2f} m to the nearest free spot on the {surface}" if d else ""
    )
    if not note and world.table_half is not None and surface == "floor":
        note = f"{what} {at[0]:g},{at[1]:g} is past the table's edge: it rests on the floor"
    return spot, note
