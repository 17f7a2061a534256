"""The scene session: a :class:`particlesplat.editing.editor.SceneEditor` (particles, their edits as do/undo
operations, objects picked and moved in world metres) plus what only the viewer needs (a fixed .ply,
names for files).

Panels and mouse tools change the session only through its methods; the renderer asks
:meth:`SceneSession.take_changes` which owners to re-decode, so an edit re-decodes only the
edited particles.
"""

from __future__ import annotations

from os import PathLike
from pathlib import Path

import torch

from particlesplat.core.gaussians import Gaussians
from particlesplat.editing.editor import History, Operation, SceneEditor, SetAttribute, load_edit_file, scene_mismatch
from particlesplat.editing.open_scene import EncodedScene

__all__ = ["History", "Operation", "SceneSession", "SetAttribute"]

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

    def autosave_path(self, folder: str | PathLike) -> Path:
        """Where :meth:`autosave` keeps this scene's unsaved edits:
        ``FOLDER/.particlesplat-autosave/NAME.edits.yaml``."""
        return Path(folder) / AUTOSAVE_DIR / f"{Path(self.source).name or 'scene'}.edits.yaml"

    def autosave(self, folder: str | PathLike) -> Path | None:
        """Keep unsaved edits (before the scene is replaced or the window closes); returns the file, or None when
        nothing was unsaved. The session stays unsaved: the user did not save them."""
        if not self.unsaved:
            return None
        return self.save(self.autosave_path(folder), scene=self.source or None, model=self.model_name or None)

    def save_edits(self, path: str | PathLike) -> Path:
        """Write what was done as a version 2 edit file (object operations picked by pixel); returns the path."""
        out = self.save(path, scene=self.source or None, model=self.model_name or None)
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
