"""The scene session: what the viewer shows and edits. It holds a
:class:`particlesplat.editing.editor.SceneEditor` (particles, their edits as do/undo operations, objects picked and
moved in world metres) for a model scene, or a :class:`PlyScene` (a fixed Gaussian set) for a .ply, plus what only
the viewer needs (names and identity for files, autosaves).

Panels and mouse tools change the session only through its methods (the editor's, which it passes on:
:data:`EDITOR_API`); the renderer asks :meth:`SceneSession.take_changes` which owners to re-decode, so an edit
re-decodes only the edited particles.
"""

from __future__ import annotations

import hashlib
from os import PathLike
from pathlib import Path

import torch

from particlesplat.core.gaussians import Gaussians
from particlesplat.editing.editor import (
    EditsError,
    SceneEditor,
    load_edit_file,
    same_scene,
    scene_mismatch,
)
from particlesplat.editing.open_scene import EncodedScene
from particlesplat.editing.scene_id import resolved, scene_digest, scene_file_key

# what the session passes on to its editor (a .ply's editor holds no particles: nothing to edit)
EDITOR_API = (
    "model",
    "particles",
    "original",
    "history",
    "context",
    "frame_cameras",
    "version",
    "editable",
    "num_particles",
    "active_threshold",
    "value",
    "original_value",
    "origin",
    "is_active",
    "edits",
    "decode",
    "object_members",
    "object_offset",
    "object_centre",
    "object_bottom",
    "support_height",
    "take_changes",
    "object_map",
    "pick",
    "pick_for",
    "set_attribute",
    "move_object",
    "remove_object",
    "duplicate_object",
    "insert_object",
    "end_gesture",
    "reset_particle",
    "set_edits",
    "undo",
    "redo",
    "apply_op",
    "apply_file",
    "operations",
    "save",
    "edit_text",
)


class PlyScene:
    """A fixed Gaussian set opened from a .ply: drawn as it is, nothing to edit; each owner id it stores is its
    own object (a plain 3DGS file stores none: everything is background).

    Args:
        gaussians: the Gaussians (checked finite; kept on the CPU).
        source: the .ply path (named in errors).
    """

    def __init__(self, gaussians: Gaussians, source: str = "") -> None:
        gaussians.check(source or "Gaussians")  # the GL renderer would draw NaN as nothing, or everything
        self.gaussians = gaussians.detach().to("cpu")
        self._owner_ids: list[int] | None = None

    def num_owners(self) -> int:
        """Max owner + 1 (0 without owners)."""
        return int(self.gaussians.owner.max()) + 1 if self.gaussians.num else 0

    def owner_ids(self) -> list[int]:
        """The distinct owners >= 0, ascending."""
        if self._owner_ids is None:
            self._owner_ids = [int(o) for o in torch.unique(self.gaussians.owner) if int(o) >= 0]
        return self._owner_ids

    def objects(self) -> torch.Tensor:
        """(num_owners,) each owner its own object."""
        return torch.arange(self.num_owners())


def _pass_on(name: str) -> property:
    return property(lambda self: getattr(self.editor, name), doc=f"The editor's ``{name}`` (:class:`SceneEditor`).")


class SceneSession:
    """What is being viewed: a model's particles (an editor: editable) or a fixed Gaussian set (a .ply).

    Args:
        model: a ParticleSplat model (needed for particles).
        encoded: the encoded scene (particles + cameras), or None for a .ply.
        gaussians: a fixed Gaussian set (a .ply), used when ``encoded`` is None.
        model_name: how the model is named in screenshots and edits files.
        source: the scene folder or .ply path.

    Attributes:
        editor: the scene's :class:`SceneEditor` (for a .ply, one without particles).
        ply: the .ply's :class:`PlyScene`, or None for a model scene.
    """

    def __init__(
        self,
        model=None,
        encoded: EncodedScene | None = None,
        gaussians: Gaussians | None = None,
        model_name: str = "",
        source: str = "",
    ) -> None:
        if encoded is None and gaussians is None:
            raise ValueError("SceneSession needs an encoded scene or a Gaussian set")
        if encoded is not None and model is None:
            raise ValueError("SceneSession: an encoded scene needs its model")
        self.editor = SceneEditor(
            model,
            encoded.particles if encoded is not None else None,
            encoded.all_cameras if encoded is not None else [],
            encoded.context if encoded is not None else None,
        )
        self.encoded = encoded
        self.model_name = model_name
        self.source = source
        self.ply = PlyScene(gaussians, source) if encoded is None and gaussians is not None else None
        self._saved_token = self._history_token()
        self._digest: str | None = None

    # ------------------------------------------------------------------ identity
    @property
    def scene_path(self) -> str:
        """The scene folder or .ply, resolved (absolute, symlinks followed); "" when there is none."""
        return resolved(self.source) if self.source else ""

    @property
    def scene_sha256(self) -> str | None:
        """The digest of the scene's content (:func:`particlesplat.editing.scene_id.scene_digest`), computed once;
        None when the scene is no file or folder."""
        if self._digest is None and self.source and Path(self.source).exists():
            self._digest = scene_digest(self.source)
        return self._digest

    # ------------------------------------------------------------------ queries
    @property
    def cameras(self) -> list:
        """The scene's input cameras (all frames), empty for a .ply."""
        return list(self.encoded.all_cameras) if self.encoded is not None else []

    def num_owners(self) -> int:
        """P for owner maps: particles, or max owner + 1 of a .ply."""
        return self.ply.num_owners() if self.ply is not None else self.editor.num_particles

    def owner_ids(self) -> list[int]:
        """The owners >= 0 the scene holds, ascending: every particle, or the distinct owners of a .ply."""
        return self.ply.owner_ids() if self.ply is not None else list(range(self.editor.num_particles))

    # ------------------------------------------------------------------ Gaussians
    def gaussians(self) -> Gaussians:
        """All Gaussians of the current state (particles with edits, plus background)."""
        return self.ply.gaussians if self.ply is not None else self.editor.decode()

    def objects(self) -> torch.Tensor:
        """(num_owners,) int64 object label per particle (:meth:`SceneEditor.objects`); a .ply has no
        particles to group: each owner is its own object."""
        return self.ply.objects() if self.ply is not None else self.editor.objects()

    def particle_gaussians(self, index: int) -> Gaussians:
        """The Gaussians of one particle (owner = index), decoded alone (none if it is inactive)."""
        return self.model.decode(self.particles, torch.tensor([index]), background=False).detach().to("cpu")

    # ------------------------------------------------------------------ files
    def _history_token(self) -> tuple:
        undo = self.history.undo
        return len(undo), id(undo[-1]) if undo else None

    @property
    def unsaved(self) -> bool:
        """Edits done since the scene was opened, its edits saved or an edit file loaded."""
        return self.editable and self._history_token() != self._saved_token

    @property
    def name(self) -> str:
        """The scene's file or folder name (for file names)."""
        return Path(self.source).stem if self.source.endswith(".ply") else (Path(self.source).name or "scene")

    @property
    def file_key(self) -> str:
        """The stem of this scene's files, ``FAMILY-NAME-HASH`` (:func:`~particlesplat.editing.scene_id.scene_file_key`:
        demo scenes of two families, or two folders of one name, never share a file)."""
        from particlesplat.data.scene_meta import read_family

        return scene_file_key(self.source or "scene", read_family(self.source) if self.source else None)

    def autosave_path(self, folder: str | PathLike) -> Path:
        """Where :meth:`autosave` keeps this scene's unsaved edits: ``FOLDER/FAMILY-NAME-HASH-KEY.edits.yaml`` (the
        viewer's FOLDER: :func:`particlesplat.core.userdirs.autosave_dir`), KEY from the resolved scene path and its
        content (two scenes of one name, or a scene whose files changed, never share an autosave)."""
        key = hashlib.sha256(f"{self.scene_path}\0{self.scene_sha256 or ''}".encode()).hexdigest()[:16]
        return Path(folder) / f"{self.file_key}-{key}.edits.yaml"

    def default_edits_path(self, folder: str | PathLike) -> Path:
        """Where Save edits writes by default: ``FOLDER/FAMILY-NAME-HASH.edits.yaml`` (one file per scene)."""
        return Path(folder) / f"{self.file_key}.edits.yaml"

    def _save(self, path: str | PathLike) -> Path:
        return self.save(
            path, scene=self.scene_path or None, model=self.model_name or None, scene_sha256=self.scene_sha256
        )

    def edit_chunk(self) -> str | dict:
        """The whole edit file of what was done, for a screenshot's ``edits`` chunk (a .ply: no edits)."""
        if not self.editable:
            return {}
        return self.edit_text(
            scene=self.scene_path or None, model=self.model_name or None, scene_sha256=self.scene_sha256
        )

    def autosave(self, folder: str | PathLike) -> Path | None:
        """Keep unsaved edits (before the scene is replaced or the window closes); returns the file, or None when
        nothing was unsaved. The session stays unsaved: the user did not save them."""
        if not self.unsaved:
            return None
        path = self.autosave_path(folder)
        path.parent.mkdir(parents=True, exist_ok=True)
        return self._save(path)

    def foreign_edit_file(self, path: str | PathLike) -> str | None:
        """Why writing this scene's edits to ``path`` would lose something: it holds another scene's edits, or is
        no edit file; None when it does not exist or holds edits of this scene."""
        p = Path(path)
        if not p.exists():
            return None
        try:
            file = load_edit_file(p)
        except (EditsError, OSError, ValueError):
            return f"{p.resolve()} exists and is not an edit file"
        if file.scene is None and file.scene_sha256 is None:
            return None
        if self.source and same_scene(file, self.source):
            return None
        return f"{p.resolve()} holds the edits of another scene ({file.scene or 'unnamed'})"

    def save_edits(self, path: str | PathLike) -> Path:
        """Write what was done as a version 2 edit file (object operations picked by pixel); returns the path."""
        out = self._save(path)
        self._saved_token = self._history_token()
        return out

    def load_edits(self, path: str | PathLike) -> str | None:
        """Do the operations of an edit file (version 1: one operation setting the particles' values).
        Returns a warning when the file names another scene or other context frames, else None."""
        file = load_edit_file(path)
        self.end_gesture()
        if file.version == 2:
            self.apply_file(file, str(path))
        else:
            self.set_edits(file.particles, label=f"load {Path(path).name}")
        self._saved_token = self._history_token()
        return scene_mismatch(file, self.source, self.context) if self.source else None


for _name in EDITOR_API:
    setattr(SceneSession, _name, _pass_on(_name))
