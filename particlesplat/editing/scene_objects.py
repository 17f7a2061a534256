"""The objects of a scene: its particles grouped (:func:`particlesplat.editing.grouping.particle_objects`) and
numbered as every tool shows and writes them (:func:`particlesplat.editing.grouping.dense_objects`), the one way
any command turns particles into objects."""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from particlesplat.core.gaussians import Gaussians
from particlesplat.editing.grouping import dense_objects, drawing_particles, particle_objects, robot_particles
from particlesplat.model.particles import Particles


@dataclass(frozen=True)
class SceneObjects:
    """(P,) int64 ``labels``: the object number 0..K-1 of each particle that draws, in the order of each object's
    smallest particle index; -1 for a particle that draws nothing (``particlesplat encode``'s ``object`` array)."""

    labels: Tensor

    @classmethod
    def group(
        cls,
        particles: Particles,
        gaussians: Gaussians,
        bg_mask_threshold: float,
        groups: Tensor | None = None,
        arm: Tensor | None = None,
    ) -> SceneObjects:
        """Group ``particles`` whose decode (owner = particle index, background included or not) is ``gaussians``;
        a particle draws at z_t >= ``bg_mask_threshold`` (the model's). ``groups``: the
        :func:`particle_objects` labels when already computed. ``arm``: the robot state
        (:func:`~particlesplat.editing.grouping.arm_state`): the robot's particles are in no object."""
        g = gaussians.detach().to("cpu")
        p = particles.detach().to("cpu")
        groups = particle_objects(g, p.num) if groups is None else groups.cpu()
        objects = drawing_particles(p, g, bg_mask_threshold) & ~robot_particles(p, g, arm)
        return cls(dense_objects(groups, objects))

    @property
    def count(self) -> int:
        """K, the number of objects."""
        return int(self.labels.max()) + 1 if self.labels.numel() and bool((self.labels >= 0).any()) else 0

    def dense(self) -> SceneObjects:
        """The same groups numbered 0..K-1 in the order of each one's smallest particle index (as
        :meth:`group` numbers them), for labels that merges, splits and copies left with gaps or out of order."""
        out = torch.full_like(self.labels, -1)
        firsts = {int(torch.nonzero(self.labels == k)[0]): int(k) for k in self.labels.unique() if k >= 0}
        for n, first in enumerate(sorted(firsts)):
            out[self.labels == firsts[first]] = n
        return SceneObjects(out)

    def members(self, index: int) -> list[int]:
        """The particles of particle ``index``'s object, ascending; a particle that draws nothing is alone."""
        if int(self.labels[index]) < 0:
            return [index]
        return [int(j) for j in torch.nonzero(self.labels == self.labels[index]).flatten()]

    def of_object(self, k: int) -> list[int]:
        """The particles of object ``k``, ascending (none when there is no such object)."""
        return [int(j) for j in torch.nonzero(self.labels == k).flatten()]
