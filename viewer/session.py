"""What the viewer shows: a :class:`Scene`. An :class:`EditableScene` holds a model's particles under edit (its
:attr:`EditableScene.editor`, a :class:`particlesplat.editing.editor.SceneEditor`: do/undo operations, objects
picked and moved in world metres); a :class:`PlyScene` holds a fixed Gaussian set opened from a .ply (its
``editor`` is None: nothing to edit). Both carry what only the viewer needs (names and identity for files,
autosaves).

Panels, tools and actions edit only through ``scene.editor``; the renderer asks :meth:`Scene.take_changes` which
owners to re-decode, so an edit re-decodes only the edited particles.
"""

from __future__ import annotations

import hashlib
from os import PathLike
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

import torch

from particlesplat.core.gaussians import BACKGROUND_OWNER, Gaussians
from particlesplat.core.outputs import guard_outputs
from particlesplat.editing.crop_box import CropBox, workspace_box
from particlesplat.editing.editor import EditsError, SceneEditor, load_edit_file, same_scene, scene_mismatch
from particlesplat.editing.scene_id import resolved, scene_digest, scene_file_key

if TYPE_CHECKING:
    from particlesplat.core.camera import Camera
    from particlesplat.editing.open_scene import EncodedScene
    from particlesplat.model.particles import Particles
    from particlesplat.model.particlesplat import ParticleSplat


class Scene(Protocol):
    """What the viewer draws, picks and saves, whatever the scene was opened from."""

    source: str  # the scene folder or .ply path, as given
    model_name: str  # how the model is named in screenshots and edit files ("" for a .ply)

    @property
    def editor(self) -> SceneEditor | None:
        """The particles under edit; None when there is nothing to edit (a .ply)."""
        ...

    @property
    def model(self) -> ParticleSplat | None: ...

    @property
    def cameras(self) -> list[Camera]:
        """The scene's input cameras (all frames), empty for a .ply."""
        ...

    @property
    def version(self) -> int:
        """Bumps on every change of the Gaussians."""
        ...

    @property
    def context(self) -> list[int] | None:
        """The context frames the particles were encoded from (None for a .ply)."""
        ...

    @property
    def warnings(self) -> list[str]:
        """What opening the scene found questionable (shown under its name)."""
        ...

    @property
    def name(self) -> str: ...

    @property
    def unsaved(self) -> bool: ...

    def gaussians(self) -> Gaussians:
        """All Gaussians of the current state (background included)."""
        ...

    def objects(self) -> torch.Tensor:
        """(num_owners,) int64 object label per owner."""
        ...

    def num_owners(self) -> int: ...

    def owner_ids(self) -> list[int]: ...

    def take_changes(self) -> set[int] | None:
        """Owners whose Gaussians changed since the last call; None = everything changed."""
        ...

    def particle_gaussians(self, index: int) -> Gaussians: ...

    def edit_chunk(self) -> str | dict:
        """The whole edit file of what was done, for a screenshot's ``edits`` chunk."""
        ...

    def autosave(self, folder: str | PathLike) -> Path | None: ...

    def autosave_path(self, folder: str | PathLike) -> Path: ...

    def inputs(self) -> list[tuple[str, str]]:
        """(flag, path) of what the scene was opened from (:meth:`SceneFiles.inputs`)."""
        ...

    def guard_output(self, what: str, path: str | PathLike) -> None:
        """OutputError unless the viewer may write ``path`` (:meth:`SceneFiles.guard_output`)."""
        ...

    def default_edits_path(self, folder: str | PathLike) -> Path: ...


def session_particles(session: Scene) -> Particles | None:
    """The particles of a session's scene as edited (None for a .ply: nothing encoded)."""
    return None if session.editor is None else session.editor.particles


class SceneFiles:
    """A scene's identity for file names: its source, resolved path and content digest."""

    def __init__(self, source: str, model_name: str) -> None:
        self.source = source
        self.model_name = model_name
        self._digest: str | None = None

    def inputs(self) -> list[tuple[str, str]]:
        """(flag, path) of what the scene was opened from, as the command line names it (``--ply``; ``--scene``
        and ``--checkpoint``): what no output of the viewer may replace."""
        raise NotImplementedError

    def guard_output(self, what: str, path: str | PathLike) -> None:
        """OutputError (one line, ``what`` naming the output: ``screenshot``, ``export``, ``edits file``,
        ``autosave``) when ``path`` is one of :meth:`inputs`, an existing file inside the scene folder, or lies in a
        run folder a live process holds (:func:`particlesplat.core.outputs.guard_outputs`); checked before anything
        is written, so nothing is replaced."""
        guard_outputs([(what, path)], self.inputs())

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


class PlyScene(SceneFiles):
    """A fixed Gaussian set opened from a .ply: drawn as it is, nothing to edit; each owner id it stores is its
    own object (a plain 3DGS file stores none: everything is background).

    Args:
        gaussians: the Gaussians (checked finite; kept on the CPU).
        source: the .ply path (named in errors).
    """

    editor: None = None
    model: None = None
    context: None = None
    version = 0
    unsaved = False

    def __init__(self, gaussians: Gaussians, source: str = "") -> None:
        super().__init__(source, "")
        gaussians.check(source or "Gaussians")  # the GL renderer would draw NaN as nothing, or everything
        self._gaussians = gaussians.detach().to("cpu")
        self._owner_ids: list[int] | None = None

    @property
    def cameras(self) -> list[Camera]:
        return []

    @property
    def warnings(self) -> list[str]:
        return []

    def gaussians(self) -> Gaussians:
        return self._gaussians

    def num_owners(self) -> int:
        """Max owner + 1 (0 without owners)."""
        return int(self._gaussians.owner.max()) + 1 if self._gaussians.num else 0

    def owner_ids(self) -> list[int]:
        """The distinct owners >= 0, ascending."""
        if self._owner_ids is None:
            self._owner_ids = [int(o) for o in torch.unique(self._gaussians.owner) if int(o) >= 0]
        return self._owner_ids

    def objects(self) -> torch.Tensor:
        """(num_owners,) each owner its own object."""
        return torch.arange(self.num_owners())

    def take_changes(self) -> set[int] | None:
        return set()  # a fixed set: nothing ever changes

    def particle_gaussians(self, index: int) -> Gaussians:
        return self._gaussians.subset(self._gaussians.owner == index)

    def edit_chunk(self) -> str | dict:
        return {}

    def inputs(self) -> list[tuple[str, str]]:
        """The Gaussian file (``--ply``)."""
        return [("--ply", self.source)]

    def autosave(self, folder: str | PathLike) -> Path | None:
        return None


class EditableScene(SceneFiles):
    """A model's scene under edit.

    Args:
        model: the ParticleSplat model that encoded the scene.
        encoded: the encoded scene (particles + cameras).
        model_name: how the model is named in screenshots and edits files.
        source: the scene folder.
        checkpoint: the checkpoint the model was loaded from (an input no output may replace).

    Attributes:
        editor: the scene's :class:`SceneEditor` (every edit goes through it).
    """

    def __init__(
        self, model: ParticleSplat, encoded: EncodedScene, model_name: str = "", source: str = "", checkpoint: str = ""
    ) -> None:
        super().__init__(source, model_name)
        self.checkpoint = checkpoint  # the model's file ("" when it was built in memory)
        self.editor = SceneEditor(model, encoded.particles, encoded.all_cameras, encoded.context, world=encoded.support)
        self.encoded = encoded
        self._workspace: CropBox | None = None
        self._workspace_read = False
        self._saved_token = self._history_token()

    # ------------------------------------------------------------------ what is drawn
    @property
    def model(self) -> ParticleSplat:
        return self.editor.model

    @property
    def cameras(self) -> list[Camera]:
        return list(self.encoded.all_cameras)

    @property
    def version(self) -> int:
        return self.editor.version

    @property
    def context(self) -> list[int] | None:
        return self.editor.context

    @property
    def warnings(self) -> list[str]:
        return list(self.encoded.warnings)

    def num_owners(self) -> int:
        """P for owner maps: the particles."""
        return self.editor.num_particles

    def owner_ids(self) -> list[int]:
        """Every particle."""
        return list(range(self.editor.num_particles))

    def gaussians(self) -> Gaussians:
        """All Gaussians of the current state (particles with edits, plus background) inside the crop box the edits
        set (:meth:`SceneEditor.crop_box`): what the view draws and picks, screenshots show and the viewer exports."""
        return self._cropped(self.editor.decode())

    def _cropped(self, g: Gaussians) -> Gaussians:
        """``g`` without the Gaussians outside the edits' crop box (all of it without one)."""
        box = self.editor.crop_box
        return g if box is None else box.crop(g)

    @property
    def workspace(self) -> CropBox | None:
        """The box about a robot scene's table and arm (:func:`particlesplat.editing.crop_box.workspace_box`, what
        ``particlesplat export`` crops to when the edits set no box), read once; None for a tabletop scene or one
        opened from no folder."""
        if not self._workspace_read:
            self._workspace_read = True
            self._workspace = workspace_box(self.source) if self.source and Path(self.source).is_dir() else None
        return self._workspace

    def objects(self) -> torch.Tensor:
        """(num_particles,) int64 object label per particle (:meth:`SceneEditor.objects`)."""
        return self.editor.objects()

    def take_changes(self) -> set[int] | None:
        return self.editor.take_changes()

    def particle_gaussians(self, index: int) -> Gaussians:
        """The Gaussians of one particle (owner = index), decoded alone (none if it is inactive), or of the
        background (index -1, which :meth:`take_changes` reports when an edit uncovered the table under an object),
        inside the crop box as :meth:`gaussians` keeps them."""
        ed = self.editor
        if index == BACKGROUND_OWNER:
            return self._cropped(ed.background())
        g = ed.model.decode(ed.scene.particles, torch.tensor([index]), background=False).detach().to("cpu")
        return self._cropped(g)

    # ------------------------------------------------------------------ files
    def inputs(self) -> list[tuple[str, str]]:
        """The scene folder (``--scene``) and the checkpoint (``--checkpoint``)."""
        return [("--scene", self.source), ("--checkpoint", self.checkpoint)]

    def _history_token(self) -> tuple:
        undo = self.editor.history.undo
        return len(undo), id(undo[-1]) if undo else None

    @property
    def unsaved(self) -> bool:
        """Edits done since the scene was opened, its edits saved or an edit file loaded."""
        return self._history_token() != self._saved_token

    def _save(self, path: str | PathLike) -> Path:
        return self.editor.save(
            path, scene=self.scene_path or None, model=self.model_name or None, scene_sha256=self.scene_sha256
        )

    def edit_chunk(self) -> str | dict:
        return self.editor.edit_text(
            scene=self.scene_path or None, model=self.model_name or None, scene_sha256=self.scene_sha256
        )

    def autosave(self, folder: str | PathLike) -> Path | None:
        """Keep unsaved edits (before the scene is replaced or the window closes); returns the file, or None when
        nothing was unsaved. The scene stays unsaved: the user did not save them."""
        if not self.unsaved:
            return None
        path = self.autosave_path(folder)
        self.guard_output("autosave", path)  # the state folder could lie in a scene folder or a live run
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
        Returns a warning when the file names another scene or other context frames, or leaves an object below its
        support, else None."""
        file = load_edit_file(path)
        self.editor.end_gesture()
        if file.version == 2:
            self.editor.apply_file(file, str(path))
        else:
            self.editor.set_edits(file.particles, label=f"load {Path(path).name}")
        self._saved_token = self._history_token()
        notes = [scene_mismatch(file, self.source, self.editor.context) if self.source else None]
        return "; ".join(n for n in notes + self.editor.sunk_objects() if n) or None
