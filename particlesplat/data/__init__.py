"""Scene data: the scene-folder loader, the split dataset, the view sampler and the tabletop generator."""

from .dataset import SceneDataset
from .scene import RawScene, Scene, SceneFormatError, load_scene, read_scene
from .views import flip_horizontal, gap_range, sample_views, supervision_mask

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
