"""A model scene with its edit file replayed: what ``particlesplat render`` and ``particlesplat export`` draw.

The edit file comes from ``--edits E.yaml`` or from the ``edits`` chunk of a PNG (``--edits-from SHOT.png``: a
viewer screenshot or a rendered image); without ``--scene`` / ``--context`` the scene and the context frames it
names are used, so a screenshot's PNG alone reproduces what it shows.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from particlesplat.core.errors import OptionError
from particlesplat.core.gaussians import Gaussians
from particlesplat.editing.crop_box import CropBox
from particlesplat.editing.open_scene import EncodedScene, load_model_scene
from particlesplat.editing.scene_objects import SceneObjects
from particlesplat.model import Particles, ParticleSplat


@dataclass
class EditedScene:
    """A model scene after its edits.

    Attributes:
        model: the model that encoded (and decodes) it.
        encoded: the encoded scene (the particles before the edits, cameras, context frames, folder).
        particles: the particles after the edits.
        edits: the edit file as replayed (its YAML text, for a PNG's ``edits`` chunk), or {} without one.
        model_name: the checkpoint's name for metadata.
        warnings: what the user should know (the scene's own warnings, an edit file made on another scene, an
            object it left below its support).
        objects: the particles' objects as the edits left them (merges and splits win over the grouping), or
            None without edits (then grouped as encoded).
        crop: the crop box the edits set (None: none), applied by :meth:`gaussians`.
    """

    model: ParticleSplat
    encoded: EncodedScene
    particles: Particles
    edits: str | dict
    model_name: str
    warnings: list[str] = field(default_factory=list)
    objects: SceneObjects | None = None
    crop: CropBox | None = None

    def gaussians(self) -> Gaussians:
        """What the scene draws: its particles' Gaussians and the background's, on the CPU, those outside the
        crop box left out."""
        g = self.model.decode(self.particles).detach().to("cpu")
        return g if self.crop is None else self.crop.crop(g)


def open_edited_scene(
    checkpoint: str | None,
    scene: str | None,
    context: str | None,
    edits: str | None = None,
    edits_from: str | None = None,
) -> EditedScene:
    """Load the model, encode ``scene`` (None = the edit file's scene, else the first demo scene) from ``context``
    (None = the edit file's frames, else the default) and replay the edit file of ``edits`` (a YAML path) or
    ``edits_from`` (a PNG's ``edits`` chunk). OptionError when both are given."""
    from particlesplat.editing.editor import SceneEditor, load_edit_file, scene_mismatch

    file, where = None, "edits"  # where: the edit file's name in messages
    if edits_from:
        if edits:
            raise OptionError("--edits and --edits-from: give one edit file")
        from particlesplat.core.yamlsafe import load_yaml
        from particlesplat.editing.editor import parse_edit_file
        from particlesplat.formats.png import edits_text_from_png

        where = f"{edits_from}: edits chunk"
        file = parse_edit_file(load_yaml(edits_text_from_png(edits_from), where), where)
    elif edits:  # version 1 (particle values) or 2 (object operations, replayed as the viewer did them)
        file, where = load_edit_file(edits), str(edits)
    if file is not None and scene is None and file.scene is not None and Path(file.scene).is_dir():
        scene = file.scene  # the scene the edits were made on
        if context is None and file.context is not None:
            context = ",".join(str(int(c)) for c in file.context)
    model, enc, name = load_model_scene(checkpoint, scene, context)
    warnings = list(enc.warnings)
    particles, objects, crop = enc.particles, None, None
    text: str | dict = {}  # for png_text: the edit file's text, {} (no edits) without one
    if file is not None:
        mismatch = scene_mismatch(file, enc.path, enc.context)
        if mismatch:
            warnings.append(f"{where}: {mismatch}")
        from particlesplat.editing.scene_id import resolved, scene_digest

        editor = SceneEditor(model, particles, enc.all_cameras, enc.context, world=enc.support)
        editor.apply_file(file, where)
        warnings += [f"{where}: {line}" for line in editor.sunk_objects()]  # allowed, but never silently
        particles, objects, crop = editor.particles, SceneObjects(editor.objects()), editor.crop_box
        text = editor.edit_text(scene=resolved(enc.path), model=name, scene_sha256=scene_digest(enc.path))
    return EditedScene(model, enc, particles, text, name, warnings, objects, crop)
