"""A torch ``Dataset`` over a split folder of scene folders, with the paper's view sampler."""

from __future__ import annotations

import dataclasses
import multiprocessing as mp
from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass, fields
from os import PathLike
from pathlib import Path

import torch
from torch import Tensor
from torch.utils.data import Dataset

from particlesplat.core.errors import one_line
from particlesplat.core.limits import memory_limit
from particlesplat.data.folders import TRANSFORMS
from particlesplat.data.scene import RawScene, SceneFormatError, read_scene
from particlesplat.data.scene_meta import SCENE_META, read_pose
from particlesplat.data.views import flip_horizontal, protocol_views, sample_views, supervision_mask

# the share of the job's memory limit a dataset's scene cache may hold (training keeps one dataset per context-view
# count: the trainer divides it among them); the rest is the model's, the batch's and the renderer's
CACHE_SHARE = 0.25


@dataclass(frozen=True)
class TrainingBatch:
    """B scenes' views for one training step: :class:`SceneDataset` items stacked (``collate``), without the
    masks and indices the loss does not read. C context views, T target views, H x W the resolution:

    - ``context_rgb`` (B, C, 3, H, W), ``target_rgb`` (B, T, 3, H, W): float32 in [0, 1].
    - ``context_depth`` (B, C, 1, H, W), ``target_depth`` (B, T, 1, H, W): planar metres, 0 = none.
    - ``context_K`` (B, C, 3, 3), ``target_K`` (B, T, 3, 3): intrinsics in pixels at H x W.
    - ``context_c2w`` (B, C, 4, 4), ``target_c2w`` (B, T, 4, 4): OpenCV camera-to-world.
    - ``target_supervision`` (B, T, 1, H, W): float32 {0, 1}; 1 where the target pixel is supervised.
    - ``pose`` (B, D): each scene's pose (``model.background.static_pose``), or None where the dataset reads none.
    """

    context_rgb: Tensor
    context_depth: Tensor
    context_K: Tensor
    context_c2w: Tensor
    target_rgb: Tensor
    target_depth: Tensor
    target_K: Tensor
    target_c2w: Tensor
    target_supervision: Tensor
    pose: Tensor | None = None

    @classmethod
    def collate(cls, items: Sequence[dict[str, Tensor]]) -> TrainingBatch:
        """Stack the fields of ``items`` (:class:`SceneDataset` items of one view count) along a new batch axis."""
        return cls(**{f.name: torch.stack([item[f.name] for item in items]) for f in fields(cls) if f.name in items[0]})

    def to(self, device: torch.device | str) -> TrainingBatch:
        return dataclasses.replace(
            self, **{f.name: t.to(device) for f in fields(self) if (t := getattr(self, f.name)) is not None}
        )


class SceneDataset(Dataset):
    """Scenes of one split (every sub-folder holding a ``transforms.json``, sorted by name).

    Each item is one scene with views chosen by :func:`sample_views` at the current training
    progress (:meth:`set_progress`; shared with DataLoader worker processes). An item is a dict
    (C context views, T target views, H x W the resolution):

    - ``context_rgb`` (C, 3, H, W), ``target_rgb`` (T, 3, H, W): float32 in [0, 1].
    - ``context_depth`` (C, 1, H, W), ``target_depth`` (T, 1, H, W): planar metres, 0 = none
      (all zeros for scenes without depth).
    - ``context_K`` (C, 3, 3), ``target_K`` (T, 3, 3): intrinsics in pixels at H x W.
    - ``context_c2w`` (C, 4, 4), ``target_c2w`` (T, 4, 4): OpenCV camera-to-world.
    - ``context_masks`` (C, H, W), ``target_masks`` (T, H, W): int64 instance ids (0 = background);
      only when the scenes have masks.
    - ``target_supervision`` (T, 1, H, W): float32 {0, 1}; 1 where the target pixel is supervised.
      Single-view mode with depth: the Splatt3R-style mask (:func:`supervision_mask`); otherwise ones.
    - ``context_index`` (C,), ``target_index`` (T,): int64 frame indices; ``scene_index`` () int64;
      ``flipped`` () bool.
    - ``pose`` (D,) float32: the pose ``scene.json`` records under ``pose_key`` (with ``pose_key`` only).

    With ``deterministic=True`` (validation/test), item ``i`` always picks the same views and flip,
    from a generator seeded by ``(seed, i)``; otherwise each call draws fresh views from torch's
    global RNG (per-worker seeded by the DataLoader).
    """

    def __init__(
        self,
        root_split_dir: str | PathLike,
        resolution: int | tuple[int, int] | None = None,
        mode: str = "multi",
        *,
        flip: bool = False,
        deterministic: bool = False,
        seed: int = 0,
        progress: float = 0.0,
        num_targets: int | None = None,
        schedule: tuple[tuple[int, int], tuple[int, int]] | None = None,
        cache_size: int = 256,
        cache_bytes: int | None = None,
        pose_key: str = "",
        pose_dims: int = 0,
        protocol: str = "sampled",
    ) -> None:
        """
        Args:
            root_split_dir: folder of scene folders (e.g. ``data/tabletop/train``).
            resolution: None (native), int S (S x S) or (W, H).
            mode: "multi" or "single" (see :func:`sample_views`).
            flip: mirror the world and flip all views of an item left-right with probability 1/2.
            deterministic: fixed views per item (validation order).
            seed: seed of the deterministic choices.
            progress: initial training progress in [0, 1] (drives the view-gap schedule); for
                validation use ``deterministic=True, progress=1.0`` (the full gap range).
            num_targets, schedule: passed to :func:`sample_views`.
            cache_size: decoded scenes kept per process (about 2.8 MB each at 21 x 128 x 128).
            cache_bytes: and at most this many bytes of them (least recently used evicted first); None =
                :data:`CACHE_SHARE` of the job's memory limit (:func:`particlesplat.core.limits.memory_limit`), so
                that a dataset of large images is read again rather than held past the limit.
            pose_key, pose_dims: each item's ``pose``, the ``pose_dims`` numbers its ``scene.json`` records under
                ``pose_key`` (``model.background.static_pose``); every scene must record it ("": none read).
            protocol: the evaluation protocol (:func:`particlesplat.data.views.protocol_views`) that replaces the
                sampled views: "sampled" (the sampler's), "paper" (fixed frames; a scene with fewer than 15 frames
                is a :class:`SceneFormatError`) or "inputs" (the context views are the targets).
        """
        root = Path(root_split_dir)
        if not root.is_dir():
            raise FileNotFoundError(f"{root}: no such split folder")
        # hidden folders are the generator's unfinished temporaries
        self.scenes = sorted(p for p in root.iterdir() if not p.name.startswith(".") and (p / TRANSFORMS).is_file())
        if not self.scenes:
            raise FileNotFoundError(f"{root}: no scene folders (sub-folders with {TRANSFORMS})")
        if mode not in ("multi", "single"):
            raise ValueError(f"mode must be 'multi' or 'single', got {mode!r}")
        self.root = root
        self.resolution = resolution
        self.mode = mode
        self.flip = flip
        self.deterministic = deterministic
        self.seed = seed
        self.num_targets = num_targets
        self.schedule = schedule
        self.cache_size = cache_size
        self.cache_bytes = int(memory_limit()[0] * CACHE_SHARE) if cache_bytes is None else cache_bytes
        self._cached_bytes = 0
        self.pose_key, self.pose_dims = pose_key, pose_dims
        self.protocol = protocol
        self._progress = mp.get_context().Value("d", float(progress), lock=False)
        self._cache: OrderedDict[int, RawScene] = OrderedDict()

    def __len__(self) -> int:
        return len(self.scenes)

    @property
    def progress(self) -> float:
        return float(self._progress.value)

    def set_progress(self, progress: float) -> None:
        """Set the training progress in [0, 1]; worker processes see it (shared memory)."""
        self._progress.value = min(max(float(progress), 0.0), 1.0)

    def raw(self, index: int) -> RawScene:
        """The decoded scene ``index`` (cached, least recently used evicted)."""
        if index in self._cache:
            self._cache.move_to_end(index)
            return self._cache[index]
        raw = read_scene(self.scenes[index])
        size = raw.nbytes
        if self.cache_size > 0 and size <= self.cache_bytes:
            self._cache[index] = raw
            self._cached_bytes += size
            while len(self._cache) > self.cache_size or self._cached_bytes > self.cache_bytes:
                self._cached_bytes -= self._cache.popitem(last=False)[1].nbytes
        return raw

    def pose(self, index: int) -> list[float]:
        """The pose scene ``index`` records (``pose_key``); SceneFormatError names its scene.json when it has none."""
        pose = read_pose(self.scenes[index], self.pose_key, self.pose_dims)
        if pose is None:
            raise SceneFormatError(
                f"{self.scenes[index] / SCENE_META}: no key {self.pose_key!r} (the model's background.static_pose: "
                f"{self.pose_dims} numbers a scene)"
            )
        return pose

    def __getitem__(self, index: int) -> dict[str, Tensor]:
        if not 0 <= index < len(self):
            raise IndexError(f"index {index} out of range for {len(self)} scenes")
        raw = self.raw(index)
        gen = torch.Generator()
        if self.deterministic:
            gen.manual_seed(self.seed * 1_000_003 + index)
        else:
            gen.manual_seed(int(torch.randint(0, 2**62, (1,))))
        try:
            ctx, tgt = sample_views(
                raw.num_frames, self.progress, self.mode, gen, num_targets=self.num_targets, schedule=self.schedule
            )
            ctx, tgt = protocol_views(self.protocol, raw.num_frames, ctx, tgt)
        except ValueError as e:  # too few frames for the sampling: name the scene
            raise SceneFormatError(f"{self.scenes[index] / TRANSFORMS}: frames: {one_line(e, 200)}") from None
        flipped = self.flip and bool(torch.rand((), generator=gen) < 0.5)
        item: dict[str, Tensor] = {
            "scene_index": torch.tensor(index),
            "flipped": torch.tensor(flipped),
            "context_index": ctx,
            "target_index": tgt,
        }
        if self.pose_key:
            item["pose"] = torch.tensor(self.pose(index))
        views = {}
        for role, idx in (("context", ctx), ("target", tgt)):
            scene = raw.select(idx.tolist(), self.resolution)
            depth = scene.depth if scene.depth is not None else torch.zeros_like(scene.rgb[:, :1])
            views[role] = (scene, depth)
        sup = torch.ones_like(views["target"][1])
        if self.mode == "single" and raw.has_depth:
            sup = supervision_mask(
                views["target"][1], views["target"][0].cameras, views["context"][1], views["context"][0].cameras
            )
        for role, (scene, depth) in views.items():
            extra = [depth] + ([scene.masks] if scene.masks is not None else [])
            if role == "target":
                extra.append(sup)
            rgb, cams = scene.rgb, scene.cameras
            if flipped:
                rgb, cams, extra = flip_horizontal(rgb, cams, *extra)
            item[f"{role}_rgb"] = rgb
            item[f"{role}_depth"] = extra[0]
            item[f"{role}_K"] = torch.stack([c.K for c in cams])
            item[f"{role}_c2w"] = torch.stack([c.c2w for c in cams])
            if scene.masks is not None:
                item[f"{role}_masks"] = extra[1]
            if role == "target":
                item["target_supervision"] = extra[-1]
        return item
