"""Object edits: operations on objects picked by a pixel of an input frame, their do/undo history, edit files.

The viewer and ``particlesplat render --edits`` both go through :class:`SceneEditor`, so a saved file
replays what the user did. Edit files, version 2 (version 1, particle index -> attribute values, still
loads; see :mod:`particlesplat.editing.particle_edits`)::

    version: 2
    scene: /data/scenes/scene_00000         # optional: the scene folder (resolved) the edits were made on
    scene_sha256: 5f0c...                   # optional: its content (scene_digest); a warning when they differ
    context: [4, 16]                        # optional: the context frames the edits were made on
    operations:
      - pick: {frame: 4, pixel: [61, 70]}   # the object under pixel (x, y) of input frame 4 (stored image)
        translate: [0.20, -0.10, 0.0]       # world metres
      - pick: {frame: 16, pixel: [40, 52]}
        remove: true
      - pick: {frame: 4, pixel: [30, 33]}
        duplicate: [0.0, 0.5, 0.0]          # a copy of the object (new particles), offset in world metres
      - particle: 3                         # one particle's attributes (the viewer's sliders)
        set: {z_t: [0.0]}
      - insert: {scene: assets/scenes/scene_00001, context: [4, 16], object: 0, at: [0.8, 0.5]}
                                            # object 0 of another scene (numbered as particlesplat encode's
                                            # `object`), its centre placed at (x, y) on this scene's floor

Operations apply in order; each pick is resolved on the scene as the operations before it left it, by
rendering that input camera and taking the object whose particles weigh most at the pixel. An object is a
group of particles (:func:`particlesplat.editing.grouping.particle_objects`, grouped once on the scene as encoded),
numbered as ``particlesplat encode`` numbers them (:meth:`SceneEditor.objects`); a copy is an object of its own.
Rotation is not an operation: a particle is a patch lifted along its own view's rays (position z_p, scale z_s,
depth z_d, extent z_e), with no latent for its orientation, so turning an object would show each view's patch
edge-on rather than the object's other side.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from os import PathLike
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, TypeVar

import torch
import yaml
from torch import Tensor

from particlesplat.core.atomic import atomic_write
from particlesplat.core.camera import Camera
from particlesplat.core.errors import short_repr
from particlesplat.core.vectors import float3
from particlesplat.core.world import SUPPORT_Z
from particlesplat.editing.decoded import DecodedParticles
from particlesplat.editing.grouping import (
    OPAQUE,
    dense_objects,
    drawing_particles,
    members_centre,
    particle_objects,
)
from particlesplat.editing.move import MoveError, anchor_points, translate
from particlesplat.editing.particle_edits import (
    Edits,
    EditsError,
    apply_edits,
    check_indices,
    diff_edits,
    finite_float32,
    read_edit_document,
    validate_edits,
)
from particlesplat.model.particles import EDITABLE, Particles
from particlesplat.rendering.api import render
from particlesplat.rendering.pixel import pixel_weights

if TYPE_CHECKING:
    from particlesplat.model.particlesplat import ParticleSplat

FORMAT_VERSION = 2
OpKind = Literal["translate", "remove", "duplicate", "set", "insert"]
OBJECT_KINDS: tuple[OpKind, ...] = ("translate", "remove", "duplicate")
BOTTOM_QUANTILE = 0.02  # an object's bottom: this quantile of its opaque Gaussians' heights
MIN_PICK_PIXELS = 2  # an object must cover this many pixels of a frame to be picked there when saving
# An edited scene holds at most this many particles (64 times what two context views encode; about 0.5 M Gaussians
# at 512 a particle). The cap bounds what one operation costs (a pick composites the Gaussians at one pixel, at
# worst all of them), so an edit file replays in time linear in its operations.
MAX_EDIT_PARTICLES = 1024
ADDING_KINDS: tuple[OpKind, ...] = ("duplicate", "insert")  # operations that add particles (at least one each)
NO_PARTICLES = "this scene has no particles to edit (opened from a .ply)"

T = TypeVar("T")


def _required(value: T | None, missing: str) -> T:
    """``value``, or ValueError(``missing``) where it is None."""
    if value is None:
        raise ValueError(missing)
    return value


class PickError(EditsError):
    """A pick hits no object (or names a frame or pixel the scene does not have)."""


@dataclass(frozen=True)
class Pick:
    """The object under ``pixel`` (x, y: column, row of the stored image) of input frame ``frame``."""

    frame: int
    pixel: tuple[int, int]


@dataclass(frozen=True)
class Insert:
    """Object ``object`` of scene folder ``scene`` (encoded from ``context``, None = the default frames; objects
    numbered as ``particlesplat encode``'s ``object`` array) placed with its centre at ``at`` (x, y) world
    metres on the edited scene's floor (:func:`particlesplat.editing.compose.insert_object`)."""

    scene: str
    object: int
    at: tuple[float, float]
    context: tuple[int, ...] | None = None


@dataclass(frozen=True)
class EditOp:
    """One operation of an edit file.

    Attributes:
        kind: translate / remove / duplicate (an object, by ``pick``) or set (a particle's attributes).
        pick: which object (object kinds).
        offset: (3,) world metres (translate: the move; duplicate: the copy's offset from the original).
        particle: the particle index (set).
        values: ((name, values), ...) absolute attribute values (set), names of ``EDITABLE``.
        insert: the object of another scene and where it goes (insert).
    """

    kind: OpKind
    pick: Pick | None = None
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    particle: int | None = None
    values: tuple[tuple[str, tuple[float, ...]], ...] = ()
    insert: Insert | None = None


@dataclass
class EditFile:
    """A parsed edit file: ``operations`` (version 2) or ``particles`` (version 1 edits)."""

    version: int
    operations: list[EditOp] = field(default_factory=list)
    particles: Edits = field(default_factory=dict)
    scene: str | None = None
    model: str | None = None
    context: list[int] | None = None
    scene_sha256: str | None = None


# ---------------------------------------------------------------------------------------------- files
def _numbers(value: Any, n: int, where: str) -> tuple[float, ...]:
    seq = value if isinstance(value, (list, tuple)) else [value]
    if len(seq) != n or any(
        isinstance(v, bool) or not isinstance(v, (int, float)) or not finite_float32(v) for v in seq
    ):
        raise EditsError(
            f"{where}: expected {n} finite number(s) (float32: |value| <= 3.4e38), got {short_repr(value)}"
        )
    return tuple(float(v) for v in seq)


def _int(value: Any, where: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise EditsError(f"{where}: expected a non-negative integer, got {short_repr(value)}")
    return int(value)


def _parse_insert(item: dict, where: str) -> Insert:
    if set(item) != {"insert"}:
        raise EditsError(f"{where}: an insert operation has the one key insert, got {sorted(item)}")
    spec = item["insert"]
    if (
        not isinstance(spec, dict)
        or not {"scene", "object", "at"} <= set(spec)
        or set(spec) - {"scene", "object", "at", "context"}
    ):
        raise EditsError(
            f"{where}.insert: expected {{scene: DIR, object: K, at: [x, y], context: [..] (optional)}}, "
            f"got {short_repr(spec)}"
        )
    if not isinstance(spec["scene"], str) or not spec["scene"]:
        raise EditsError(f"{where}.insert.scene: expected a scene folder, got {short_repr(spec['scene'])}")
    context = spec.get("context")
    if context is not None and (
        not isinstance(context, list)
        or not context
        or not all(isinstance(c, int) and not isinstance(c, bool) and c >= 0 for c in context)
    ):
        raise EditsError(f"{where}.insert.context: expected a list of frame indices, got {short_repr(context)}")
    at = _numbers(spec["at"], 2, f"{where}.insert.at")
    return Insert(
        spec["scene"],
        _int(spec["object"], f"{where}.insert.object"),
        (at[0], at[1]),
        None if context is None else tuple(context),
    )


def _parse_op(item: Any, where: str) -> EditOp:
    if not isinstance(item, dict):
        raise EditsError(f"{where}: expected a mapping (pick + translate/remove/duplicate, particle + set, or insert)")
    if "insert" in item:
        return EditOp("insert", insert=_parse_insert(item, where))
    if "particle" in item:
        unknown = set(item) - {"particle", "set"}
        if unknown or "set" not in item:
            raise EditsError(f"{where}: a particle operation has the keys particle and set, got {sorted(item)}")
        index = _int(item["particle"], f"{where}.particle")
        edits = validate_edits({index: item["set"]}, where)
        return EditOp("set", particle=index, values=tuple(sorted(edits.get(index, {}).items())))
    kinds = [k for k in OBJECT_KINDS if k in item]
    unknown = set(item) - {"pick", *OBJECT_KINDS}
    if unknown:
        raise EditsError(
            f"{where}: unknown key(s) {sorted(unknown)} (expected pick and one of "
            f"{', '.join(OBJECT_KINDS)}, or particle and set)"
        )
    if "pick" not in item or len(kinds) != 1:
        raise EditsError(f"{where}: expected pick and exactly one of {', '.join(OBJECT_KINDS)}")
    pick = item["pick"]
    if not isinstance(pick, dict) or set(pick) != {"frame", "pixel"}:
        raise EditsError(f"{where}.pick: expected {{frame: F, pixel: [x, y]}}, got {short_repr(pick)}")
    pixel = pick["pixel"]
    if not isinstance(pixel, (list, tuple)) or len(pixel) != 2:
        raise EditsError(f"{where}.pick.pixel: expected [x, y], got {short_repr(pixel)}")
    p = Pick(
        _int(pick["frame"], f"{where}.pick.frame"),
        (_int(pixel[0], f"{where}.pick.pixel"), _int(pixel[1], f"{where}.pick.pixel")),
    )
    kind = kinds[0]
    if kind == "remove":
        if item["remove"] is not True:
            raise EditsError(f"{where}.remove: expected true, got {short_repr(item['remove'])}")
        return EditOp("remove", pick=p)
    return EditOp(kind, pick=p, offset=float3(_numbers(item[kind], 3, f"{where}.{kind}")))


def parse_edit_file(data: Any, where: str = "edits") -> EditFile:
    """Check a parsed edit document, version 1 or 2 (a bare particle mapping is version 1)."""
    if isinstance(data, dict) and data.get("version") == FORMAT_VERSION:
        unknown = set(data) - {"version", "operations", "scene", "scene_sha256", "model", "context"}
        if unknown:
            raise EditsError(
                f"{where}: unknown key(s) {sorted(unknown)} (expected version, operations, scene, scene_sha256, "
                "model, context)"
            )
        digest = data.get("scene_sha256")
        if digest is not None and not (
            isinstance(digest, str) and len(digest) == 64 and all(c in "0123456789abcdef" for c in digest)
        ):
            raise EditsError(f"{where}: scene_sha256: expected 64 hex digits, got {short_repr(digest)}")
        ops = data.get("operations") or []
        if not isinstance(ops, list):
            raise EditsError(f"{where}: operations: expected a list, got {type(ops).__name__}")
        context = data.get("context")
        if context is not None and (
            not isinstance(context, list) or not all(isinstance(c, int) and not isinstance(c, bool) for c in context)
        ):
            raise EditsError(f"{where}: context: expected a list of frame indices, got {short_repr(context)}")
        return EditFile(
            2,
            [_parse_op(item, f"{where}: operations[{i}]") for i, item in enumerate(ops)],
            scene=None if data.get("scene") is None else str(data["scene"]),
            model=None if data.get("model") is None else str(data["model"]),
            context=context,
            scene_sha256=digest,
        )
    if isinstance(data, dict) and "version" in data and data["version"] not in (1, FORMAT_VERSION):
        raise EditsError(f"{where}: version: expected 1 or {FORMAT_VERSION}, got {short_repr(data['version'])}")
    scene = data.get("scene") if isinstance(data, dict) else None
    return EditFile(1, particles=validate_edits(data, where), scene=None if scene is None else str(scene))


def load_edit_file(path: str | PathLike) -> EditFile:
    """Read an edit file (version 1 or 2) with :func:`particlesplat.core.yamlsafe.read_yaml` (safe tags, no aliases,
    no duplicate keys); errors name the file and the field."""
    return parse_edit_file(read_edit_document(path), str(path))


def op_to_yaml(op: EditOp) -> dict[str, Any]:
    """The YAML mapping of one operation (inverse of the parser)."""
    if op.kind == "set":
        index = _required(op.particle, "a set operation needs its particle")
        return {"particle": int(index), "set": {k: [float(x) for x in v] for k, v in op.values}}
    if op.kind == "insert":
        insert = _required(op.insert, "an insert operation needs its insert")
        spec = {
            "scene": insert.scene,
            "object": int(insert.object),
            "at": [round(float(v), 6) for v in insert.at],
        }
        if insert.context is not None:
            spec["context"] = [int(c) for c in insert.context]
        return {"insert": spec}
    pick = _required(op.pick, f"a {op.kind} operation needs its pick")
    out: dict[str, Any] = {"pick": {"frame": int(pick.frame), "pixel": [int(pick.pixel[0]), int(pick.pixel[1])]}}
    out[op.kind] = True if op.kind == "remove" else [round(float(v), 6) for v in op.offset]
    return out


def edit_file_text(
    ops: list[EditOp],
    *,
    scene: str | None = None,
    model: str | None = None,
    context: list[int] | None = None,
    scene_sha256: str | None = None,
) -> str:
    """A version 2 edit file as YAML text (what :func:`save_edit_file` writes; screenshots carry it whole)."""
    doc: dict[str, Any] = {"version": FORMAT_VERSION}
    if scene is not None:
        doc["scene"] = str(scene)
    if scene_sha256 is not None:
        doc["scene_sha256"] = str(scene_sha256)
    if model is not None:
        doc["model"] = str(model)
    if context is not None:
        doc["context"] = [int(c) for c in context]
    doc["operations"] = [op_to_yaml(op) for op in ops]
    return yaml.safe_dump(doc, sort_keys=False, default_flow_style=None)


def save_edit_file(
    path: str | PathLike,
    ops: list[EditOp],
    *,
    scene: str | None = None,
    model: str | None = None,
    context: list[int] | None = None,
    scene_sha256: str | None = None,
) -> Path:
    """Write a version 2 edit file atomically (temp file + rename); returns the path."""
    text = edit_file_text(ops, scene=scene, model=model, context=context, scene_sha256=scene_sha256)
    with atomic_write(path, "w") as f:
        f.write(text)
    return Path(path)


def same_scene(file: EditFile, scene_path: str | PathLike) -> bool:
    """Whether an edit file was made on the scene at ``scene_path``: by content when the file records its
    ``scene_sha256`` (a moved or copied scene is the same scene), else by resolved path (not the folder's name:
    ``train/scene_00000`` and ``test/scene_00000`` are two scenes). A file that names no scene matches."""
    from particlesplat.editing.scene_id import scene_digest

    if file.scene_sha256 is not None:
        try:
            return scene_digest(scene_path) == file.scene_sha256
        except OSError:
            return False
    if file.scene is None:
        return True
    return Path(file.scene).expanduser().resolve() == Path(scene_path).expanduser().resolve()


def scene_mismatch(file: EditFile, scene_path: str | PathLike, context: list[int] | None = None) -> str | None:
    """A warning when an edit file was made on another scene (:func:`same_scene`) or other context frames,
    else None."""
    notes = []
    if not same_scene(file, scene_path):
        how = "another scene's content" if file.scene_sha256 is not None else "another scene path"
        notes.append(f"they were made on scene {file.scene or '(unnamed)'} ({how}), this is {scene_path}")
    if file.context is not None and context is not None and list(file.context) != list(context):
        notes.append(f"they were made with context frames {file.context}, these are {list(context)}")
    return "; ".join(notes) or None


# ---------------------------------------------------------------------------------------------- history
@dataclass(frozen=True)
class SetAttribute:
    """One attribute change of one particle."""

    index: int
    name: str
    old: tuple[float, ...]
    new: tuple[float, ...]


@dataclass
class Operation:
    """A do/undo step: attribute changes applied together, and particles it appends (a duplicate).

    Attributes:
        label: what the history shows.
        changes: attribute changes (applied after ``added`` is appended).
        open_key: set while a drag gesture may still extend this operation.
        kind: what an edit file records it as (object kinds save a pick; set saves the changed values).
        members: the particles of the object it acts on (object kinds).
        offset: (3,) world metres of a translate or duplicate (a drag adds up).
        added: particles appended by the operation (their values before ``changes``), or None.
        added_labels: (len(added),) object labels of the appended particles.
        sources: rows of the appended particles in :meth:`SceneEditor.origin` (insert; else those of ``members``).
        insert: what an insert operation inserted (saved as such).
        before: the particles as they were before the operation (to pick its object when saving).
    """

    label: str
    changes: list[SetAttribute]
    open_key: tuple | None = None
    kind: OpKind = "set"
    members: tuple[int, ...] = ()
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    added: Particles | None = None
    added_labels: Tensor | None = None
    before: Particles | None = None
    sources: tuple[int, ...] = ()
    insert: Insert | None = None
    pick: Pick | None = None


@dataclass
class History:
    """Undo and redo stacks of operations."""

    undo: list[Operation] = field(default_factory=list)
    redo: list[Operation] = field(default_factory=list)


# ---------------------------------------------------------------------------------------------- editor
class SceneEditor:
    """Particles of one scene under edit, as named do/undo operations.

    Args:
        model: the ParticleSplat model that decodes the particles, or None (a scene opened from a .ply).
        particles: the encoded particles (kept as the original), or None (nothing to edit).
        frame_cameras: the scene's input cameras at their stored size, indexed by frame (picks name these).
        context: the context frame indices (saved in edit files; picks try them first).
        z_t_threshold: the particles that draw (None: the model's, :meth:`ParticleSplat.decode`; 0 draws the
            inactive ones too, as before they were dropped: for measuring that).
    """

    def __init__(
        self,
        model: ParticleSplat | None,
        particles: Particles | None,
        frame_cameras: list[Camera] | None = None,
        context: list[int] | None = None,
        z_t_threshold: float | None = None,
    ) -> None:
        if model is None and particles is not None:
            raise ValueError("SceneEditor: particles need the model that decodes them")
        self.model = model
        self.z_t_threshold = z_t_threshold
        self.frame_cameras = list(frame_cameras or [])
        self.context = list(context) if context is not None else None
        self.history = History()
        self.original: Particles | None = particles.detach().to("cpu") if particles is not None else None
        self.particles: Particles | None = self.original.clone() if self.original is not None else None
        self._objects: Tensor | None = None
        self._labels: tuple[tuple[int, int], Tensor] | None = None  # objects() as of (version, operations done)
        # a scene opened from a .ply has no model and no particles
        self._decoded = DecodedParticles(model, z_t_threshold) if model is not None else None
        self._source: list[int] = list(range(self.original.num)) if self.original is not None else []
        self._inserted: Particles | None = None  # inserted particles as inserted: origin() rows past the original
        self._changed: set[int] = set()
        self._all_changed = True
        self.version = 0  # bumps on every change of the Gaussians

    # ------------------------------------------------------------------ queries
    def _particles(self) -> Particles:
        """The particles under edit; ValueError for a scene without them (opened from a .ply)."""
        return _required(self.particles, NO_PARTICLES)

    def _original(self) -> Particles:
        """The particles as encoded; ValueError for a scene without them (opened from a .ply)."""
        return _required(self.original, NO_PARTICLES)

    def _model(self) -> ParticleSplat:
        """The model that decodes the particles; ValueError for a scene without one (opened from a .ply)."""
        return _required(self.model, NO_PARTICLES)

    @property
    def editable(self) -> bool:
        return self.particles is not None

    @property
    def num_particles(self) -> int:
        return self.particles.num if self.particles is not None else 0

    def value(self, index: int, name: str) -> tuple[float, ...]:
        return tuple(float(v) for v in self._particles().attribute(index, name).tolist())

    def origin(self) -> Particles:
        """The particles as encoded, followed by every particle inserted from another scene as it was inserted
        (the rows :meth:`original_value` and :meth:`object_offset` refer to)."""
        original = self._original()
        return original if self._inserted is None else original.cat(self._inserted)

    def original_value(self, index: int, name: str) -> tuple[float, ...]:
        """The encoded value (a copy's: that of the particle it was copied from; an inserted one's: as inserted)."""
        return tuple(float(v) for v in self.origin().attribute(self._source[index], name).tolist())

    @property
    def active_threshold(self) -> float:
        """z_t at and above which a particle draws: the model's ``bg_mask_threshold`` (the decoder drops
        particles below it, :meth:`ParticleSplat.decode`), else 0.5."""
        return float(getattr(getattr(self.model, "config", None), "bg_mask_threshold", 0.5))

    def is_active(self, index: int) -> bool:
        """Active = draws: z_t at or above :attr:`active_threshold`."""
        return float(self._particles().z_t[index, 0]) >= self.active_threshold

    def edits(self) -> Edits:
        """Version 1 edits (absolute values) of the encoded particles; copies are not part of them."""
        if self.particles is None:
            return {}
        original = self._original()
        return diff_edits(original, self.particles.truncate(original.num))

    def decode(self, particles: Particles | None = None):
        """All Gaussians (edits applied, background included) on the CPU; of the current particles (the default)
        from the Gaussians kept up to date edit by edit (:class:`particlesplat.editing.decoded.DecodedParticles`)."""
        p = self._particles() if particles is None else particles
        if self._decoded is not None and p is self.particles:
            return self._decoded.gaussians(p)
        return self._model().decode(p, z_t_threshold=self.z_t_threshold).detach().to("cpu")

    def objects(self) -> Tensor:
        """(num_particles,) int64 object number per particle, the numbering ``particlesplat encode`` writes
        (:func:`particlesplat.editing.grouping.dense_objects`: 0..K-1 in the order of each object's smallest
        particle index, -1 for a particle that draws nothing). Grouped once on the scene as encoded, so an edit
        does not regroup it; a copied or inserted object takes the next number."""
        if self._objects is None:
            original = self._original()
            g = self.decode(original)
            groups = particle_objects(g, original.num)
            self._objects = dense_objects(groups, drawing_particles(original, g, self.active_threshold))
        key = (self.version, len(self.history.undo))
        if self._labels is None or self._labels[0] != key:
            added = [op.added_labels for op in self.history.undo if op.added_labels is not None]
            self._labels = (key, torch.cat([self._objects, *added]) if added else self._objects)
        return self._labels[1]

    def object_members(self, index: int) -> list[int]:
        """The particles of particle ``index``'s object (:meth:`objects`), ascending; a particle that draws
        nothing is alone."""
        labels = self.objects()
        if int(labels[index]) < 0:
            return [index]
        return [int(j) for j in torch.nonzero(labels == labels[index]).flatten()]

    def _next_object(self) -> int:
        """The number a new (copied or inserted) object takes: one past the largest."""
        labels = self.objects()
        return int(labels.max()) + 1 if labels.numel() else 0

    def support_height(self) -> float:
        """The height (world z, metres) objects rest on: the support surface of the shared world frame
        (:data:`particlesplat.core.world.SUPPORT_Z`; the tabletop's floor, the robot's table top)."""
        return SUPPORT_Z

    def object_centre(self, index: int) -> Tensor | None:
        """(3,) float64 world metres: the resting centre of particle ``index``'s object as drawn now
        (:func:`particlesplat.editing.grouping.members_centre`, as ``particlesplat encode`` and ``eval`` place
        objects), or None if it draws nothing."""
        return members_centre(self._model(), self._particles(), self.object_members(index), self.support_height())

    def object_bottom(self, index: int) -> float | None:
        """World height (metres) of the lowest part of particle ``index``'s object as drawn now: the
        ``BOTTOM_QUANTILE`` of its opaque Gaussians' centres (a few stray ones do not count); None if it draws
        nothing opaque."""
        g = self._model().decode(self._particles(), torch.tensor(self.object_members(index)), background=False)
        z = g.means[:, 2][g.opacities >= OPAQUE].detach().double()
        return float(torch.quantile(z, BOTTOM_QUANTILE)) if z.numel() else None

    def object_offset(self, index: int) -> tuple[float, float, float]:
        """World offset (metres) of particle ``index``'s anchor from where it (or what it copies) was encoded."""
        cfg = self._model().config
        now = anchor_points(self._particles(), [index], cfg)[0]
        was = anchor_points(self.origin(), [self._source[index]], cfg)[0]
        return float3(now - was)

    def take_changes(self) -> set[int] | None:
        """Particles whose Gaussians changed since the last call; None = everything (or the count) changed."""
        if self._all_changed:
            self._all_changed, self._changed = False, set()
            return None
        out, self._changed = self._changed, set()
        return out

    # ------------------------------------------------------------------ picking
    def _frame_camera(self, frame: int, where: str) -> Camera:
        if not 0 <= frame < len(self.frame_cameras):
            raise PickError(f"{where}: pick.frame {frame}: the scene has frames 0..{len(self.frame_cameras) - 1}")
        return self.frame_cameras[frame]

    def object_map(self, frame: int, particles: Particles | None = None, where: str = "pick") -> Tensor:
        """(H, W) int64 object label per pixel of input frame ``frame`` at its stored size (-1 background)."""
        p = self._particles() if particles is None else particles
        return self._label_render(self.decode(p), self._frame_camera(frame, where), self.objects()[: p.num])

    def _label_render(self, g, cam: Camera, labels: Tensor) -> Tensor:
        """(H, W) int64 object label per pixel of Gaussians ``g`` (owner = particle) seen by ``cam``; labels:
        (particles,) object per particle."""
        # the rasteriser sums each object's weights itself: owners are object labels (a particle in no object
        # draws as background, as object_segmentation counts it), so the owner weights hold one plane per object,
        # not one per particle (a scene grown by many duplicates would need particles x pixels of them)
        g = replace(g, owner=torch.where(g.owner >= 0, labels.to(g.owner.device)[g.owner.clamp_min(0)], g.owner))
        count = int(labels.max()) + 1 if labels.numel() else 0
        if count <= 0:
            return torch.full((cam.height, cam.width), -1, dtype=torch.int64)
        with torch.no_grad():
            res = render(
                g,
                cam.to("cpu", torch.float32),
                background=self._model().background_color().cpu(),
                owner_weights=True,
                num_owners=count,
            )
        return res.segmentation()

    def _pixel_object(self, frame: int, cam: Camera, pixel: tuple[int, int]) -> int:
        """The object label at ``pixel`` of frame ``frame`` on the current particles, -1 for the background, as
        :meth:`object_map` has it there; composited from the Gaussians that reach the pixel alone, so a pick costs
        what they cost, not what the whole scene does."""
        if self._decoded is None or self.particles is None:
            raise PickError("this scene has no particles to pick (opened from a .ply)")
        g = self._decoded.reaching(self.particles, cam, frame, pixel)
        index, weights = pixel_weights(g, cam.to("cpu", torch.float32), pixel)
        labels = self.objects()
        owner = g.owner[index]
        label = torch.where(owner >= 0, labels[owner.clamp_min(0)], owner)
        count = int(labels.max()) + 1 if labels.numel() else 0
        scores = torch.zeros(1 + count, dtype=torch.float64)
        scores.index_add_(0, (label + 1).clamp_min(0), weights.double())
        scores[0] += 1.0 - float(weights.double().sum())  # the empty remainder counts as background
        return int(scores.argmax()) - 1

    def pick(self, pick: Pick, where: str = "pick") -> int:
        """The first particle of the object under ``pick`` on the current particles; PickError names ``where``
        when the pixel shows no object."""
        cam = self._frame_camera(pick.frame, where)
        x, y = pick.pixel
        if not (0 <= x < cam.width and 0 <= y < cam.height):
            raise PickError(f"{where}: pick.pixel [{x}, {y}] is outside frame {pick.frame} ({cam.width}x{cam.height})")
        label = self._pixel_object(pick.frame, cam, (x, y))
        if label < 0:
            raise PickError(f"{where}: pick {{frame: {pick.frame}, pixel: [{x}, {y}]}} hits no object (background)")
        return int(torch.nonzero(self.objects() == label)[0])

    def pick_for(self, index: int, particles: Particles | None = None) -> Pick:
        """A pixel of an input frame that picks particle ``index``'s object on ``particles`` (default: now):
        the object's most interior pixel in the context frame (else any frame) where it covers most pixels."""
        label = int(self.objects()[index])
        if label < 0:
            raise PickError(f"object of particle {index}: it draws nothing, so no pick names it")
        frames = list(self.context or []) + [f for f in range(len(self.frame_cameras)) if f not in (self.context or [])]
        best: tuple[int, int, Tensor] | None = None
        for i, f in enumerate(frames):
            mask = self.object_map(f, particles) == label
            count = int(mask.sum())
            if count >= MIN_PICK_PIXELS and (best is None or count > best[1]):
                best = (f, count, mask)
            if best is not None and i + 1 >= len(self.context or []):
                break  # the context frames are searched in full, the others until one shows the object
        if best is None:
            raise PickError(f"object of particle {index}: not visible in any input frame, so no pick names it")
        f, _, mask = best
        depth = torch.zeros(mask.shape, dtype=torch.float32)
        cur = mask.float()[None, None]
        while bool(cur.any()):  # erosion depth: the pixel farthest inside the object
            depth += cur[0, 0]
            cur = -torch.nn.functional.max_pool2d(-cur, 3, stride=1, padding=1)
        ys, xs = torch.nonzero(depth == depth.max(), as_tuple=True)
        cy, cx = mask.nonzero().float().mean(0)
        k = int(((ys.float() - cy) ** 2 + (xs.float() - cx) ** 2).argmin())
        return Pick(f, (int(xs[k]), int(ys[k])))

    # ------------------------------------------------------------------ operations
    def _apply(self, op: Operation, forward: bool) -> None:
        particles = self._particles()
        if forward and op.added is not None:
            particles = particles.cat(op.added)  # the new rows are decoded on first use
            self._source += list(op.sources) if op.sources else [self._source[i] for i in op.members]
            self._all_changed = True
        for ch in op.changes if forward else reversed(op.changes):
            particles = particles.with_attribute(ch.index, ch.name, ch.new if forward else ch.old)
            self._changed.add(ch.index)
        if self._decoded is not None:
            self._decoded.invalidate(ch.index for ch in op.changes)
        if not forward and op.added is not None:
            particles = particles.truncate(particles.num - op.added.num)
            if self._decoded is not None:
                self._decoded.truncate(particles.num)
            del self._source[particles.num :]
            self._all_changed = True
        self.particles = particles
        self.version += 1

    def _push(self, op: Operation) -> None:
        op.before = self.particles
        self.history.undo.append(op)  # first: objects() then counts a duplicate's labels
        self._apply(op, True)
        self.history.redo.clear()

    def _check_editable(self, index: int) -> None:
        num = self._particles().num
        if not 0 <= index < num:
            raise IndexError(f"particle {index} out of range (0..{num - 1})")

    def _record(self, op: Operation) -> None:
        """Apply ``op``, or, when the last operation is the open gesture ``op.open_key``, extend it (each
        attribute keeps the old value it had when the gesture began; offsets add up)."""
        last = self.history.undo[-1] if self.history.undo else None
        if op.open_key is not None and last is not None and last.open_key == op.open_key:
            merged = {(c.index, c.name): c for c in last.changes}
            for c in op.changes:
                first = merged.get((c.index, c.name), c)
                merged[(c.index, c.name)] = SetAttribute(c.index, c.name, first.old, c.new)
            last.changes = list(merged.values())
            last.offset = float3(a + b for a, b in zip(last.offset, op.offset, strict=False))
            self._apply(replace(op, added=None), True)
            return
        self._push(op)

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
        self._record(
            Operation(
                f"set {name} of particle {index}",
                [SetAttribute(index, name, old, new)],
                (gesture, index, name) if gesture is not None else None,
            )
        )

    def _members_label(self, members: list[int]) -> str:
        return f"particle{'s' if len(members) > 1 else ''} {', '.join(map(str, members))}"

    def move_object(self, index: int, delta, gesture: str | None = None) -> None:
        """Translate every particle of particle ``index``'s object by ``delta`` (3,) world metres (one
        operation; consecutive calls with the same ``gesture`` extend it until :meth:`end_gesture`).
        Raises :class:`particlesplat.editing.move.MoveError` (nothing changed) if a particle would leave the
        model's depth range."""
        self._check_editable(index)
        members = self.object_members(index)
        delta = tuple(float(v) for v in torch.as_tensor(delta, dtype=torch.float64).reshape(3).tolist())
        target = translate(self._particles(), members, delta, self._model().config)
        changes = [
            SetAttribute(i, name, self.value(i, name), value)
            for i, attrs in target.items()
            for name, value in attrs.items()
            if value != self.value(i, name)
        ]
        if changes:
            self._record(
                Operation(
                    f"move object of {self._members_label(members)}",
                    changes,
                    (gesture, "move", tuple(members)) if gesture is not None else None,
                    kind="translate",
                    members=tuple(members),
                    offset=delta,
                )
            )

    def remove_object(self, index: int) -> None:
        """Remove particle ``index``'s object: its particles' z_t go to 0, so they no longer draw."""
        self._check_editable(index)
        members = self.object_members(index)
        changes = [
            SetAttribute(i, "z_t", self.value(i, "z_t"), (0.0,)) for i in members if self.value(i, "z_t") != (0.0,)
        ]
        if not changes:
            return  # already removed
        self.end_gesture()
        self._push(
            Operation(
                f"remove object of {self._members_label(members)}", changes, kind="remove", members=tuple(members)
            )
        )

    def duplicate_object(self, index: int, offset) -> int:
        """Copy particle ``index``'s object (new particles, the same latents) and move the copy by ``offset``
        (3,) world metres. Returns the copy's first particle. Raises MoveError."""
        self._check_editable(index)
        members = self.object_members(index)
        offset = tuple(float(v) for v in torch.as_tensor(offset, dtype=torch.float64).reshape(3).tolist())
        n = self.num_particles
        _check_room(n, len(members), "duplicate")
        particles = self._particles()
        grown = particles.cat(particles.take(members))
        new = list(range(n, n + len(members)))
        target = translate(grown, new, offset, self._model().config)
        changes = [
            SetAttribute(i, name, tuple(float(v) for v in grown.attribute(i, name).tolist()), value)
            for i, attrs in target.items()
            for name, value in attrs.items()
        ]
        self.end_gesture()
        added = grown.take(slice(n, None))
        self._push(
            Operation(
                f"duplicate object of {self._members_label(members)}",
                changes,
                kind="duplicate",
                members=tuple(members),
                offset=offset,
                added=added,
                added_labels=torch.full((len(members),), self._next_object(), dtype=torch.int64),
            )
        )
        return n

    def insert_object(self, source: Particles, insert: Insert) -> int:
        """Insert object ``insert.object`` of another scene's particles ``source`` (encoded with this model) with
        its centre at ``insert.at`` on this scene's floor (:func:`particlesplat.editing.compose.insert_object`): new
        particles, editable like the scene's own. Returns the first new particle. Raises
        ValueError (no such object) or MoveError."""
        from particlesplat.editing.compose import insert_object

        particles = self._particles()
        n = particles.num
        _check_room(n, 1, "insert")
        grown, new = insert_object(self._model(), particles, source, insert.object, insert.at)
        _check_room(n, grown.num - n, "insert")
        added = grown.take(slice(n, None))
        added = added.detach().to("cpu")
        rows = self._original().num + (0 if self._inserted is None else self._inserted.num)
        self._inserted = added if self._inserted is None else self._inserted.cat(added)
        self.end_gesture()
        self._push(
            Operation(
                f"insert object {insert.object} of {Path(insert.scene).name}",
                [],
                kind="insert",
                added=added,
                added_labels=torch.full((len(new),), self._next_object(), dtype=torch.int64),
                sources=tuple(range(rows, rows + len(new))),
                insert=insert,
            )
        )
        return n

    def end_gesture(self) -> None:
        """Close the open drag operation, if any."""
        if self.history.undo:
            self.history.undo[-1].open_key = None

    def reset_particle(self, index: int) -> None:
        """Restore all editable attributes of particle ``index`` to the encoded values."""
        changes = [
            SetAttribute(index, n, self.value(index, n), self.original_value(index, n))
            for n in EDITABLE
            if self.value(index, n) != self.original_value(index, n)
        ]
        if changes:
            self.end_gesture()
            self._push(Operation(f"reset particle {index}", changes))

    def set_edits(self, edits: Edits, label: str = "load edits") -> None:
        """Set the encoded particles to version 1 ``edits`` (absolute values; unnamed ones as encoded) in one
        operation."""
        original = self._original()
        check_indices(edits, original.num, label)
        target = apply_edits(original, edits, label)
        changes = []
        for name in EDITABLE:
            for index in range(original.num):
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
        op = self.history.undo[-1]
        op.open_key = None
        self._apply(op, False)
        self.history.undo.pop()
        self.history.redo.append(op)
        return True

    def redo(self) -> bool:
        """Redo the last undone operation; False if there is none."""
        if not self.history.redo:
            return False
        op = self.history.redo.pop()
        self.history.undo.append(op)
        self._apply(op, True)
        return True

    # ------------------------------------------------------------------ edit files
    def apply_op(self, op: EditOp, where: str = "operation") -> None:
        """Do one edit-file operation (a pick is resolved on the current particles). Errors name ``where``."""
        if op.kind == "set":
            particle = _required(op.particle, f"{where}: a set operation needs its particle")
            if not 0 <= particle < self.num_particles:
                raise EditsError(f"{where}: particle {particle}: no such particle (the scene has {self.num_particles})")
            changes = [
                SetAttribute(particle, n, self.value(particle, n), tuple(v))
                for n, v in op.values
                if self.value(particle, n) != tuple(v)
            ]
            if changes:
                self.end_gesture()
                self._push(Operation(f"set particle {particle}", changes))
            return
        if op.kind == "insert":
            from particlesplat.editing.open_scene import encode_scene

            insert = _required(op.insert, f"{where}: an insert operation needs its insert")
            try:
                source = encode_scene(
                    self._model(), insert.scene, None if insert.context is None else list(insert.context)
                ).particles
                self.insert_object(source, insert)
            except (MoveError, ValueError, OSError) as e:
                raise EditsError(f"{where}: insert: {e}") from None
            return
        pick = _required(op.pick, f"{where}: a {op.kind} operation needs its pick")
        index = self.pick(pick, where)
        done = len(self.history.undo)
        try:
            if op.kind == "translate":
                self.move_object(index, op.offset)
                self.end_gesture()
            elif op.kind == "remove":
                self.remove_object(index)
            else:
                self.duplicate_object(index, op.offset)
        except MoveError as e:
            raise EditsError(f"{where}: {e}") from None
        if len(self.history.undo) > done:
            self.history.undo[-1].pick = pick  # saved as it was read: a replayed file saves itself

    def apply_file(self, file: EditFile, where: str = "edits") -> None:
        """Do every operation of an edit file (version 1: its particle edits as one operation). All or
        nothing: when an operation fails, the ones before it are taken back and the error names it."""
        if file.version == 1:
            self.set_edits(file.particles, label=where)
            return
        adding = [i for i, op in enumerate(file.operations) if op.kind in ADDING_KINDS]
        room = MAX_EDIT_PARTICLES - self.num_particles
        if len(adding) > max(room, 0):  # refused before any work: each adding operation adds a particle or more
            i = adding[max(room, 0)]
            raise EditsError(
                f"{where}: operations[{i}] ({file.operations[i].kind}): the scene has {self.num_particles} particles "
                f"and {len(adding)} operations add at least one each: more than the {MAX_EDIT_PARTICLES} an edited "
                "scene may hold"
            )
        self.end_gesture()
        done, redo = len(self.history.undo), list(self.history.redo)
        try:
            for i, op in enumerate(file.operations):
                self.apply_op(op, f"{where}: operations[{i}] ({op.kind})")
        except Exception:
            while len(self.history.undo) > done:
                self.undo()
            self.history.redo = redo
            raise

    def operations(self) -> list[EditOp]:
        """What was done, as edit-file operations: an object operation saves a pick of its object on the
        particles as they were before it; attribute changes save the particles' new values."""
        out: list[EditOp] = []
        for op in self.history.undo:
            if op.kind == "insert":
                out.append(EditOp("insert", insert=op.insert))
                continue
            if op.kind in OBJECT_KINDS:
                if op.pick is None:  # found once: the particles before the operation do not change
                    op.pick = self.pick_for(op.members[0], op.before)
                out.append(EditOp(op.kind, pick=op.pick, offset=op.offset))
                continue
            per: dict[int, dict[str, tuple[float, ...]]] = {}
            for c in op.changes:
                per.setdefault(c.index, {})[c.name] = c.new
            out += [EditOp("set", particle=i, values=tuple(sorted(v.items()))) for i, v in sorted(per.items())]
        return out

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


def _check_room(num: int, more: int, what: str) -> None:
    """MoveError unless a scene of ``num`` particles can take ``more`` (:data:`MAX_EDIT_PARTICLES`)."""
    if num + more > MAX_EDIT_PARTICLES:
        raise MoveError(
            f"{what}: the scene would have {num + more} particles, more than the {MAX_EDIT_PARTICLES} an edited "
            "scene may hold"
        )
