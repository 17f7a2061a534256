"""Object edits: the scene editor, one facade over the particles under edit, their operations, history and picks.

The viewer and ``particlesplat render --edits`` both go through :class:`SceneEditor`, so a saved file replays
what the user did. Where the parts live:

- the particles under edit and what follows them: :mod:`particlesplat.editing.edited`;
- one class per operation (do, undo, its edit-file record): :mod:`particlesplat.editing.operations`;
- the history (a cursor) and drags (a gesture commits one operation at its end): :mod:`particlesplat.editing.history`;
- edit files (the document, version 1 and 2): :mod:`particlesplat.editing.edit_file`, their fields
  :mod:`particlesplat.editing.edit_fields`;
- which object a pixel shows: :mod:`particlesplat.editing.picking`; objects: :mod:`particlesplat.editing.scene_objects`.

An object is a group of particles (grouped once on the scene as encoded), numbered as ``particlesplat encode``
numbers them (:meth:`SceneEditor.objects`); a copy is an object of its own. Rotation is not an operation: a
particle is a patch lifted along its own view's rays (position z_p, scale z_s, depth z_d, extent z_e), with no
latent for its orientation, so turning an object would show each view's patch edge-on rather than the object's
other side.
"""

from __future__ import annotations

from os import PathLike
from pathlib import Path
from typing import TYPE_CHECKING, Any

import torch
from torch import Tensor

from particlesplat.core.camera import Camera
from particlesplat.core.gaussians import Gaussians
from particlesplat.core.panda_arm import capsule_distance
from particlesplat.core.world import Support
from particlesplat.editing.crop_box import CropBox
from particlesplat.editing.decoded import DecodedParticles
from particlesplat.editing.edit_fields import Insert, Pick, PickError
from particlesplat.editing.edit_file import (
    EditFile,
    edit_file_text,
    load_edit_file,
    parse_edit_file,
    same_scene,
    save_edit_file,
    scene_mismatch,
)
from particlesplat.editing.edited import MAX_EDIT_PARTICLES, EditedParticles, SetAttribute
from particlesplat.editing.grouping import arm_state, members_centre
from particlesplat.editing.history import Gesture, History
from particlesplat.editing.operations import (
    Crop,
    Duplicate,
    InsertObject,
    Merge,
    Operation,
    Remove,
    Scale,
    SetAttributes,
    Split,
    Translate,
    changes_to,
)
from particlesplat.editing.particle_edits import Edits, EditsError, apply_edits, check_indices, diff_edits
from particlesplat.editing.picking import Picker
from particlesplat.editing.placement import place
from particlesplat.model.evidence import arm_capsules_of
from particlesplat.model.particles import EDITABLE, Particles

if TYPE_CHECKING:
    from particlesplat.model.particlesplat import ParticleSplat

ROBOT_MARGIN = 0.03  # metres: a point this near the room the robot's arm takes is on the robot (its surface lies
# within a few centimetres of its capsules)

__all__ = [  # the names edit-file users import from here
    "MAX_EDIT_PARTICLES", "EditFile", "EditsError", "Insert", "Pick", "PickError", "SceneEditor",
    "load_edit_file", "parse_edit_file", "same_scene", "save_edit_file", "scene_mismatch",
]  # fmt: skip


class SceneEditor:
    """Particles of one scene under edit, as named do/undo operations.

    Args:
        model: the ParticleSplat model that decodes the particles.
        particles: the encoded particles (kept as the original).
        frame_cameras: the scene's input cameras at their stored size, indexed by frame (picks name these).
        context: the context frame indices (saved in edit files; picks try them first).
        z_t_threshold: the particles that draw (None: the model's, :meth:`ParticleSplat.decode`; 0 draws the
            inactive ones too, as before they were dropped: for measuring that).
        world: what the scene's objects rest on (:class:`particlesplat.core.world.Support`: its table and the floor
            around it; default a floor everywhere); an :class:`~particlesplat.editing.open_scene.EncodedScene`'s
            ``support``.
    """

    def __init__(
        self,
        model: ParticleSplat,
        particles: Particles,
        frame_cameras: list[Camera] | None = None,
        context: list[int] | None = None,
        z_t_threshold: float | None = None,
        world: Support | None = None,
    ) -> None:
        self.model = model
        self.z_t_threshold = z_t_threshold
        self.frame_cameras = list(frame_cameras or [])
        self.context = list(context) if context is not None else None
        self.history = History()
        self.scene = EditedParticles(model, particles, z_t_threshold, world)
        self.picker = Picker(self.frame_cameras, self.context)

    # ------------------------------------------------------------------ queries
    @property
    def particles(self) -> Particles:
        """The particles under edit."""
        return self.scene.particles

    @property
    def original(self) -> Particles:
        """The particles as encoded."""
        return self.scene.original

    @property
    def version(self) -> int:
        """Bumps on every change of the Gaussians."""
        return self.scene.version

    @property
    def _decoded(self) -> DecodedParticles:
        return self.scene.decoded

    @property
    def num_particles(self) -> int:
        return self.scene.num

    def value(self, index: int, name: str) -> tuple[float, ...]:
        return self.scene.value(index, name)

    def origin(self) -> Particles:
        """The particles as encoded, followed by every particle inserted from another scene as it was inserted
        (the rows :meth:`original_value` and :meth:`object_offset` refer to)."""
        return self.scene.origin()

    def original_value(self, index: int, name: str) -> tuple[float, ...]:
        """The encoded value (a copy's: that of the particle it was copied from; an inserted one's: as inserted)."""
        return self.scene.original_value(index, name)

    @property
    def active_threshold(self) -> float:
        """z_t at and above which a particle draws: the model's ``bg_mask_threshold`` (the decoder drops
        particles below it, :meth:`ParticleSplat.decode`)."""
        return self.scene.active_threshold

    def is_active(self, index: int) -> bool:
        """Active = draws: z_t at or above :attr:`active_threshold`."""
        return float(self.scene.particles.z_t[index, 0]) >= self.active_threshold

    def edits(self) -> Edits:
        """Version 1 edits (absolute values) of the encoded particles; copies are not part of them."""
        return diff_edits(self.scene.original, self.scene.particles.truncate(self.scene.original.num))

    def decode(self, particles: Particles | None = None) -> Gaussians:
        """All Gaussians (edits applied, background included) on the CPU; of the current particles (the default)
        from the Gaussians kept up to date edit by edit (:class:`particlesplat.editing.decoded.DecodedParticles`)."""
        return self.scene.decode(particles)

    def background(self) -> Gaussians:
        """The background Gaussians of the current particles (owner -1) on the CPU, as :meth:`decode` holds them
        (:meth:`particlesplat.editing.decoded.DecodedParticles.background`)."""
        return self._decoded.background(self.scene.particles)

    def objects(self) -> Tensor:
        """(num_particles,) int64 object number per particle, the numbering ``particlesplat encode`` writes
        (:class:`particlesplat.editing.scene_objects.SceneObjects`). Grouped once on the scene as encoded, so an
        edit does not regroup it; a copied or inserted object takes the next number."""
        return self.scene.objects().labels

    def object_members(self, index: int) -> list[int]:
        """The particles of particle ``index``'s object (:meth:`objects`), ascending; a particle that draws
        nothing is alone."""
        return self.scene.objects().members(index)

    @property
    def world(self) -> Support:
        """What the scene's objects rest on: its table and the floor around it, or a floor."""
        return self.scene.world

    def support_height(self, index: int | None = None) -> float:
        """The height (world z, metres) of the surface particle ``index``'s object rests on (the table top or the
        shared support surface as encoded, the floor once placed past a table's edge); without ``index``, the shared
        support surface (:data:`particlesplat.core.world.SUPPORT_Z`; the tabletop's floor, the robot's table top)."""
        return self.scene.support_height(None if index is None else self.object_members(index))

    def object_centre(self, index: int) -> Tensor | None:
        """(3,) float64 world metres: the resting centre of particle ``index``'s object as drawn now
        (:func:`particlesplat.editing.grouping.members_centre`, as ``particlesplat encode`` and ``eval`` place
        objects), or None if it draws nothing."""
        scene = self.scene
        return members_centre(scene.model, scene.particles, self.object_members(index), self.support_height(index))

    def object_scale(self, index: int) -> float:
        """How many times its encoded size particle ``index``'s object is now (what scaling it multiplied): the
        geometric mean over its particles of their depth extent in metres now over as encoded (``z_e``, which a
        scale multiplies and a move keeps); 1 for an object as encoded."""
        members = self.object_members(index)
        now = torch.sigmoid(self.scene.particles.z_e[members, 0].double())
        origin = self.scene.origin()
        was = torch.sigmoid(origin.z_e[[self.scene.source[i] for i in members], 0].double())
        return float(torch.exp(torch.log(now / was).mean()))

    def on_robot(self, point: Tensor, margin: float = ROBOT_MARGIN) -> bool:
        """Whether world ``point`` (3,) metres lies on the scene's robot: within ``margin`` metres of the room its
        arm takes (:func:`particlesplat.core.panda_arm.capsule_distance`) in the robot state the particles were
        encoded with. False for a scene without a robot, or a model that reads none."""
        arm = arm_state(self.model, self.original)
        if arm is None:
            return False
        starts, ends, radii = (t.double() for t in arm_capsules_of(arm.detach().cpu()))
        return float(capsule_distance(point.double().reshape(1, 3), starts, ends, radii)[0]) < margin

    def object_bottom(self, index: int) -> float | None:
        """World height (metres) of the lowest part of particle ``index``'s object as drawn now
        (:meth:`EditedParticles.bottom`); None if it draws nothing opaque."""
        return self.scene.bottom(self.object_members(index))

    def sunk_objects(self) -> list[str]:
        """A line for each object whose bottom is below its support (:meth:`EditedParticles.sunk_objects`)."""
        return self.scene.sunk_objects()

    def object_offset(self, index: int) -> tuple[float, float, float]:
        """World offset (metres) of particle ``index``'s anchor from where it (or what it copies) was encoded."""
        return self.scene.offset(index)

    def take_changes(self) -> set[int] | None:
        """Particles whose Gaussians changed since the last call; None = everything (or the count) changed."""
        return self.scene.take_changes()

    # ------------------------------------------------------------------ picking
    def object_map(self, frame: int, particles: Particles | None = None, where: str = "pick") -> Tensor:
        """(H, W) int64 object label per pixel of input frame ``frame`` at its stored size (-1 background)."""
        return self.picker.object_map(self.scene, frame, particles, where)

    def _pixel_object(self, frame: int, cam: Camera, pixel: tuple[int, int]) -> int:
        return self.picker.pixel_object(self.scene, frame, cam, pixel)

    def pick(self, pick: Pick, where: str = "pick") -> int:
        """The first particle of the object under ``pick`` on the current particles (:class:`Picker`)."""
        return self.picker.pick(self.scene, pick, where)

    def pick_for(self, index: int, particles: Particles | None = None) -> Pick:
        """A pixel of an input frame that picks particle ``index``'s object on ``particles`` (default: now)."""
        return self.picker.pick_for(self.scene, index, particles)

    # ------------------------------------------------------------------ doing and undoing
    def _commit(self, op: Operation | None, gesture: str | None = None) -> None:
        """Do ``op`` (None: nothing to do). Without ``gesture`` it is one operation of the history; with one, a step
        of that drag: the steps of one gesture on the same thing add up to one operation, committed by
        :meth:`end_gesture` (or by the next operation that is not a step of it)."""
        if op is None:
            return
        key = (gesture, type(op).__name__, op.gesture_key())
        open_gesture = self.history.gesture
        if gesture is not None and open_gesture is not None and open_gesture.key == key:
            op.do(self.scene)
            open_gesture.operation.extend(op)
            return
        self.end_gesture()
        op.before, op.before_labels = self.scene.particles, self.scene.labels_now()
        op.do(self.scene)
        if gesture is None:
            self.history.add(op)
        else:
            self.history.gesture = Gesture(key, op)
            # a drag keeps the background as it was decoded until it ends (the table under a moved object,
            # ``background.opaque_under_objects``, is a whole background decode: at the drag's end, not every step)
            self.scene.hold_table_fill(True)

    def end_gesture(self) -> None:
        """End the drag under way, if any: it enters the history as one operation, and the next decode draws the
        table its objects uncovered (:meth:`EditedParticles.hold_table_fill`)."""
        self.history.end_gesture()
        self.scene.hold_table_fill(False)

    def _check_editable(self, index: int) -> None:
        num = self.scene.num
        if not 0 <= index < num:
            raise IndexError(f"particle {index} out of range (0..{num - 1})")

    def set_attribute(self, index: int, name: str, value: Any, gesture: str | None = None) -> None:
        """Set attribute ``name`` (width of EDITABLE[name]) of particle ``index``.

        gesture: an id of an ongoing drag; consecutive calls with the same gesture, index and
        name extend one operation (one undo step per drag) until :meth:`end_gesture`.
        """
        self._check_editable(index)
        self._commit(SetAttributes.slider(self.scene, index, name, value), gesture)

    def move_object(self, index: int, delta: Any, gesture: str | None = None) -> None:
        """Translate every particle of particle ``index``'s object by ``delta`` (3,) world metres (one
        operation; consecutive calls with the same ``gesture`` extend it until :meth:`end_gesture`).
        Raises :class:`particlesplat.editing.move.MoveError` (nothing changed) if a particle would leave the
        model's depth range."""
        self._check_editable(index)
        self._commit(Translate(offset=delta).on(self.scene, index), gesture)

    def remove_object(self, index: int) -> None:
        """Remove particle ``index``'s object: its particles' z_t go to 0, so they no longer draw."""
        self._check_editable(index)
        self._commit(Remove().on(self.scene, index))

    def duplicate_object(self, index: int, offset: Any) -> int:
        """Copy particle ``index``'s object (new particles, the same latents) and move the copy by ``offset``
        (3,) world metres. Returns the copy's first particle. Raises MoveError."""
        self._check_editable(index)
        n = self.num_particles
        self._commit(Duplicate(offset=offset).on(self.scene, index))
        return n

    def copy_object(self, index: int, offset: Any) -> tuple[int, str]:
        """Copy particle ``index``'s object to a place that respects the world: ``offset`` (3,) metres from it, on the
        surface there (the table, or the floor past its edge), at the free spot nearest to that
        (:func:`particlesplat.editing.placement.place`; a copy of a resting object rests, ``offset``'s z lifts it).
        One ``duplicate`` operation with the offset it took. Returns (the copy's first particle, a note for the
        user: "" when it went where ``offset`` put it). Raises MoveError."""
        self._check_editable(index)
        members = self.object_members(index)
        placed = place(self.scene, members, [float(v) for v in offset], self.scene.resting(members), copy=True)
        if placed is None:
            return self.duplicate_object(index, offset), ""
        return self.duplicate_object(index, placed.offset), placed.note

    def place_object(self, index: int, resting: bool, gesture: str | None = None) -> str:
        """Put particle ``index``'s object, where a drag left it, on the surface under it (the table, or the floor
        past its edge) at the free spot nearest, clear of the other objects
        (:func:`particlesplat.editing.placement.place`): a move, a step of ``gesture`` when given (so the drag and
        its landing are one operation). ``resting``: it rested on its surface when the drag began (it is set down on
        the new one; else it keeps its height, never below it). Returns a note for the user ("" when it stays where
        it was put). Raises MoveError."""
        self._check_editable(index)
        placed = place(self.scene, self.object_members(index), (0.0, 0.0, 0.0), resting)
        if placed is None:
            return ""
        if any(abs(v) > 1e-9 for v in placed.offset):
            self._commit(Translate(offset=placed.offset).on(self.scene, index), gesture)
        return placed.note

    def scale_object(self, index: int, factor: float, gesture: str | None = None) -> None:
        """Scale particle ``index``'s object ``factor`` times about its resting centre, on its support
        (:class:`particlesplat.editing.operations.Scale`; consecutive calls with the same ``gesture`` multiply into
        one operation until :meth:`end_gesture`). Raises MoveError (nothing changed)."""
        self._check_editable(index)
        self._commit(Scale(factor=float(factor)).on(self.scene, index), gesture)

    def merge_objects(self, index: int, other: int) -> None:
        """Join the objects of particles ``index`` and ``other`` into one. Raises MoveError (one object already,
        or a particle in none)."""
        self._check_editable(index)
        self._check_editable(other)
        self._commit(Merge(other_index=other).on(self.scene, index))

    def split_particle(self, index: int) -> None:
        """Take particle ``index`` out of its object into an object of its own. Raises MoveError (alone already,
        or in no object)."""
        self._check_editable(index)
        self._commit(Split.of(self.scene, index))

    def insert_object(self, source: Particles, insert: Insert) -> int:
        """Insert object ``insert.object`` of another scene's particles ``source`` (encoded with this model) with
        its centre at ``insert.at`` on this scene's floor (:func:`particlesplat.editing.compose.insert_object`): new
        particles, editable like the scene's own. Returns the first new particle. Raises
        ValueError (no such object) or MoveError."""
        n = self.num_particles
        self._commit(InsertObject.of(self.scene, source, insert))
        return n

    @property
    def crop_box(self) -> CropBox | None:
        """The crop box the edits set (None: none), which render and export apply to the Gaussians they draw
        (:meth:`CropBox.crop`)."""
        return self.scene.crop

    def set_crop(self, box: CropBox, gesture: str | None = None) -> None:
        """Hide the Gaussians outside ``box`` (:meth:`CropBox.everything`: show all again); consecutive calls with
        the same ``gesture`` (a handle's drag) are one operation until :meth:`end_gesture`."""
        self._commit(Crop.of(self.scene, box), gesture)

    def reset_particle(self, index: int) -> None:
        """Restore all editable attributes of particle ``index`` to the encoded values."""
        changes = changes_to(self.scene, index, {n: self.original_value(index, n) for n in EDITABLE})
        if changes:
            self._commit(SetAttributes(label=f"reset particle {index}", changes=changes))

    def set_edits(self, edits: Edits, label: str = "load edits") -> None:
        """Set the encoded particles to version 1 ``edits`` (absolute values; unnamed ones as encoded) in one
        operation."""
        scene = self.scene
        check_indices(edits, scene.original.num, label)
        target = apply_edits(scene.original, edits, label)
        changes: list[SetAttribute] = []
        for name in EDITABLE:
            for index in range(scene.original.num):
                new = tuple(float(v) for v in target.attribute(index, name).tolist())
                changes += changes_to(scene, index, {name: new})
        if changes:
            self._commit(SetAttributes(label=label, changes=changes))

    def undo(self) -> Operation | None:
        """Undo the last operation: returns it (its ``label`` says what it was), or None if there is none."""
        self.end_gesture()
        op = self.history.back()
        if op is None:
            return None
        op.undo(self.scene)
        return op

    def redo(self) -> Operation | None:
        """Redo the last undone operation: returns it, or None if there is none."""
        self.end_gesture()
        op = self.history.forward()
        if op is None:
            return None
        op.do(self.scene)
        return op

    # ------------------------------------------------------------------ edit files
    def apply_op(self, op: Operation, where: str = "operation") -> None:
        """Do one edit-file operation (a pick is resolved on the current particles). Errors name ``where``."""
        self._commit(op.replay(self.scene, self.pick, where))

    def apply_file(self, file: EditFile, where: str = "edits") -> None:
        """Do every operation of an edit file (version 1: its particle edits as one operation). All or
        nothing: when an operation fails, the ones before it are taken back and the error names it."""
        if file.version == 1:
            self.set_edits(file.particles, label=where)
            return
        adding = [i for i, op in enumerate(file.operations) if op.adds_particles]
        room = MAX_EDIT_PARTICLES - self.num_particles
        if len(adding) > max(room, 0):  # refused before any work: each adding operation adds a particle or more
            i = adding[max(room, 0)]
            raise EditsError(
                f"{where}: operations[{i}] ({file.operations[i].kind}): the scene has {self.num_particles} particles "
                f"and {len(adding)} operations add at least one each: more than the {MAX_EDIT_PARTICLES} an edited "
                "scene may hold"
            )
        self.end_gesture()
        mark = self.history.mark()
        try:
            for i, op in enumerate(file.operations):
                self.apply_op(op, f"{where}: operations[{i}] ({op.kind})")
        except Exception:
            while self.history.cursor > mark[0]:
                self.undo()
            self.history.restore(mark)
            raise

    def operations(self) -> list[Operation]:
        """What was done, as edit-file operations: an object operation saves a pick of its object on the
        particles as they were before it; attribute changes save the particles' new values."""

        def find(index: int, op: Operation) -> Pick:
            return self.picker.pick_for(self.scene, index, op.before, op.before_labels)

        return [f for op in self.history.undo for f in op.file_operations(find)]

    def save(
        self,
        path: str | PathLike,
        *,
        scene: str | None = None,
        model: str | None = None,
        scene_sha256: str | None = None,
    ) -> Path:
        """Write what was done as a version 2 edit file (see :meth:`operations`)."""
        return save_edit_file(
            path, self.operations(), scene=scene, model=model, context=self.context, scene_sha256=scene_sha256
        )

    def edit_text(self, *, scene: str | None = None, model: str | None = None, scene_sha256: str | None = None) -> str:
        """What :meth:`save` writes, as text (a screenshot's ``edits`` chunk)."""
        return edit_file_text(
            self.operations(), scene=scene, model=model, context=self.context, scene_sha256=scene_sha256
        )
