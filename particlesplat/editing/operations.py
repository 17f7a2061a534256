"""Edit operations: one class per operation, each doing and undoing itself on the particles under edit
(:class:`particlesplat.editing.edited.EditedParticles`) and reading and writing its own edit-file record.

An operation has two forms. As read from an edit file (or asked for by a tool) it holds its parameters: which
object (a :class:`~particlesplat.editing.edit_fields.Pick`, or a particle of it) and what to do to it. Resolved on
the scene as it is (:meth:`ObjectOperation.on`, :meth:`Operation.replay`) it is a done step: the attribute changes,
appended particles or object labels it made, which :meth:`Operation.do` and :meth:`Operation.undo` apply.
:meth:`Operation.file_operations` turns a done step back into the file form, whose :meth:`Operation.record` is
what the edit file holds.

A new operation is one class here: its ``kind`` (the edit file's key), how it reads and writes its value, what it
does on an object (:meth:`ObjectOperation.on`), listed in :data:`PICKED` (or read by its own key in
:func:`particlesplat.editing.edit_file.read_operation`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import torch
from torch import Tensor

from particlesplat.core.errors import short_repr
from particlesplat.core.vectors import float3
from particlesplat.editing.crop_box import CropBox, crop_yaml, read_crop
from particlesplat.editing.edit_fields import (
    DECIMALS,
    Insert,
    Pick,
    insert_yaml,
    pick_yaml,
    read_index,
    read_insert,
    read_numbers,
    read_pick,
    read_positive,
    rounded,
)
from particlesplat.editing.edited import EditedParticles, Rows, SetAttribute, check_room
from particlesplat.editing.grouping import members_centre
from particlesplat.editing.move import MoveError, scale, translate
from particlesplat.editing.particle_edits import EditsError, validate_edits
from particlesplat.model.particles import EDITABLE, Particles

FindPick = Callable[[int, "Operation"], Pick]  # (particle, an operation) -> a pick of its object before it


def members_label(members: list[int] | tuple[int, ...]) -> str:
    return f"particle{'s' if len(members) > 1 else ''} {', '.join(map(str, members))}"


def changes_to(scene: EditedParticles, index: int, values: dict[str, tuple[float, ...]]) -> list[SetAttribute]:
    """The changes that set particle ``index``'s attributes to ``values`` (those already equal are left out)."""
    return [
        SetAttribute(index, name, scene.value(index, name), tuple(new))
        for name, new in values.items()
        if scene.value(index, name) != tuple(new)
    ]


@dataclass(eq=False, kw_only=True)
class Operation:
    """A do/undo step: attribute ``changes`` applied together, after appending ``rows`` (a copy, an insert).

    Attributes:
        label: what the history shows.
        changes: attribute changes (old and new values).
        rows: particles it appends, or None.
        before: the particles as they were before it was done (to pick its object when saving).
        before_labels: their object labels then (None: as grouped, nothing appended or regrouped yet).
    """

    kind: ClassVar[str] = "set"
    adds_particles: ClassVar[bool] = False  # adds at least one particle each (a file's count is checked first)

    label: str = ""
    changes: list[SetAttribute] = field(default_factory=list)
    rows: Rows | None = None
    before: Particles | None = None
    before_labels: Tensor | None = None

    def do(self, scene: EditedParticles) -> None:
        scene.apply(self.changes, True, self.rows)

    def undo(self, scene: EditedParticles) -> None:
        scene.apply(self.changes, False, self.rows)

    def gesture_key(self) -> tuple:
        """What a drag's steps share to be one gesture (the attributes, or the object, they change)."""
        return tuple((c.index, c.name) for c in self.changes)

    def extend(self, later: Operation) -> None:
        """Take in ``later``, the next step of the same gesture (done already): each attribute keeps the old value
        it had when the gesture began."""
        merged = {(c.index, c.name): c for c in self.changes}
        for c in later.changes:
            first = merged.get((c.index, c.name), c)
            merged[(c.index, c.name)] = SetAttribute(c.index, c.name, first.old, c.new)
        self.changes = list(merged.values())

    def file_operations(self, find_pick: FindPick) -> list[Operation]:
        """This done step as edit-file operations."""
        raise NotImplementedError

    def record(self) -> dict[str, Any]:
        """The edit file's mapping of this (file-form) operation."""
        raise NotImplementedError

    def replay(self, scene: EditedParticles, find: Callable[[Pick, str], int], where: str) -> Operation | None:
        """This file-form operation resolved on ``scene`` as it is (``find``: the particle a pick names), ready to
        do; None when it changes nothing. Errors name ``where``."""
        raise NotImplementedError


@dataclass(eq=False, kw_only=True)
class SetAttributes(Operation):
    """Particles' attributes set to values (the viewer's sliders, a reset, version 1 edits, an edit file's
    ``{particle: I, set: {NAME: VALUES}}``). File form: ``particle`` and its ``values``."""

    kind: ClassVar[str] = "set"
    particle: int | None = None
    values: tuple[tuple[str, tuple[float, ...]], ...] = ()

    @classmethod
    def read(cls, item: dict, where: str) -> SetAttributes:
        unknown = set(item) - {"particle", "set"}
        if unknown or "set" not in item:
            raise EditsError(f"{where}: a particle operation has the keys particle and set, got {sorted(item)}")
        index = read_index(item["particle"], f"{where}.particle")
        edits = validate_edits({index: item["set"]}, where)
        return cls(particle=index, values=tuple(sorted(edits.get(index, {}).items())))

    @classmethod
    def slider(cls, scene: EditedParticles, index: int, name: str, value: Any) -> SetAttributes | None:
        """Set attribute ``name`` (width of EDITABLE[name]) of particle ``index`` to ``value`` (z_t clamped to
        [0, 1]); None when it is that already."""
        if name not in EDITABLE:
            raise KeyError(f"'{name}' is not an editable attribute ({', '.join(EDITABLE)})")
        new = tuple(float(v) for v in (value if isinstance(value, (list, tuple)) else [value]))
        if len(new) != EDITABLE[name]:
            raise ValueError(f"{name} needs {EDITABLE[name]} value(s), got {len(new)}")
        if name == "z_t":
            new = (min(1.0, max(0.0, new[0])),)
        changes = changes_to(scene, index, {name: new})
        return cls(label=f"set {name} of particle {index}", changes=changes) if changes else None

    def file_operations(self, find_pick: FindPick) -> list[Operation]:
        per: dict[int, dict[str, tuple[float, ...]]] = {}
        for c in self.changes:
            per.setdefault(c.index, {})[c.name] = c.new
        return [SetAttributes(particle=i, values=tuple(sorted(v.items()))) for i, v in sorted(per.items())]

    def record(self) -> dict[str, Any]:
        if self.particle is None:
            raise ValueError("a set operation needs its particle")
        return {"particle": int(self.particle), "set": {k: [float(x) for x in v] for k, v in self.values}}

    def replay(self, scene: EditedParticles, find: Callable[[Pick, str], int], where: str) -> Operation | None:
        particle = self.particle
        if particle is None:
            raise ValueError(f"{where}: a set operation needs its particle")
        if not 0 <= particle < scene.num:
            raise EditsError(f"{where}: particle {particle}: no such particle (the scene has {scene.num})")
        changes = changes_to(scene, particle, dict(self.values))
        return SetAttributes(label=f"set particle {particle}", changes=changes) if changes else None


@dataclass(eq=False, kw_only=True)
class ObjectOperation(Operation):
    """An operation on one object, named in an edit file by a pick: ``{pick: {frame, pixel}, KIND: VALUE}``.

    Attributes:
        pick: which object (file form; found when saving a done step that has none).
        members: the particles of the object it acted on (done step).
    """

    pick: Pick | None = None
    members: tuple[int, ...] = ()

    @classmethod
    def read(cls, item: dict, where: str) -> ObjectOperation:
        """The operation of a mapping holding ``pick`` and this class's ``kind`` (checked by the caller)."""
        return cls.read_value(item[cls.kind], read_pick(item["pick"], f"{where}.pick"), f"{where}.{cls.kind}")

    @classmethod
    def read_value(cls, value: Any, pick: Pick, where: str) -> ObjectOperation:
        raise NotImplementedError

    def value_yaml(self) -> Any:
        """What the edit file holds under ``kind``."""
        raise NotImplementedError

    def on(self, scene: EditedParticles, index: int) -> ObjectOperation | None:
        """This operation done on particle ``index``'s object as the scene is now: a done step, or None when it
        changes nothing. Raises MoveError (nothing changed) where the scene cannot take it."""
        raise NotImplementedError

    def gesture_key(self) -> tuple:
        return (self.kind, self.members)

    def file_operations(self, find_pick: FindPick) -> list[Operation]:
        if self.pick is None:  # found once: the particles before the operation do not change
            self.pick = find_pick(self.members[0], self)
        return [self]

    def record(self) -> dict[str, Any]:
        if self.pick is None:
            raise ValueError(f"a {self.kind} operation needs its pick")
        return {"pick": pick_yaml(self.pick), self.kind: self.value_yaml()}

    def replay(self, scene: EditedParticles, find: Callable[[Pick, str], int], where: str) -> Operation | None:
        if self.pick is None:
            raise ValueError(f"{where}: a {self.kind} operation needs its pick")
        index = find(self.pick, where)
        try:
            done = self.on(scene, index)
        except MoveError as e:
            raise EditsError(f"{where}: {e}") from None
        if done is not None:
            done.pick = self.pick  # saved as it was read: a replayed file saves itself
        return done


def _offset(value: Any) -> tuple[float, float, float]:
    return float3(torch.as_tensor(value, dtype=torch.float64).reshape(3).tolist())


def _moved(scene: EditedParticles, particles: Particles, members: list[int], offset) -> list[SetAttribute]:
    """The changes that move particles ``members`` of ``particles`` by ``offset`` (3,) world metres, and give them
    the height of the surface under where the object goes (:meth:`EditedParticles.support_changes`)."""
    target = translate(particles, members, offset, scene.model.config)
    return [
        SetAttribute(i, name, tuple(float(v) for v in particles.attribute(i, name).tolist()), value)
        for i, attrs in target.items()
        for name, value in attrs.items()
    ] + scene.support_changes(particles, members, offset)


@dataclass(eq=False, kw_only=True)
class OffsetOperation(ObjectOperation):
    """An object operation whose value is an ``offset`` (3,) world metres: ``KIND: [x, y, z]``."""

    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @classmethod
    def read_value(cls, value: Any, pick: Pick, where: str) -> ObjectOperation:
        return cls(pick=pick, offset=float3(read_numbers(value, 3, where)))

    def value_yaml(self) -> Any:
        return rounded(self.offset)


@dataclass(eq=False, kw_only=True)
class Translate(OffsetOperation):
    """Move an object by ``offset`` (3,) world metres: ``translate: [x, y, z]``. A drag adds its steps up."""

    kind: ClassVar[str] = "translate"

    def on(self, scene: EditedParticles, index: int) -> ObjectOperation | None:
        members = scene.objects().members(index)
        delta = _offset(self.offset)
        changes = [c for c in _moved(scene, scene.particles, members, delta) if c.new != c.old]
        if not changes:
            return None
        return Translate(
            label=f"move object of {members_label(members)}", changes=changes, members=tuple(members), offset=delta
        )

    def extend(self, later: Operation) -> None:
        super().extend(later)
        if isinstance(later, Translate):
            self.offset = float3(a + b for a, b in zip(self.offset, later.offset, strict=True))


@dataclass(eq=False, kw_only=True)
class Remove(ObjectOperation):
    """Remove an object: its particles' z_t go to 0, so they no longer draw: ``remove: true``."""

    kind: ClassVar[str] = "remove"

    @classmethod
    def read_value(cls, value: Any, pick: Pick, where: str) -> ObjectOperation:
        if value is not True:
            raise EditsError(f"{where}: expected true, got {short_repr(value)}")
        return cls(pick=pick)

    def value_yaml(self) -> Any:
        return True

    def on(self, scene: EditedParticles, index: int) -> ObjectOperation | None:
        members = scene.objects().members(index)
        changes = [
            SetAttribute(i, "z_t", scene.value(i, "z_t"), (0.0,)) for i in members if scene.value(i, "z_t") != (0.0,)
        ]
        if not changes:
            return None  # already removed
        return Remove(label=f"remove object of {members_label(members)}", changes=changes, members=tuple(members))


@dataclass(eq=False, kw_only=True)
class Duplicate(OffsetOperation):
    """Copy an object (new particles, the same latents) moved by ``offset`` (3,) world metres:
    ``duplicate: [x, y, z]``. The copy is an object of its own."""

    kind: ClassVar[str] = "duplicate"
    adds_particles: ClassVar[bool] = True

    def on(self, scene: EditedParticles, index: int) -> ObjectOperation | None:
        members = scene.objects().members(index)
        offset = _offset(self.offset)
        n = scene.num
        check_room(n, len(members), "duplicate")
        grown = scene.particles.cat(scene.particles.take(members))
        changes = _moved(scene, grown, list(range(n, n + len(members))), offset)
        labels = torch.full((len(members),), scene.next_object(), dtype=torch.int64)
        rows = Rows(grown.take(slice(n, None)), labels, tuple(scene.source[i] for i in members))
        return Duplicate(
            label=f"duplicate object of {members_label(members)}",
            changes=changes,
            rows=rows,
            members=tuple(members),
            offset=offset,
        )


@dataclass(eq=False, kw_only=True)
class InsertObject(Operation):
    """Insert an object of another scene: ``insert: {scene, object, at, context}`` (:class:`Insert`)."""

    kind: ClassVar[str] = "insert"
    adds_particles: ClassVar[bool] = True
    insert: Insert | None = None

    @classmethod
    def read(cls, item: dict, where: str) -> InsertObject:
        if set(item) != {"insert"}:
            raise EditsError(f"{where}: an insert operation has the one key insert, got {sorted(item)}")
        return cls(insert=read_insert(item["insert"], f"{where}.insert"))

    def _insert(self) -> Insert:
        if self.insert is None:
            raise ValueError("an insert operation needs its insert")
        return self.insert

    @classmethod
    def of(cls, scene: EditedParticles, source: Particles, insert: Insert) -> InsertObject:
        """Object ``insert.object`` of another scene's particles ``source`` (encoded with this model) with its
        centre at ``insert.at`` on the surface there (the table, or the floor past its edge:
        :func:`particlesplat.editing.compose.insert_object`).
        Raises ValueError (no such object) or MoveError."""
        from particlesplat.editing.compose import insert_object

        n = scene.num
        check_room(n, 1, "insert")
        support = scene.world.height_at(*insert.at)  # the table under it, or the floor past its edge
        grown, new = insert_object(scene.model, scene.particles, source, insert.object, insert.at, support=support)
        check_room(n, grown.num - n, "insert")
        added = grown.take(slice(n, None)).detach().to("cpu")
        sources = scene.add_inserted(added)
        labels = torch.full((len(new),), scene.next_object(), dtype=torch.int64)
        return cls(
            label=f"insert object {insert.object} of {Path(insert.scene).name}",
            rows=Rows(added, labels, sources),
            insert=insert,
        )

    def file_operations(self, find_pick: FindPick) -> list[Operation]:
        return [InsertObject(insert=self.insert)]

    def record(self) -> dict[str, Any]:
        return {"insert": insert_yaml(self._insert())}

    def replay(self, scene: EditedParticles, find: Callable[[Pick, str], int], where: str) -> Operation | None:
        from particlesplat.editing.open_scene import encode_scene

        insert = self._insert()
        try:
            context = None if insert.context is None else list(insert.context)
            source = encode_scene(scene.model, insert.scene, context).particles
            return InsertObject.of(scene, source, insert)
        except (MoveError, ValueError, OSError) as e:
            raise EditsError(f"{where}: insert: {e}") from None


@dataclass(eq=False, kw_only=True)
class Crop(Operation):
    """Hide the Gaussians outside a world-aligned box (:class:`particlesplat.editing.crop_box.CropBox`; the
    particles do not change): ``crop: {min: [x, y, z], max: [x, y, z]}`` world metres, or ``crop: false`` to show
    everything again. ``old``: the box before it (done step). A drag of the box's handles is one step."""

    kind: ClassVar[str] = "crop"
    box: CropBox | None = None
    old: CropBox | None = None

    @classmethod
    def read(cls, item: dict, where: str) -> Crop:
        if set(item) != {"crop"}:
            raise EditsError(f"{where}: a crop operation has the one key crop, got {sorted(item)}")
        return cls(box=read_crop(item["crop"], f"{where}.crop"))

    @classmethod
    def of(cls, scene: EditedParticles, box: CropBox) -> Crop | None:
        """The crop of ``scene`` set to ``box``; None when it is that already."""
        if scene.crop == box:
            return None
        return cls(label=f"crop to {box.text()}" if box.bounded else "crop box off", box=box, old=scene.crop)

    def _box(self) -> CropBox:
        if self.box is None:
            raise ValueError("a crop operation needs its box")
        return self.box

    def do(self, scene: EditedParticles) -> None:
        scene.set_crop(self._box())

    def undo(self, scene: EditedParticles) -> None:
        scene.set_crop(self.old)

    def gesture_key(self) -> tuple:
        return (self.kind,)

    def extend(self, later: Operation) -> None:
        if isinstance(later, Crop):  # the drag's last box; the box before the drag stays what undo restores
            self.box, self.label = later.box, later.label

    def file_operations(self, find_pick: FindPick) -> list[Operation]:
        return [Crop(box=self._box())]

    def record(self) -> dict[str, Any]:
        return {"crop": crop_yaml(self._box())}

    def replay(self, scene: EditedParticles, find: Callable[[Pick, str], int], where: str) -> Operation | None:
        return Crop.of(scene, self._box())


@dataclass(eq=False, kw_only=True)
class Scale(ObjectOperation):
    """Scale an object ``factor`` times about its resting centre, keeping it on its support: ``scale: F``. Each
    particle's anchor moves away from (or towards) the point below the centre on the support surface and its size
    in metres grows F times (its latents ``z_s`` and ``z_e``, :func:`particlesplat.editing.move.scale`), so the
    object grows about that point: its bottom stays on the support. A drag multiplies its steps."""

    kind: ClassVar[str] = "scale"
    factor: float = 1.0

    @classmethod
    def read_value(cls, value: Any, pick: Pick, where: str) -> ObjectOperation:
        return cls(pick=pick, factor=read_positive(value, where))

    def value_yaml(self) -> Any:
        return round(float(self.factor), DECIMALS)

    def on(self, scene: EditedParticles, index: int) -> ObjectOperation | None:
        members = scene.objects().members(index)
        factor = float(self.factor)
        if not (math.isfinite(factor) and factor > 0.0):
            raise MoveError(f"scale: expected a factor in (0, inf), got {factor!r}")
        if factor == 1.0:
            return None
        support = scene.support_height(members)
        centre = members_centre(scene.model, scene.particles, members, support)
        if centre is None:
            raise MoveError(f"scale: the object of {members_label(members)} draws nothing")
        pivot = (float(centre[0]), float(centre[1]), support)
        target = scale(scene.particles, members, factor, pivot, scene.model.config)
        changes = [
            SetAttribute(i, name, scene.value(i, name), value)
            for i, attrs in target.items()
            for name, value in attrs.items()
            if value != scene.value(i, name)
        ]
        label = f"scale object of {members_label(members)} x{factor:.3g}"
        return Scale(label=label, changes=changes, members=tuple(members), factor=factor) if changes else None

    def extend(self, later: Operation) -> None:
        super().extend(later)
        if isinstance(later, Scale):
            self.factor *= later.factor
            self.label = f"scale object of {members_label(self.members)} x{self.factor:.3g}"


@dataclass(eq=False, kw_only=True)
class Regroup(Operation):
    """A change of which particles form an object: ``relabel`` (index, old label, new label) per particle."""

    relabel: tuple[tuple[int, int, int], ...] = ()

    def do(self, scene: EditedParticles) -> None:
        scene.relabel([i for i, _, _ in self.relabel], [new for _, _, new in self.relabel])

    def undo(self, scene: EditedParticles) -> None:
        scene.relabel([i for i, _, _ in self.relabel], [old for _, old, _ in self.relabel])


@dataclass(eq=False, kw_only=True)
class Merge(Regroup, ObjectOperation):
    """Join two objects into one: ``merge: {frame, pixel}`` picks the other object. The joined object keeps the
    smaller of the two numbers. File form: ``other`` (its pick); to do: ``other_index`` (a particle of it)."""

    kind: ClassVar[str] = "merge"
    other: Pick | None = None
    other_index: int | None = None
    others: tuple[int, ...] = ()

    @classmethod
    def read_value(cls, value: Any, pick: Pick, where: str) -> ObjectOperation:
        return cls(pick=pick, other=read_pick(value, where))

    def value_yaml(self) -> Any:
        if self.other is None:
            raise ValueError("a merge operation needs the pick of its other object")
        return pick_yaml(self.other)

    def on(self, scene: EditedParticles, index: int) -> ObjectOperation | None:
        if self.other_index is None:
            raise ValueError("merge: which object to join is not given")
        objects = scene.objects()
        a, b = int(objects.labels[index]), int(objects.labels[self.other_index])
        if a < 0 or b < 0:
            which = index if a < 0 else self.other_index
            raise MoveError(f"merge: particle {which} draws nothing, so it is in no object")
        if a == b:
            raise MoveError(f"merge: particles {index} and {self.other_index} are one object already")
        members, others = objects.members(index), objects.members(self.other_index)
        keep, old, moved = (a, b, others) if a < b else (b, a, members)
        relabel = tuple((i, old, keep) for i in moved)
        return Merge(
            label=f"merge objects of {members_label(members)} and {members_label(others)}",
            relabel=relabel,
            members=tuple(members),
            others=tuple(others),
        )

    def file_operations(self, find_pick: FindPick) -> list[Operation]:
        if self.other is None:
            self.other = find_pick(self.others[0], self)
        return super().file_operations(find_pick)

    def replay(self, scene: EditedParticles, find: Callable[[Pick, str], int], where: str) -> Operation | None:
        if self.other is None:
            raise ValueError(f"{where}: a merge operation needs the pick of its other object")
        self.other_index = find(self.other, f"{where}.merge")
        done = super().replay(scene, find, where)
        if isinstance(done, Merge):
            done.other = self.other
        return done


@dataclass(eq=False, kw_only=True)
class Split(Regroup):
    """Take a particle out of its object into an object of its own (the next number): ``{particle: I, split:
    true}``."""

    kind: ClassVar[str] = "split"
    particle: int | None = None

    @classmethod
    def read(cls, item: dict, where: str) -> Split:
        if set(item) != {"particle", "split"}:
            raise EditsError(f"{where}: a split operation has the keys particle and split, got {sorted(item)}")
        if item["split"] is not True:
            raise EditsError(f"{where}.split: expected true, got {short_repr(item['split'])}")
        return cls(particle=read_index(item["particle"], f"{where}.particle"))

    @classmethod
    def of(cls, scene: EditedParticles, index: int) -> Split:
        """Particle ``index`` out of its object. Raises MoveError when it draws nothing or is alone already."""
        objects = scene.objects()
        label = int(objects.labels[index])
        if label < 0:
            raise MoveError(f"split: particle {index} draws nothing, so it is in no object")
        if len(objects.members(index)) == 1:
            raise MoveError(f"split: particle {index} is an object of its own already")
        new = scene.next_object()
        return cls(label=f"split particle {index} off its object", relabel=((index, label, new),), particle=index)

    def file_operations(self, find_pick: FindPick) -> list[Operation]:
        return [Split(particle=self.particle)]

    def record(self) -> dict[str, Any]:
        if self.particle is None:
            raise ValueError("a split operation needs its particle")
        return {"particle": int(self.particle), "split": True}

    def replay(self, scene: EditedParticles, find: Callable[[Pick, str], int], where: str) -> Operation | None:
        particle = self.particle
        if particle is None:
            raise ValueError(f"{where}: a split operation needs its particle")
        if not 0 <= particle < scene.num:
            raise EditsError(f"{where}: particle {particle}: no such particle (the scene has {scene.num})")
        try:
            return Split.of(scene, particle)
        except MoveError as e:
            raise EditsError(f"{where}: {e}") from None


PICKED: dict[str, type[ObjectOperation]] = {op.kind: op for op in (Translate, Remove, Duplicate, Scale, Merge)}
"""The operations on a picked object, by their edit-file key."""
