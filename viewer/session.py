"""The scene session: particles, their edits as do/undo operations, and the Gaussians to draw.

Panels and mouse tools change the session only through its methods; the renderer asks
:meth:`SceneSession.take_changes` which owners to re-decode, so an edit re-decodes only the
edited particle.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from os import PathLike
from pathlib import Path

import torch

from particlesplat.edits import Edits, apply_edits, check_indices, diff_edits, load_edits, save_edits
from particlesplat.encode_scene import EncodedScene
from particlesplat.gaussians import Gaussians
from particlesplat.model.particles import EDITABLE, Particles
from particlesplat.move import anchor_points, translate
from particlesplat.objects import particle_objects


@dataclass(frozen=True)
class SetAttribute:
    """One attribute change of one particle."""

    index: int
    name: str
    old: tuple[float, ...]
    new: tuple[float, ...]


@dataclass
class Operation:
    """A do/undo step: several attribute changes applied together (reset, load, drag)."""

    label: str
    changes: list[SetAttribute]
    open_key: tuple | None = None  # set while a drag gesture may still extend this operation


@dataclass
class History:
    """Undo and redo stacks of operations."""

    undo: list[Operation] = field(default_factory=list)
    redo: list[Operation] = field(default_factory=list)


class SceneSession:
    """What is being viewed: either a model's particles (editable) or a fixed Gaussian set (.ply).

    Args:
        model: a ParticleSplat model (needed for particles).
        encoded: the encoded scene (particles + cameras), or None for a .ply.
        gaussians: a fixed Gaussian set (a .ply), used when ``encoded`` is None.
        model_name: how the model is named in screenshots and edits files.
    """

    def __init__(self, model=None, encoded: EncodedScene | None = None, gaussians: Gaussians | None = None,
                 model_name: str = "", source: str = "") -> None:
        if encoded is None and gaussians is None:
            raise ValueError("SceneSession needs an encoded scene or a Gaussian set")
        if encoded is not None and model is None:
            raise ValueError("SceneSession: an encoded scene needs its model")
        self.model = model
        self.encoded = encoded
        self.model_name = model_name
        self.source = source
        self.history = History()
        if gaussians is not None:
            gaussians.check(source or "Gaussians")  # the GL renderer would draw NaN as nothing, or everything
        self._fixed = gaussians.detach().to("cpu") if gaussians is not None else None
        self._owner_ids: list[int] | None = None
        self.original: Particles | None = encoded.particles.detach().to("cpu") if encoded else None
        self.particles: Particles | None = self.original.clone() if self.original is not None else None
        self._objects: torch.Tensor | None = None
        self._changed: set[int] = set()
        self._all_changed = True
        self.version = 0  # bumps on every change of the Gaussians

    # ------------------------------------------------------------------ queries
    @property
    def editable(self) -> bool:
        return self.particles is not None

    @property
    def num_particles(self) -> int:
        return self.particles.num if self.particles is not None else 0

    @property
    def cameras(self) -> list:
        """The scene's input cameras (all frames), empty for a .ply."""
        return list(self.encoded.all_cameras) if self.encoded is not None else []

    def num_owners(self) -> int:
        """P for owner maps: particles, or max owner + 1 of a .ply."""
        if self.particles is not None:
            return self.particles.num
        return int(self._fixed.owner.max()) + 1 if self._fixed.num else 0

    def owner_ids(self) -> list[int]:
        """The owners >= 0 the scene holds, ascending: every particle, or the distinct owners of a .ply."""
        if self.particles is not None:
            return list(range(self.particles.num))
        if self._owner_ids is None:
            self._owner_ids = [int(o) for o in torch.unique(self._fixed.owner) if int(o) >= 0]
        return self._owner_ids

    def value(self, index: int, name: str) -> tuple[float, ...]:
        return tuple(float(v) for v in self.particles.attribute(index, name).tolist())

    def original_value(self, index: int, name: str) -> tuple[float, ...]:
        return tuple(float(v) for v in self.original.attribute(index, name).tolist())

    @property
    def active_threshold(self) -> float:
        """z_t above which a particle counts as active: the model's ``bg_mask_threshold`` (the
        transparency above which DLP masks a particle's box out of the background), else 0.5."""
        return float(getattr(getattr(self.model, "config", None), "bg_mask_threshold", 0.5))

    def is_active(self, index: int) -> bool:
        """Active = transparency z_t above :attr:`active_threshold` (DLP's active particles)."""
        return float(self.particles.z_t[index, 0]) > self.active_threshold

    def edits(self) -> Edits:
        """Current edits relative to the encoded particles."""
        return diff_edits(self.original, self.particles) if self.particles is not None else {}

    # ------------------------------------------------------------------ Gaussians
    def gaussians(self) -> Gaussians:
        """All Gaussians of the current state (particles with edits, plus background)."""
        if self._fixed is not None:
            return self._fixed
        return self.model.decode(self.particles).detach().to("cpu")

    def objects(self) -> torch.Tensor:
        """(num_owners,) int64 object label per particle (:func:`particlesplat.objects.particle_objects`),
        grouped once on the scene as encoded, so an edit does not regroup it. A .ply has no particles to
        group: each owner is its own object."""
        if self._objects is None:
            if self._fixed is not None:
                self._objects = torch.arange(self.num_owners())
            else:
                self._objects = particle_objects(self.model.decode(self.original).detach().to("cpu"),
                                                 self.num_owners())
        return self._objects

    def particle_gaussians(self, index: int) -> Gaussians:
        """The Gaussians of one particle (owner = index), decoded alone."""
        return self.model.decode(self.particles, torch.tensor([index]), background=False).detach().to("cpu")

    def take_changes(self) -> set[int] | None:
        """Owners whose Gaussians changed since the last call; None = everything changed."""
        if self._all_changed:
            self._all_changed, self._changed = False, set()
            return None
        out, self._changed = self._changed, set()
        return out

    # ------------------------------------------------------------------ operations
    def _apply(self, changes: list[SetAttribute], forward: bool) -> None:
        for ch in changes:
            self.particles = self.particles.with_attribute(ch.index, ch.name, ch.new if forward else ch.old)
            self._changed.add(ch.index)
        self.version += 1

    def _push(self, op: Operation) -> None:
        self._apply(op.changes, True)
        self.history.undo.append(op)
        self.history.redo.clear()

    def set_attribute(self, index: int, name: str, value, gesture: str | None = None) -> None:
        """Set attribute ``name`` (width of EDITABLE[name]) of particle ``index``.

        gesture: an id of an ongoing drag; consecutive calls with the same gesture, index and
        name extend one operation (one undo step per drag) until :meth:`end_gesture`.
        """
        self._check_editable(index)
        if name not in EDITABLE:
            raise KeyError(f"'{name}' is not an editable attribute ({', '.join(EDITABLE)})")
        new = tuple(float(v) for v in (value if isinstance(value, (list, tuple)) else [value]))
        if len(new) != EDITABLE[name]:
            raise ValueError(f"{name} needs {EDITABLE[name]} value(s), got {len(new)}")
        if name == "z_t":
            new = (min(1.0, max(0.0, new[0])),)
        old = self.value(index, name)
        if new == old:
            return
        self._record(f"set {name} of particle {index}", [SetAttribute(index, name, old, new)],
                     (gesture, index, name) if gesture is not None else None)

    def _check_editable(self, index: int) -> None:
        if not self.editable:
            raise ValueError("this scene has no particles to edit (opened from a .ply)")
        if not 0 <= index < self.num_particles:
            raise IndexError(f"particle {index} out of range (0..{self.num_particles - 1})")

    def _record(self, label: str, changes: list[SetAttribute], key: tuple | None) -> None:
        """Apply ``changes`` as a new operation, or, when the last operation is the open gesture ``key``,
        extend it (each attribute keeps the old value it had when the gesture began)."""
        last = self.history.undo[-1] if self.history.undo else None
        if key is not None and last is not None and last.open_key == key:
            merged = {(c.index, c.name): c for c in last.changes}
            for c in changes:
                first = merged.get((c.index, c.name), c)
                merged[(c.index, c.name)] = SetAttribute(c.index, c.name, first.old, c.new)
            last.changes = list(merged.values())
            self._apply(changes, True)
            return
        self._push(Operation(label, changes, key))

    def object_members(self, index: int) -> list[int]:
        """The particles of particle ``index``'s object (:meth:`objects`), ascending."""
        labels = self.objects()
        return [int(j) for j in torch.nonzero(labels == labels[index]).flatten()]

    def object_offset(self, index: int) -> tuple[float, float, float]:
        """World offset (metres) of particle ``index``'s anchor from where it was encoded."""
        cfg = self.model.config
        now = anchor_points(self.particles, [index], cfg)[0]
        was = anchor_points(self.original, [index], cfg)[0]
        return tuple(float(v) for v in now - was)

    def move_object(self, index: int, delta, gesture: str | None = None) -> None:
        """Translate every particle of particle ``index``'s object by ``delta`` (3,) world metres (one
        operation; consecutive calls with the same ``gesture`` extend it until :meth:`end_gesture`).
        Raises :class:`particlesplat.move.MoveError` (nothing changed) if a particle would leave the
        model's depth range."""
        self._check_editable(index)
        members = self.object_members(index)
        target = translate(self.particles, members, delta, self.model.config)
        changes = [SetAttribute(i, name, self.value(i, name), value)
                   for i, attrs in target.items() for name, value in attrs.items() if value != self.value(i, name)]
        if changes:
            self._record(f"move object of particle{'s' if len(members) > 1 else ''} {', '.join(map(str, members))}",
                         changes, (gesture, "move", tuple(members)) if gesture is not None else None)

    def end_gesture(self) -> None:
        """Close the open drag operation, if any."""
        if self.history.undo:
            self.history.undo[-1].open_key = None

    def reset_particle(self, index: int) -> None:
        """Restore all editable attributes of particle ``index`` to the encoded values."""
        changes = [SetAttribute(index, n, self.value(index, n), self.original_value(index, n)) for n in EDITABLE
                   if self.value(index, n) != self.original_value(index, n)]
        if changes:
            self.end_gesture()
            self._push(Operation(f"reset particle {index}", changes))

    def set_edits(self, edits: Edits, label: str = "load edits") -> None:
        """Replace all edits by ``edits`` (absolute values) as one operation."""
        check_indices(edits, self.num_particles, label)
        target = apply_edits(self.original, edits, label)
        changes = []
        for name in EDITABLE:
            for index in range(self.num_particles):
                old, new = self.value(index, name), tuple(float(v) for v in target.attribute(index, name).tolist())
                if old != new:
                    changes.append(SetAttribute(index, name, old, new))
        if changes:
            self.end_gesture()
            self._push(Operation(label, changes))

    def undo(self) -> bool:
        """Undo the last operation; False if there is none."""
        if not self.history.undo:
            return False
        op = self.history.undo.pop()
        op.open_key = None
        self._apply(list(reversed(op.changes)), False)
        self.history.redo.append(op)
        return True

    def redo(self) -> bool:
        """Redo the last undone operation; False if there is none."""
        if not self.history.redo:
            return False
        op = self.history.redo.pop()
        self._apply(op.changes, True)
        self.history.undo.append(op)
        return True

    # ------------------------------------------------------------------ files
    def save_edits(self, path: str | PathLike) -> None:
        save_edits(path, self.edits(), model=self.model_name or None, scene=self.source or None)

    def load_edits(self, path: str | PathLike) -> None:
        self.set_edits(load_edits(path), label=f"load {Path(path).name}")
