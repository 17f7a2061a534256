"""The particles of one scene under edit: what operations change (attribute values, appended particles, object
labels) and what follows them (the kept Gaussians, which particles changed, a version number).

Operations (:mod:`particlesplat.editing.operations`) change these only through :meth:`EditedParticles.apply`, so
doing and undoing keep the Gaussians, the object labels and the rows' origins in step.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import torch
from torch import Tensor

from particlesplat.core.gaussians import BACKGROUND_OWNER, Gaussians
from particlesplat.core.vectors import float3
from particlesplat.core.world import SUPPORT_Z, Support
from particlesplat.editing.crop_box import CropBox
from particlesplat.editing.decoded import DecodedParticles
from particlesplat.editing.grouping import OPAQUE, arm_state, members_centre
from particlesplat.editing.move import MoveError, anchor_points
from particlesplat.editing.scene_objects import SceneObjects
from particlesplat.model.config import ModelConfig
from particlesplat.model.particles import Particles

if TYPE_CHECKING:
    from particlesplat.model.particlesplat import ParticleSplat

# An edited scene holds at most this many particles (64 times what two context views encode; about 0.5 M Gaussians
# at 512 a particle). The cap bounds what one operation costs (a pick composites the Gaussians at one pixel, at
# worst all of them), so an edit file replays in time linear in its operations.
MAX_EDIT_PARTICLES = 1024
BOTTOM_QUANTILE = 0.02  # an object's bottom: this quantile of its opaque Gaussians' heights
SUNK_TOLERANCE = 0.02  # metres an object's bottom may sit below its support before it is flagged (encoded objects
# rest within about 1 cm of it)
RESTING_TOLERANCE = 0.03  # metres: an object whose bottom is this near its surface rests on it (a placement keeps it
# there); one lifted higher stays lifted


@dataclass(frozen=True)
class SetAttribute:
    """One attribute change of one particle: ``old`` and ``new`` values of attribute ``name`` of particle ``index``."""

    index: int
    name: str
    old: tuple[float, ...]
    new: tuple[float, ...]


@dataclass(frozen=True)
class Rows:
    """Particles an operation appends: their values before the operation's changes, their object labels
    ((len(particles),) int64) and their rows in :meth:`EditedParticles.origin`."""

    particles: Particles
    labels: Tensor
    sources: tuple[int, ...]


class EditedParticles:
    """The particles under edit (``particles``) beside the encoded ones (``original``).

    Args:
        model: the model that decodes them.
        particles: the encoded particles (kept on the CPU as the original).
        z_t_threshold: the particles that draw (None: the model's, :meth:`ParticleSplat.decode`).
        world: what the scene's objects rest on (:class:`particlesplat.core.world.Support`; default a floor at the
            shared support height everywhere).
    """

    def __init__(
        self,
        model: ParticleSplat,
        particles: Particles,
        z_t_threshold: float | None = None,
        world: Support | None = None,
    ) -> None:
        self.model = model
        self.world = world or Support()  # what objects rest on: the table and the floor around it, or a floor
        self.z_t_threshold = z_t_threshold
        self.original = particles.detach().to("cpu")
        self.particles = self.original.clone()
        self.decoded = DecodedParticles(model, z_t_threshold)
        self.source: list[int] = list(range(self.original.num))  # each row's row in origin()
        self.inserted: Particles | None = None  # inserted particles as inserted: origin() rows past the original
        self._labels: Tensor | None = None  # object labels of the rows (grouped once, on the original)
        self._changed: set[int] = set()
        self._all_changed = True
        self._fill_stale = False  # the particles changed since take_changes last brought the background up to date
        self._reported_backgrounds = 0  # the background's decode (DecodedParticles.backgrounds_decoded) last reported
        self.version = 0  # bumps on every change of the Gaussians
        self.crop: CropBox | None = None  # the crop box an edit set (None: none set; render and export apply it)

    # ------------------------------------------------------------------ values
    @property
    def num(self) -> int:
        return self.particles.num

    @property
    def active_threshold(self) -> float:
        """z_t at and above which a particle draws: the model's ``bg_mask_threshold``."""
        return float(self.model.config.bg_mask_threshold)

    def value(self, index: int, name: str) -> tuple[float, ...]:
        return tuple(float(v) for v in self.particles.attribute(index, name).tolist())

    def origin(self) -> Particles:
        """The particles as encoded, followed by every particle inserted from another scene as it was inserted."""
        return self.original if self.inserted is None else self.original.cat(self.inserted)

    def original_value(self, index: int, name: str) -> tuple[float, ...]:
        """The encoded value (a copy's: that of the particle it was copied from; an inserted one's: as inserted)."""
        return tuple(float(v) for v in self.origin().attribute(self.source[index], name).tolist())

    def add_inserted(self, particles: Particles) -> tuple[int, ...]:
        """Keep ``particles`` (inserted from another scene, as inserted) in :meth:`origin`; returns their rows."""
        rows = self.original.num + (0 if self.inserted is None else self.inserted.num)
        self.inserted = particles if self.inserted is None else self.inserted.cat(particles)
        return tuple(range(rows, rows + particles.num))

    def decode(self, particles: Particles | None = None) -> Gaussians:
        """All Gaussians (background included) on the CPU; of the current particles (the default) from the kept
        Gaussians, updated edit by edit."""
        if particles is None or particles is self.particles:
            return self.decoded.gaussians(self.particles)
        return self.model.decode(particles, z_t_threshold=self.z_t_threshold).detach().to("cpu")

    # ------------------------------------------------------------------ objects
    def objects(self) -> SceneObjects:
        """The rows' objects: grouped once on the scene as encoded (an edit does not regroup it); an appended
        object takes the labels its operation gave it."""
        if self._labels is None:
            if self.particles.num != self.original.num:
                raise RuntimeError("EditedParticles: rows were appended before the scene was grouped")
            arm = arm_state(self.model, self.original)
            g = self.decode(self.original)
            self._labels = SceneObjects.group(self.original, g, self.active_threshold, arm=arm).labels
        return SceneObjects(self._labels)

    def labels_now(self) -> Tensor | None:
        """The rows' object labels as they are (not to be changed: a regroup makes new ones); None before the scene
        was first grouped (then every row is as encoded and grouped so)."""
        return self._labels

    def next_object(self) -> int:
        """The number a new (copied or inserted) object takes: one past the largest."""
        labels = self.objects().labels
        return int(labels.max()) + 1 if labels.numel() else 0

    def bottom(self, members: list[int]) -> float | None:
        """World height (metres) of the lowest part of the object of particles ``members`` where its edits put it:
        the ``BOTTOM_QUANTILE`` of the heights of its opaque Gaussians as each particle drew when encoded (a few
        stray ones do not count), carried along by what the edits did to that particle since (its anchor's move,
        its size's growth about it); None if it draws nothing opaque.

        Not the heights it draws at now: a model that presses Gaussians onto the support surface
        (``support_clamp``) draws a sunk object as a smear on the surface, at the surface's height."""
        active = [i for i in members if float(self.particles.z_t[i, 0]) >= self.active_threshold]
        if not active:
            return None
        cfg, origin = self.model.config, self.origin()
        rows = [self.source[i] for i in active]
        g = self.model.decode(origin, torch.tensor(rows), background=False, z_t_threshold=0.0)
        now, was = anchor_points(self.particles, active, cfg), anchor_points(origin, rows, cfg)
        heights = []
        for k, (i, r) in enumerate(zip(active, rows, strict=True)):
            z = g.means[:, 2][(g.owner == r) & (g.opacities >= OPAQUE)].detach().double()
            grow = _size(self.particles, i, cfg) / _size(origin, r, cfg)
            heights.append(float(now[k, 2]) + grow * (z - float(was[k, 2])))
        z = torch.cat(heights)
        return float(torch.quantile(z, BOTTOM_QUANTILE)) if z.numel() else None

    def offset(self, index: int) -> tuple[float, float, float]:
        """World offset (metres) of particle ``index``'s anchor from where it (or what it copies) was encoded."""
        cfg = self.model.config
        now = anchor_points(self.particles, [index], cfg)[0]
        was = anchor_points(self.origin(), [self.source[index]], cfg)[0]
        return float3(now - was)

    def sunk_objects(self, tolerance: float = SUNK_TOLERANCE) -> list[str]:
        """One line for each object whose bottom (:meth:`bottom`) is more than ``tolerance`` metres below the
        surface it rests on (:meth:`support_height`): an edit file or a hand-set latent that sank it."""
        labels = self.objects().labels
        out = []
        for k in sorted({int(v) for v in labels.tolist() if v >= 0}):
            members = torch.nonzero(labels == k).flatten()
            bottom = self.bottom(members.tolist())
            support = self.support_height(members.tolist())
            if bottom is not None and bottom < support - tolerance:
                names = ", ".join(str(int(i)) for i in members)
                out.append(
                    f"object {k} (particle{'s' if len(members) > 1 else ''} {names}) has its bottom at z = "
                    f"{bottom:.2f} m, below its support at {support:.2f} m"
                )
        return out

    def support_height(self, members: Sequence[int] | None = None) -> float:
        """The height (world z, metres) of the surface the object of particles ``members`` rests on (the highest
        of theirs, :attr:`Particles.support`: the table top, or the floor it was placed on); without ``members``,
        the shared support surface (:data:`particlesplat.core.world.SUPPORT_Z`), where every object rests as
        encoded."""
        if not members:
            return SUPPORT_Z
        return float(self.particles.support_heights()[list(members), 0].max())

    def resting(self, members: Sequence[int]) -> bool:
        """Whether the object of particles ``members`` rests on its surface (its bottom within
        :data:`RESTING_TOLERANCE` of it), not lifted off it."""
        bottom = self.bottom(list(members))
        return bottom is not None and abs(bottom - self.support_height(members)) <= RESTING_TOLERANCE

    def support_changes(
        self, particles: Particles, members: Sequence[int], offset: Sequence[float]
    ) -> list[SetAttribute]:
        """The changes that give particles ``members`` of ``particles``, moved by ``offset`` (3,) metres, the height
        of the surface under the moved object's resting centre (:meth:`Support.height_at`): the table top, or the
        floor past its edge. None needed in a world without a table, nor when the object draws nothing."""
        if self.world.table_half is None or not members:
            return []
        now = particles.support_heights()
        centre = members_centre(self.model, particles, list(members), float(now[list(members), 0].max()))
        if centre is None:
            return []
        height = self.world.height_at(float(centre[0]) + float(offset[0]), float(centre[1]) + float(offset[1]))
        return [
            SetAttribute(i, "support", (float(now[i, 0]),), (height,))
            for i in members
            if abs(float(now[i, 0]) - height) > 1e-9
        ]

    # ------------------------------------------------------------------ changes
    def apply(self, changes: Sequence[SetAttribute], forward: bool, rows: Rows | None = None) -> None:
        """Do (``forward``) or undo attribute ``changes``, with the ``rows`` they append (appended before the
        changes are done, dropped after they are undone)."""
        particles = self.particles
        if forward and rows is not None:
            labels = self.objects().labels  # grouped before the rows arrive
            particles = particles.cat(rows.particles)  # the new rows are decoded on first use
            self.source += list(rows.sources)
            self._labels = torch.cat([labels, rows.labels])
            self._all_changed = True
        for ch in changes if forward else reversed(changes):
            particles = particles.with_attribute(ch.index, ch.name, ch.new if forward else ch.old)
            self._changed.add(ch.index)
        self.decoded.invalidate(ch.index for ch in changes)
        if not forward and rows is not None:
            particles = particles.truncate(particles.num - rows.particles.num)
            self.decoded.truncate(particles.num)
            del self.source[particles.num :]
            self._labels = self.objects().labels[: particles.num]
            self._all_changed = True
        self.particles = particles
        self._fill_stale = True
        self.version += 1

    def hold_table_fill(self, hold: bool) -> None:
        """Keep the background as decoded while a drag is under way (``hold``), or draw again the table the edits
        uncovered (``background.opaque_under_objects``, :attr:`DecodedParticles.hold_table_fill`): releasing the hold
        of such a model counts as a change, so a viewer asks :meth:`take_changes` again."""
        if self.decoded.hold_table_fill and not hold and self.model.config.bg_opaque_under_objects:
            self.version += 1
        self.decoded.hold_table_fill = hold

    def _background_changed(self) -> bool:
        """Whether the background was decoded again since the last report (the table under a moved object,
        ``background.opaque_under_objects``): brought up to date when the particles changed, never while held."""
        if self._fill_stale and not self.decoded.hold_table_fill:
            self._fill_stale = False
            self.decoded.background(self.particles)
        changed = self.decoded.backgrounds_decoded != self._reported_backgrounds
        self._reported_backgrounds = self.decoded.backgrounds_decoded
        return changed

    def set_crop(self, box: CropBox | None) -> None:
        """Set the crop box (None: as if none was ever set); what is drawn changes, the particles do not."""
        self.crop = box
        self._all_changed = True
        self.version += 1

    def relabel(self, indices: Sequence[int], labels: Sequence[int]) -> None:
        """Set the object labels of particles ``indices`` (a change of which particles form an object)."""
        new = self.objects().labels.clone()
        new[list(indices)] = torch.tensor(list(labels), dtype=torch.int64)
        self._labels = new
        self._changed.update(int(i) for i in indices)
        self.version += 1

    def take_changes(self) -> set[int] | None:
        """Particles whose Gaussians changed since the last call, with ``BACKGROUND_OWNER`` (-1) where the
        background did (the table under a moved object, ``background.opaque_under_objects``); None = everything (or
        the count) changed."""
        if self._all_changed:
            self._all_changed, self._changed = False, set()
            self._fill_stale = True  # the upload reads the background as it is now
            self._background_changed()
            return None
        background = self._background_changed()
        out, self._changed = self._changed, set()
        return (out | {BACKGROUND_OWNER}) if background else out


def _size(particles: Particles, i: int, config: ModelConfig) -> float:
    """Particle ``i``'s width in metres, up to a constant factor: its image-plane scale times its depth."""
    return float(torch.sigmoid(particles.z_s[i]).double().mean()) * float(config.depth_of(particles.z_d[i, 0]))


def check_room(num: int, more: int, what: str) -> None:
    """MoveError unless a scene of ``num`` particles can take ``more`` (:data:`MAX_EDIT_PARTICLES`)."""
    if num + more > MAX_EDIT_PARTICLES:
        raise MoveError(
            f"{what}: the scene would have {num + more} particles, more than the {MAX_EDIT_PARTICLES} an edited "
            "scene may hold"
        )
