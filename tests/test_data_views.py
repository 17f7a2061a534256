"""View sampler, monocular supervision mask and SceneDataset tests."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from torch.utils.data import DataLoader

from particlesplat.core.bundled import bundled_assets
from particlesplat.data import SceneDataset, load_scene, sample_views, supervision_mask
from particlesplat.data.families.tabletop import TabletopObject, TabletopScene, trace

SCENES = bundled_assets() / "scenes"


def _draws(progress: float, mode: str, n: int = 1500) -> list[tuple[torch.Tensor, torch.Tensor]]:
    gen = torch.Generator().manual_seed(1)
    return [sample_views(21, progress, mode, gen) for _ in range(n)]


# the paper's appendix: multi-view gap [1, 4] -> [5, 20], single-view [1, 2] -> [5, 10], max at half time
@pytest.mark.parametrize(
    "progress, gaps", [(0.0, (1, 4)), (0.25, (3, 12)), (0.5, (5, 20)), (0.8, (5, 20)), (1.0, (5, 20))]
)
def test_multi_view_gaps(progress, gaps):
    seen = set()
    for ctx, tgt in _draws(progress, "multi"):
        assert ctx.dtype == torch.int64 and ctx.shape == (2,) and tgt.shape == (4,)
        left, right = ctx.tolist()
        seen.add(right - left)
        assert 0 <= left < right <= 20
        assert ((tgt >= left) & (tgt <= right)).all()
        if right - left >= 3:
            assert len(set(tgt.tolist())) == 4
    assert seen == set(range(gaps[0], gaps[1] + 1))


@pytest.mark.parametrize("progress, gaps", [(0.0, (1, 2)), (0.5, (5, 10)), (1.0, (5, 10))])
def test_single_view_gaps(progress, gaps):
    seen = set()
    for ctx, tgt in _draws(progress, "single"):
        assert ctx.tolist() == [10] and tgt.shape == (2,) and tgt[0] != tgt[1]
        offsets = (tgt - 10).abs().tolist()
        assert all(gaps[0] <= g <= gaps[1] for g in offsets)
        seen.update((tgt - 10).tolist())
    assert seen == {s * g for s in (-1, 1) for g in range(gaps[0], gaps[1] + 1)}


def test_sampler_is_seeded_and_clips_short_trajectories():
    a = sample_views(21, 0.3, "multi", torch.Generator().manual_seed(5))
    b = sample_views(21, 0.3, "multi", torch.Generator().manual_seed(5))
    assert all(torch.equal(x, y) for x, y in zip(a, b, strict=False))
    ctx, tgt = sample_views(3, 1.0, "multi", torch.Generator().manual_seed(0))
    assert ctx.tolist() == [0, 2] and len(tgt) == 4
    with pytest.raises(ValueError, match="mode"):
        sample_views(21, 0.0, "both")


# ---------------------------------------------------------------------------- supervision mask
def _analytic_visibility(folder: Path, scene, t: int, c: int) -> np.ndarray:
    """(H, W) bool: is target pixel t's surface point seen by context camera c? Ray-cast from the context
    camera with the scene's analytic description (not from depth maps)."""
    meta = json.loads((folder / "scene.json").read_text())
    tab = TabletopScene(
        [TabletopObject(**{**o, "center": tuple(o["center"]), "size": tuple(o["size"])}) for o in meta["objects"]],
        meta["elevation_deg"],
        meta["distance"],
    )
    ct, cc = scene.cameras[t].to(dtype=torch.float64), scene.cameras[c].to(dtype=torch.float64)
    d = scene.depth[t, 0].double()
    _, dirs = ct.rays()
    far = d == 0
    points = ct.center + dirs * torch.where(far, torch.full_like(d, 1e4), d)[..., None]
    uv, z = cc.project(points)
    inside = (z > 0) & (uv[..., 0] >= 0) & (uv[..., 0] < cc.width) & (uv[..., 1] >= 0) & (uv[..., 1] < cc.height)
    ray = ((points - cc.center) / z.clamp_min(1e-9)[..., None]).reshape(-1, 3).numpy()
    _, hit_depth, _ = trace(tab, cc.center.numpy(), ray, shade=False)
    hit_depth = hit_depth.reshape(d.shape)
    zn = z.numpy()
    visible = np.where(far.numpy(), hit_depth == 0, (hit_depth == 0) | (hit_depth > zn - 1e-3 * zn))
    return inside.numpy() & visible


@pytest.mark.parametrize("target", [6, 14, 0])
def test_supervision_mask_matches_analytic_visibility(target):
    folder = SCENES / "scene_00001"
    scene = load_scene(folder)
    mask = supervision_mask(scene.depth[[target]], [scene.cameras[target]], scene.depth[[10]], [scene.cameras[10]])
    assert mask.shape == (1, 1, 128, 128) and mask.dtype == torch.float32
    truth = _analytic_visibility(folder, scene, target, 10)
    got = mask[0, 0].numpy() > 0.5
    assert 0.05 < truth.mean() < 0.98  # both visible and hidden pixels exist
    assert (got == truth).mean() > 0.97, (target, (got == truth).mean())


def test_supervision_mask_of_the_context_itself_is_full():
    scene = load_scene(SCENES / "scene_00000", 64)
    mask = supervision_mask(scene.depth[[10]], [scene.cameras[10]], scene.depth[[10]], [scene.cameras[10]])
    assert float(mask.mean()) == 1.0


# ---------------------------------------------------------------------------- dataset
def test_dataset_items_multi_and_single():
    ds = SceneDataset(SCENES, resolution=64, mode="multi")
    item = ds[0]
    shapes = {k: tuple(v.shape) for k, v in item.items()}
    assert shapes["context_rgb"] == (2, 3, 64, 64) and shapes["target_rgb"] == (4, 3, 64, 64)
    assert shapes["context_depth"] == (2, 1, 64, 64) and shapes["target_masks"] == (4, 64, 64)
    assert shapes["context_K"] == (2, 3, 3) and shapes["target_c2w"] == (4, 4, 4)
    assert float(item["target_supervision"].min()) == 1.0  # multi-view: everything supervised
    assert float(item["context_K"][0, 0, 0]) == pytest.approx(0.5 * 175.8386, rel=1e-4)
    scene = load_scene(SCENES / "scene_00000", 64)
    assert torch.equal(item["target_rgb"], scene.rgb[item["target_index"]])
    single = SceneDataset(SCENES, resolution=64, mode="single")[1]
    assert single["context_index"].tolist() == [10] and single["target_rgb"].shape == (2, 3, 64, 64)
    sup = single["target_supervision"]
    assert 0.0 < float(sup.mean()) < 1.0


def test_dataset_deterministic_and_flip():
    plain = SceneDataset(SCENES, mode="multi", deterministic=True, seed=3, progress=1.0)
    flips = SceneDataset(SCENES, mode="multi", deterministic=True, seed=3, progress=1.0, flip=True)
    flipped_any = False
    for i in range(len(plain)):
        a, b, again = plain[i], flips[i], flips[i]
        assert all(torch.equal(b[k], again[k]) for k in b)
        assert torch.equal(a["target_index"], b["target_index"])
        if bool(b["flipped"]):
            flipped_any = True
            assert torch.equal(b["context_rgb"], a["context_rgb"].flip(-1))
            assert torch.equal(b["target_masks"], a["target_masks"].flip(-1))
            assert float(b["context_K"][0, 0, 2]) == pytest.approx(128 - float(a["context_K"][0, 0, 2]))
        else:
            assert torch.equal(b["context_rgb"], a["context_rgb"])
    assert flipped_any


def test_progress_reaches_dataloader_workers():
    ds = SceneDataset(SCENES, resolution=32, mode="multi")
    loader = DataLoader(ds, batch_size=3, num_workers=1, persistent_workers=True)
    gaps = [int(b["context_index"][:, 1].sub(b["context_index"][:, 0]).max()) for b in loader]
    assert max(gaps) <= 4
    ds.set_progress(1.0)
    gaps = [int(b["context_index"][:, 1].sub(b["context_index"][:, 0]).min()) for _ in range(3) for b in loader]
    assert min(gaps) >= 5
