"""Which particles are one object: particles whose opaque Gaussians overlap in 3D are grouped.

ParticleSplat encodes L particles per context view, so an object seen by two context views is
usually held by two particles (one per view), and a large object sometimes by two particles of one
view. Both describe the same 3D surface, so their Gaussians interleave over a large part of it, while
particles of different objects meet at most along a line of contact. The grouping is a union-find over
overlapping pairs: an opaque Gaussian of one particle *touches* the other when it lies within ``reach``
x (sum of the two Gaussians' largest standard deviations) of an opaque Gaussian of the other, and two
particles overlap when at least ``overlap`` of the opaque Gaussians of either of them touch the other.

:func:`particle_objects` labels each group by its smallest particle index; :func:`dense_objects` turns those
labels into the one object numbering every tool shows and writes (0..K-1 in the order of the groups' smallest
particle index, -1 for particles that draw nothing). :func:`members_centre` is the one object centre.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch
from torch import Tensor

from particlesplat.core.choices import OBJECT_CENTRES, ObjectCentre
from particlesplat.core.gaussians import Gaussians
from particlesplat.core.panda_arm import ARM_STATE_DIMS, ARM_STATE_KEY, capsule_distance
from particlesplat.core.world import SUPPORT_Z
from particlesplat.model import Particles
from particlesplat.model.evidence import arm_capsules_of

if TYPE_CHECKING:
    from particlesplat.model import ParticleSplat

# Defaults measured on the tabletop family (docs/model-development.md, "The overlap rule of the grouping"; 96
# training and 32 validation scenes; pairs of particles each >= 60 % on one true object): opaque means opacity
# (z_t included) >= 0.2. Of 2074 pairs of particles on one object, 95 % had Gaussians within 0.22 x (sum of their
# largest stds) of each other, and in 94 % at least 30 % of one particle's opaque Gaussians touched the other
# (median 89 %); of 5825 pairs on different objects 27 touched, 22 of them with at most 11 %.
OPAQUE = 0.2
REACH = 1.0
OVERLAP = 0.3
CHUNK = 2048  # Gaussians per block of the pairwise distance test (bounds its memory)
DRAW_OPACITY = 1.0 / 255.0  # a Gaussian draws nowhere below this opacity (the renderer's alpha cut-off)
TOP_QUANTILE = 0.95  # an object's top: this quantile of its opaque Gaussians' heights


def touching_counts(means: Tensor, radius: Tensor, owner: Tensor, num_particles: int) -> Tensor:
    """How many Gaussians of each particle touch each other particle: (P, P) int64, entry [a, b] = the number
    of Gaussians of particle a with a Gaussian of particle b within the sum of their radii.

    means: (M, 3) metres; radius: (M,) metres; owner: (M,) int64 in [0, num_particles).
    """
    M = means.shape[0]
    onehot = torch.nn.functional.one_hot(owner, num_particles).to(means.dtype)  # (M, P)
    reaches = torch.zeros(M, num_particles, dtype=torch.bool, device=means.device)
    for s in range(0, M, CHUNK):
        near = torch.cdist(means[s : s + CHUNK], means) < radius[s : s + CHUNK, None] + radius[None, :]  # (m, M)
        reaches[s : s + CHUNK] = (near.to(means.dtype) @ onehot) > 0
    reaches &= ~onehot.bool()  # a particle does not touch itself
    return (onehot.T @ reaches.to(means.dtype)).round().long()


def particle_objects(
    gaussians: Gaussians, num_particles: int, *, opaque: float = OPAQUE, reach: float = REACH, overlap: float = OVERLAP
) -> Tensor:
    """Object label of each particle: (num_particles,) int64, the smallest particle index of its group.

    gaussians: the decoded scene (owner = particle index, -1 background; background ignored).
    A particle with no Gaussian of opacity >= ``opaque`` is an object of its own. Two particles are joined
    when at least ``overlap`` (a fraction in [0, 1]) of the opaque Gaussians of either touch the other, and
    always at least one: ``overlap`` 0 joins particles with a single touching pair. ``reach`` 0 groups
    nothing (every particle its own object).
    """
    if num_particles < 0:
        raise ValueError(f"num_particles must be >= 0, got {num_particles}")
    if reach < 0:
        raise ValueError(f"reach must be >= 0, got {reach}")
    if not 0.0 <= overlap <= 1.0:
        raise ValueError(f"overlap must be a fraction in [0, 1], got {overlap}")
    parent = list(range(num_particles))

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    keep = (gaussians.owner >= 0) & (gaussians.owner < num_particles) & (gaussians.opacities >= opaque)
    if reach > 0 and int(keep.sum()) > 1:
        means = gaussians.means[keep].detach().double()  # (M, 3) metres
        radius = gaussians.scales[keep].detach().double().amax(-1) * reach  # (M,) metres
        owner = gaussians.owner[keep]  # (M,)
        counts = touching_counts(means, radius, owner, num_particles)  # (P, P)
        sizes = torch.bincount(owner, minlength=num_particles).double()  # (P,) opaque Gaussians
        frac = counts.double() / sizes.clamp_min(1)[:, None]  # (P, P) share of a's Gaussians touching b
        joined = (counts > 0) & ((frac >= overlap) | (frac.T >= overlap))
        for a, b in torch.triu(joined, diagonal=1).nonzero().tolist():
            ra, rb = root(a), root(b)
            if ra != rb:
                parent[max(ra, rb)] = min(ra, rb)
    return torch.tensor([root(i) for i in range(num_particles)], dtype=torch.int64)


def weighted_stats(means: Tensor, weights: Tensor, group: Tensor, num_groups: int) -> tuple[Tensor, Tensor, Tensor]:
    """Weighted mean and standard deviation per group, float64.

    means: (M, 3) metres; weights: (M,) >= 0; group: (M,) int64 in [0, num_groups) (others ignored).
    Returns mean (G, 3), std (G, 3) along each axis, total weight (G,); a group without weight gets zeros.
    """
    keep = (group >= 0) & (group < num_groups)
    x, w, g = means[keep].double(), weights[keep].double(), group[keep]
    total = torch.zeros(num_groups, dtype=torch.float64, device=x.device).index_add_(0, g, w)
    s1 = torch.zeros(num_groups, 3, dtype=torch.float64, device=x.device).index_add_(0, g, w[:, None] * x)
    safe = torch.where(total > 0, total, torch.ones_like(total))[:, None]
    mean = torch.where(total[:, None] > 0, s1 / safe, torch.zeros_like(s1))
    s2 = torch.zeros_like(s1).index_add_(0, g, w[:, None] * (x - mean[g]) ** 2)
    std = torch.where(total[:, None] > 0, (s2 / safe).clamp_min(0).sqrt(), torch.zeros_like(s2))
    return mean, std, total


def drawing_particles(particles: Particles, gaussians: Gaussians, bg_mask_threshold: float) -> Tensor:
    """(P,) bool: the particles that draw, i.e. ``z_t`` >= the model's ``bg_mask_threshold`` and at least
    one of their Gaussians is opaque enough to draw (opacity >= 1/255, the renderer's cut-off).

    gaussians: the decoded scene (owner = particle index).
    """
    P = particles.num
    own = gaussians.owner
    draws = (own >= 0) & (own < P) & (gaussians.opacities >= DRAW_OPACITY)
    has = torch.zeros(P, dtype=torch.bool, device=own.device)
    has[own[draws]] = True
    return has.cpu() & (particles.z_t[:, 0].detach().cpu() >= bg_mask_threshold)


def arm_state(model: ParticleSplat, particles: Particles) -> Tensor | None:
    """The robot state (:data:`~particlesplat.core.panda_arm.ARM_STATE_DIMS`,) the particles were encoded with, when
    ``model`` reads one (``bg_static_pose: robot_state``); else None."""
    cfg = model.config
    if cfg.bg_static_pose != ARM_STATE_KEY or particles.pose is None or particles.pose.numel() != ARM_STATE_DIMS:
        return None
    return particles.pose


def robot_particles(particles: Particles, gaussians: Gaussians, arm: Tensor | None) -> Tensor:
    """(P,) bool: the particles that draw the robot, not an object: the opacity-weighted centre of their
    Gaussians lies in the room the arm takes (:func:`particlesplat.core.panda_arm.capsule_distance`), which the
    robot state ``arm`` (:func:`arm_state`; None: no particle is the robot's) gives."""
    P = particles.num
    if arm is None:
        return torch.zeros(P, dtype=torch.bool)
    centre, _, total = weighted_stats(gaussians.means.cpu(), gaussians.opacities.cpu(), gaussians.owner.cpu(), P)
    starts, ends, radii = (t.double() for t in arm_capsules_of(arm.cpu()))
    inside = capsule_distance(centre, starts, ends, radii) < 0
    return inside & (total > 0)


def dense_objects(groups: Tensor, active: Tensor) -> Tensor:
    """(P,) int64 object index 0..K-1 of each active particle, numbered in the order of the groups' smallest
    particle index; -1 for inactive particles. groups: (P,) labels of :func:`particle_objects`; active: (P,)."""
    out = torch.full_like(groups, -1)
    labels = sorted(set(groups[active].tolist()))
    for k, lab in enumerate(labels):
        out[(groups == lab) & active] = k
    return out


def object_centres(
    gaussians: Gaussians,
    objects: Tensor,
    num_objects: int,
    method: ObjectCentre = "resting",
    support: float | None = None,
) -> tuple[Tensor, Tensor]:
    """Centre (K, 3) and extent (K, 3) of each object, float64 metres.

    objects: (P,) int64 object index per particle (-1 = none; :func:`dense_objects`). The extent is the
    opacity-weighted standard deviation of the object's Gaussians along x, y, z. The centre:

    - ``"weighted"``: the opacity-weighted mean of the object's Gaussians. The Gaussians cover the surfaces
      the context views see, so this lies above and in front of the true centre.
    - ``"resting"``: x, y of the opacity-weighted mean of the object's opaque Gaussians (opacity >= 0.2), and
      z half-way between the support surface (``support``, default
      :data:`particlesplat.core.world.SUPPORT_Z`) and the object's top (the 0.95 quantile of those Gaussians'
      z): the centre of an object standing on the support, as objects stand in every scene family.
    """
    if method not in OBJECT_CENTRES:
        raise ValueError(f"object centre method must be one of {', '.join(OBJECT_CENTRES)}, got {method!r}")
    own = gaussians.owner
    valid = (own >= 0) & (own < objects.shape[0])
    group = torch.full_like(own, -1)
    group[valid] = objects.to(own.device)[own[valid]]
    mean, std, _ = weighted_stats(gaussians.means, gaussians.opacities, group, num_objects)
    if method == "weighted" or num_objects == 0:
        return mean, std
    base = SUPPORT_Z if support is None else float(support)
    opaque = gaussians.opacities >= OPAQUE
    centre = mean.clone()
    for k in range(num_objects):
        sel = (group == k) & opaque
        if not bool(sel.any()):
            sel = group == k
        if not bool(sel.any()):
            continue
        x, w = gaussians.means[sel].double(), gaussians.opacities[sel].double()
        if float(w.sum()) > 0:
            centre[k, :2] = (w[:, None] * x[:, :2]).sum(0) / w.sum()
        top = float(torch.quantile(x[:, 2], TOP_QUANTILE))
        centre[k, 2] = 0.5 * (top + base)
    return centre, std


def members_centre(
    model: ParticleSplat,
    particles: Particles,
    members: list[int],
    support: float,
    method: ObjectCentre = "resting",
) -> Tensor | None:
    """(3,) float64 world metres: the centre (:func:`object_centres`, ``method``) of the object made of particles
    ``members`` as ``particles`` draw it, resting on the support surface at height ``support`` (metres); None when
    it draws nothing."""
    g = model.decode(particles, torch.tensor(members), background=False).detach().to("cpu")
    if g.num == 0:
        return None
    labels = torch.full((particles.num,), -1, dtype=torch.int64)
    labels[members] = 0
    return object_centres(g, labels, 1, method, support)[0][0]
