"""Which particles are one object: particles whose opaque Gaussians overlap in 3D are grouped.

ParticleSplat encodes L particles per context view, so an object seen by two context views is
usually held by two particles (one per view), and a large object sometimes by two particles of one
view. Both describe the same 3D surface, so their Gaussians interleave over a large part of it, while
particles of different objects meet at most along a line of contact. The grouping is a union-find over
overlapping pairs: an opaque Gaussian of one particle *touches* the other when it lies within ``reach``
x (sum of the two Gaussians' largest standard deviations) of an opaque Gaussian of the other, and two
particles overlap when at least ``overlap`` of the opaque Gaussians of either of them touch the other.

Objects are labelled by their smallest particle index, so an object label is also an owner index and
a segmentation over objects reads like one over particles.
"""

from __future__ import annotations

import torch
from torch import Tensor

from .gaussians import Gaussians

# Defaults measured on the tabletop family (docs/model-development.md, "The overlap rule of the grouping"; 96
# training and 32 validation scenes; pairs of particles each >= 60 % on one true object): opaque means opacity
# (z_t included) >= 0.2. Of 2074 pairs of particles on one object, 95 % had Gaussians within 0.22 x (sum of their
# largest stds) of each other, and in 94 % at least 30 % of one particle's opaque Gaussians touched the other
# (median 89 %); of 5825 pairs on different objects 27 touched, 22 of them with at most 11 %.
OPAQUE = 0.2
REACH = 1.0
OVERLAP = 0.3
CHUNK = 2048  # Gaussians per block of the pairwise distance test (bounds its memory)


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
