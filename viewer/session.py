"""The scene session: a :class:`particlesplat.editing.editor.SceneEditor` (particles, their edits as do/undo
operations, objects picked and moved in world metres) plus what only the viewer needs (a fixed .ply,
names for files).

Panels and mouse tools change the session only through its methods; the renderer asks
:meth:`SceneSession.take_changes` which owners to re-decode, so an edit re-decodes only the
edited particles.
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
from particlesplat.editing.scene_id import resolved, scene_digest

AUTOSAVE_DIR = ".particlesplat-autosave"  # under the viewer's --output-dir


class SceneSession(SceneEditor):
    """What is being viewed: either a model's particles (editable) or a fixed Gaussian set (.ply).

    Args:
        model: a ParticleSplat model (needed for particles).
        encoded: the encoded scene (particles + cameras), or None for a .ply.
        gaussians: a fixed Gaussian set (a .ply), used when ``encoded`` is None.
        model_name: how the model is named in screenshots and edits files.
        source: the scene folder or .ply path.
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
        super().__init__(
            model,
            encoded.particles if encoded is not None else None,
            encoded.all_cameras if encoded is not None else [],
            encoded.context if encoded is not None else None,
        )
        self.encoded = encoded
        self.model_name = model_name
        self.source = source
        if gaussians is not None:
            gaussians.check(source or "Gaussians")  # the GL renderer would draw NaN as nothing, or everything
        self._fixed = gaussians.detach().to("cpu") if gaussians is not None else None
        self._owner_ids: list[int] | None = None
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

    # ------------------------------------------------------------------ Gaussians
    def gaussians(self) -> Gaussians:
        """All Gaussians of the current state (particles with edits, plus background)."""
        if self._fixed is not None:
            return self._fixed
        return self.decode()

    def objects(self) -> torch.Tensor:
        """(num_owners,) int64 object label per particle (:meth:`SceneEditor.objects`); a .ply has no
        particles to group: each owner is its own object."""
        if self._fixed is not None:
            return torch.arange(self.num_owners())
        return super().objects()

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

    def autosave_path(self, folder: str | PathLike) -> Path:
        """Where :meth:`autosave` keeps this scene's unsaved edits:
        ``FOLDER/.particlesplat-autosave/NAME-KEY.edits.yaml``, KEY from the resolved scene path and its content
        (two scenes of one name, or a scene whose files changed, never share an autosave)."""
        key = hashlib.sha256(f"{self.scene_path}\0{self.scene_sha256 or ''}".encode()).hexdigest()[:16]
        return Path(folder) / AUTOSAVE_DIR / f"{self.name}-{key}.edits.yaml"

    def default_edits_path(self, folder: str | PathLike) -> Path:
        """Where Save edits writes by default: ``FOLDER/NAME.edits.yaml`` (one file per scene)."""
        return Path(folder) / f"{self.name}.edits.yaml"

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
