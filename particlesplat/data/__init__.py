"""Scene data: the scene-folder loader, the split dataset, the view sampler and the tabletop generator.

Names are imported on first use (PEP 562), so importing one submodule does not load the others.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

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


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        value = getattr(importlib.import_module(_EXPORTS[name], __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *_EXPORTS])


if TYPE_CHECKING:
    from .dataset import SceneDataset
    from .scene import RawScene, Scene, SceneFormatError, load_scene, read_scene
    from .views import flip_horizontal, gap_range, sample_views, supervision_mask
