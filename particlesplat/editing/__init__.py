"""Object edits: grouping particles into objects, moves, named do/undo operations, edit files, insert/export.

``demo_scenes()`` lists the scene folders shipped with the package (wherever it is installed)."""

from particlesplat.core.lazy import lazy_exports

_EXPORTS = {"demo_scenes": ".open_scene", "encode_scene": ".open_scene", "SceneEditor": ".editor"}
__all__ = ["SceneEditor", "demo_scenes", "encode_scene"]

__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
