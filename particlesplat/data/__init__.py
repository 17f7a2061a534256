"""Scene data: the scene-folder loader, the split dataset, the view sampler and the tabletop generator.

Names are imported on first use (PEP 562), so importing one submodule does not load the others.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from particlesplat.core.lazy import lazy_exports

_EXPORTS = {
    "RawScene": ".scene",
    "Scene": ".scene",
    "SceneDataset": ".dataset",
    "SceneFormatError": ".scene",
    "flip_horizontal": ".views",
    "gap_range": ".views",
    "load_scene": ".scene",
    "read_scene": ".scene",
    "sample_views": ".views",
    "supervision_mask": ".views",
}
__all__ = [
    "RawScene",
    "Scene",
    "SceneDataset",
    "SceneFormatError",
    "flip_horizontal",
    "gap_range",
    "load_scene",
    "read_scene",
    "sample_views",
    "supervision_mask",
]


__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)


if TYPE_CHECKING:
    from particlesplat.data.dataset import SceneDataset
    from particlesplat.data.scene import RawScene, Scene, SceneFormatError, load_scene, read_scene
    from particlesplat.data.views import flip_horizontal, gap_range, sample_views, supervision_mask
