"""Edit files: what was done to a scene, replayed by the viewer and ``particlesplat render --edits``.

Version 2 (version 1, particle index -> attribute values, still loads; see
:mod:`particlesplat.editing.particle_edits`)::

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
      - crop: {min: [-0.7, -0.5, -0.05], max: [0.5, 0.5, 1.0]}
                                            # hide the Gaussians outside this world box (false: show all again)

Operations apply in order; each pick is resolved on the scene as the operations before it left it
(:mod:`particlesplat.editing.picking`). Each operation's record is read and written by its class
(:mod:`particlesplat.editing.operations`); this module holds the document around them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from os import PathLike
from pathlib import Path
from typing import Any

import yaml

from particlesplat.core.atomic import atomic_write
from particlesplat.core.errors import short_repr
from particlesplat.editing.operations import PICKED, Crop, InsertObject, Operation, SetAttributes, Split
from particlesplat.editing.particle_edits import Edits, EditsError, read_edit_document, validate_edits

FORMAT_VERSION = 2
HEADER = ("version", "operations", "scene", "scene_sha256", "model", "context")


@dataclass
class EditFile:
    """A parsed edit file: ``operations`` (version 2, in file form) or ``particles`` (version 1 edits)."""

    version: int
    operations: list[Operation] = field(default_factory=list)
    particles: Edits = field(default_factory=dict)
    scene: str | None = None
    model: str | None = None
    context: list[int] | None = None
    scene_sha256: str | None = None


def read_operation(item: Any, where: str) -> Operation:
    """One operation of a version 2 file, by its keys."""
    kinds = "/".join(PICKED)
    if not isinstance(item, dict):
        raise EditsError(f"{where}: expected a mapping (pick + {kinds}, particle + set/split, insert or crop)")
    if "insert" in item:
        return InsertObject.read(item, where)
    if "crop" in item:
        return Crop.read(item, where)
    if "particle" in item:
        return Split.read(item, where) if "split" in item else SetAttributes.read(item, where)
    found = [k for k in PICKED if k in item]
    unknown = set(item) - {"pick", *PICKED}
    if unknown:
        raise EditsError(
            f"{where}: unknown key(s) {sorted(unknown)} (expected pick and one of {', '.join(PICKED)}, or particle "
            "and set or split)"
        )
    if "pick" not in item or len(found) != 1:
        raise EditsError(f"{where}: expected pick and exactly one of {', '.join(PICKED)}")
    return PICKED[found[0]].read(item, where)


def parse_edit_file(data: Any, where: str = "edits") -> EditFile:
    """Check a parsed edit document, version 1 or 2 (a bare particle mapping is version 1)."""
    if isinstance(data, dict) and data.get("version") == FORMAT_VERSION:
        unknown = set(data) - set(HEADER)
        if unknown:
            raise EditsError(f"{where}: unknown key(s) {sorted(unknown)} (expected {', '.join(HEADER)})")
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
            [read_operation(item, f"{where}: operations[{i}]") for i, item in enumerate(ops)],
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


def edit_file_text(
    ops: list[Operation],
    *,
    scene: str | None = None,
    model: str | None = None,
    context: list[int] | None = None,
    scene_sha256: str | None = None,
) -> str:
    """A version 2 edit file of file-form operations as YAML text (what :func:`save_edit_file` writes;
    screenshots carry it whole)."""
    doc: dict[str, Any] = {"version": FORMAT_VERSION}
    if scene is not None:
        doc["scene"] = str(scene)
    if scene_sha256 is not None:
        doc["scene_sha256"] = str(scene_sha256)
    if model is not None:
        doc["model"] = str(model)
    if context is not None:
        doc["context"] = [int(c) for c in context]
    doc["operations"] = [op.record() for op in ops]
    return yaml.safe_dump(doc, sort_keys=False, default_flow_style=None)


def save_edit_file(
    path: str | PathLike,
    ops: list[Operation],
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
