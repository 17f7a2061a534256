"""The Gaussians of a scene under edit, decoded once and kept current: an edit decodes only what it changed.

An editor decodes its scene for every pick, render and export. Decoding every particle each time made an edit
file replay in time that grew with the square of its operations (each duplicate adds particles that every later
pick decodes again). :class:`DecodedParticles` keeps each particle's Gaussians and decodes a particle again only
when it changes (:meth:`ParticleSplat.decode` of a subset equals the full decode restricted to it, to float32
rounding), and keeps
each particle's footprint box per camera, so that a pick looks only at the particles that reach its pixel.
"""

from __future__ import annotations

from collections.abc import Iterable

import torch
from torch import Tensor

from particlesplat.core.camera import Camera
from particlesplat.core.gaussians import Gaussians
from particlesplat.model import Particles, ParticleSplat
from particlesplat.rendering.projection import footprint_extents, project_gaussians

_FIELDS = ("means", "quats", "scales", "opacities", "sh")


def _same(a: Tensor, b: Tensor | None) -> bool:
    return b is not None and a.shape == b.shape and torch.equal(a, b)


class DecodedParticles:
    """Per-particle Gaussians of one scene's particles, on the CPU.

    Rows are decoded with every particle drawing; :meth:`gaussians` keeps those of the particles at or above
    ``z_t_threshold``, so the result equals ``model.decode(particles, z_t_threshold=z_t_threshold)`` (to float32
    rounding: the rows were decoded in batches of other sizes).

    Args:
        model: the model that decodes the particles.
        z_t_threshold: the particles that draw (None: the model's ``bg_mask_threshold``).
    """

    def __init__(self, model: ParticleSplat, z_t_threshold: float | None = None) -> None:
        self.model = model
        self.z_t_threshold = model.config.bg_mask_threshold if z_t_threshold is None else z_t_threshold
        self._rows: dict[str, Tensor] = {}  # field -> (N, G, ...) per particle row
        self._stale: set[int] = set()
        self.rows_decoded = 0  # particles decoded so far (each edit decodes only the particles it changed)
        self.backgrounds_decoded = 0  # times the background was decoded (once, or again when its table fill changed)
        # while True (a drag under way: SceneEditor sets it), the background is not decoded again when the table fill
        # changes; the first decode after it is cleared is exact again
        self.hold_table_fill = False
        self._background: Gaussians | None = None
        # the blocks drawn as the table where an object stood when the background was decoded (None: no such blocks)
        self._background_fill: Tensor | None = None
        self._boxes: dict[int, Tensor] = {}  # camera key -> (N, 4) x0, y0, x1, y1 footprint box per row (pixels)
        self._boxed: dict[int, Tensor] = {}  # camera key -> (N,) bool: the row's box is current

    @property
    def num_rows(self) -> int:
        return int(self._rows["means"].shape[0]) if self._rows else 0

    def invalidate(self, indices: Iterable[int]) -> None:
        """Particles whose attributes changed: decoded again on the next :meth:`gaussians`."""
        rows = [int(i) for i in indices]
        self._stale.update(rows)
        for valid in self._boxed.values():
            valid[[i for i in rows if i < valid.numel()]] = False

    def truncate(self, num: int) -> None:
        """Drop the rows of particles ``num`` and up (they were removed; a row added later is decoded anew)."""
        if self._rows and self.num_rows > num:
            self._rows = {k: v[:num] for k, v in self._rows.items()}
        self._stale = {i for i in self._stale if i < num}
        self._boxes = {k: v[:num] for k, v in self._boxes.items()}
        self._boxed = {k: v[:num] for k, v in self._boxed.items()}

    def _decode_rows(self, particles: Particles, indices: Tensor) -> dict[str, Tensor]:
        g = self.model.decode(particles, indices, background=False, z_t_threshold=0.0).detach().to("cpu")
        per = self.model.config.gaussians_per_particle
        n = int(indices.numel())
        return {k: getattr(g, k).reshape(n, per, *getattr(g, k).shape[1:]) for k in _FIELDS}

    def background(self, particles: Particles) -> Gaussians:
        """The background Gaussians of ``particles`` (owner -1): decoded once, and again when the blocks it draws as
        the table where an object stood change (a model with ``background.opaque_under_objects``:
        :meth:`ParticleSplat.table_fill_key`), but not while :attr:`hold_table_fill`."""
        held = self._background is not None and self.hold_table_fill
        fill = self._background_fill if held else self.model.table_fill_key(particles)
        if self._background is None or (fill is not None and not _same(fill, self._background_fill)):
            self._background = self.model.decode(particles, torch.zeros(0, dtype=torch.long)).detach().to("cpu")
            self._background_fill = fill
            self.backgrounds_decoded += 1
        return self._background

    def _refresh(self, particles: Particles) -> None:
        """Bring the background (:meth:`background`) and the rows of particles that changed or are new up to date."""
        self.background(particles)
        num = particles.num
        self.truncate(num)
        fresh = sorted(self._stale.union(range(self.num_rows, num)))
        if not fresh:
            return
        idx = torch.tensor(fresh, dtype=torch.long)
        rows = self._decode_rows(particles, idx)
        self.rows_decoded += len(fresh)
        if not self._rows:
            self._rows = rows
        else:
            grown = num - self.num_rows
            if grown > 0:
                self._rows = {k: torch.cat([v, v.new_zeros((grown, *v.shape[1:]))]) for k, v in self._rows.items()}
            for k in _FIELDS:
                self._rows[k][idx] = rows[k]
        self._stale.clear()

    def _assemble(self, particles: Particles, rows: Tensor) -> Gaussians:
        """The Gaussians of particle rows ``rows`` (ascending) that draw, then the background."""
        assert self._background is not None
        if self.z_t_threshold > 0.0:
            rows = rows[particles.z_t[rows, 0].detach().cpu() >= self.z_t_threshold]
        if not self._rows or not rows.numel():
            return self._background
        return Gaussians.cat([self._row_gaussians(rows), self._background])

    def _row_gaussians(self, rows: Tensor) -> Gaussians:
        """The Gaussians of particle rows ``rows`` (M,), owner = row."""
        f = {k: self._rows[k][rows].reshape(-1, *self._rows[k].shape[2:]) for k in _FIELDS}
        per = self.model.config.gaussians_per_particle
        return Gaussians(f["means"], f["quats"], f["scales"], f["opacities"], f["sh"], rows.repeat_interleave(per))

    def gaussians(self, particles: Particles) -> Gaussians:
        """The Gaussians of ``particles`` (the drawing particles', owner = particle index, then the background,
        owner -1), as :meth:`ParticleSplat.decode` gives them (while :attr:`hold_table_fill`, with the background as
        last decoded)."""
        self._refresh(particles)
        return self._assemble(particles, torch.arange(particles.num))

    def _footprint_boxes(self, camera: Camera, key: int, num: int) -> Tensor:
        """(num, 4) float64 box x0, y0, x1, y1 (pixels) per particle row around where its Gaussians reach
        α ≥ 1/255 in ``camera`` (empty: x0 > x1); only rows that changed are projected again."""
        per = self.model.config.gaussians_per_particle
        boxes, valid = self._boxes.get(key), self._boxed.get(key)
        if boxes is None or valid is None:
            boxes, valid = torch.zeros(0, 4, dtype=torch.float64), torch.zeros(0, dtype=torch.bool)
        if boxes.shape[0] < num:  # new rows: boxes to compute
            grown = num - boxes.shape[0]
            boxes = torch.cat([boxes, boxes.new_zeros(grown, 4)])
            valid = torch.cat([valid, valid.new_zeros(grown)])
        todo = torch.nonzero(~valid).flatten()
        if todo.numel():
            rows = self._row_gaussians(todo)
            proj = project_gaussians(rows, camera.to("cpu", rows.means.dtype))
            ext = footprint_extents(proj, rows.opacities[proj.index]).double()
            reach = ext[:, 0] >= 0
            row = (proj.index // per)[reach][:, None].expand(-1, 2)
            box = torch.empty(todo.numel(), 4, dtype=torch.float64)
            box[:, :2], box[:, 2:] = float("inf"), -float("inf")  # no footprint: an empty box
            box[:, :2] = box[:, :2].scatter_reduce(0, row, proj.means2d[reach] - ext[reach], "amin")
            box[:, 2:] = box[:, 2:].scatter_reduce(0, row, proj.means2d[reach] + ext[reach], "amax")
            boxes[todo], valid[todo] = box, True
        self._boxes[key], self._boxed[key] = boxes, valid
        return boxes

    def reaching(self, particles: Particles, camera: Camera, key: int, pixel: tuple[int, int]) -> Gaussians:
        """The Gaussians of the drawing particles whose footprint box in ``camera`` holds the centre of ``pixel``
        (x, y), then the background: every Gaussian that can reach α ≥ 1/255 there, in :meth:`gaussians` order.
        ``key`` names the camera (its boxes are kept until a particle changes)."""
        self._refresh(particles)
        if not self._rows:
            return self._assemble(particles, torch.zeros(0, dtype=torch.long))
        boxes = self._footprint_boxes(camera, key, particles.num)
        px, py = pixel[0] + 0.5, pixel[1] + 0.5
        near = (boxes[:, 0] <= px) & (px <= boxes[:, 2]) & (boxes[:, 1] <= py) & (py <= boxes[:, 3])
        return self._assemble(particles, torch.nonzero(near).flatten())
