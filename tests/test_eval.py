"""Metric tests against brute-force and analytic truth, and the eval CLI on a tiny dataset."""

from __future__ import annotations

import itertools
import json
import math

import numpy as np
import torch
from model_data import TINY_MODEL, tiny_dataset
from PIL import Image

from particlesplat.analysis.evaluate import FIGURE_LABEL_WIDTH
from particlesplat.analysis.metrics import (
    FAR_HEIGHTS,
    OVERLAYS,
    REGIONS,
    adjusted_rand_index,
    depth_abs_rel,
    fg_ari,
    mask_regions,
    matched_miou,
    psnr,
    region_errors,
    ssim,
    summarise_region_errors,
)
from particlesplat.cli.main import main
from particlesplat.model import ModelConfig, ParticleSplat, save_checkpoint


def ari_brute_force(a: list[int], b: list[int]) -> float:
    """ARI from pair counts over all point pairs (independent of the contingency-table formula)."""
    n = len(a)
    pairs = list(itertools.combinations(range(n), 2))
    same_a = [a[i] == a[j] for i, j in pairs]
    same_b = [b[i] == b[j] for i, j in pairs]
    n11 = sum(x and y for x, y in zip(same_a, same_b, strict=False))
    na, nb, m = sum(same_a), sum(same_b), len(pairs)
    expected = na * nb / m
    return (n11 - expected) / (0.5 * (na + nb) - expected)


def test_ari_matches_pair_counting():
    gen = torch.Generator().manual_seed(0)
    for _ in range(5):
        a = torch.randint(0, 3, (40,), generator=gen)
        b = torch.randint(-1, 4, (40,), generator=gen)
        assert math.isclose(adjusted_rand_index(a, b), ari_brute_force(a.tolist(), b.tolist()), rel_tol=1e-9)


def test_ari_is_one_for_relabelled_partitions_and_fg_ari_ignores_background():
    gt = torch.tensor([[0, 1, 1], [2, 2, 0]])
    pred = torch.tensor([[5, 7, 7], [-1, -1, 5]])  # background pixels are predicted anything
    assert fg_ari(pred, gt) == 1.0
    assert adjusted_rand_index(torch.tensor([1, 1, 2, 2]), torch.tensor([3, 4, 3, 4])) < 0
    assert math.isnan(fg_ari(pred, torch.zeros_like(gt)))


def test_matched_miou():
    gt = torch.tensor([[1, 1, 0, 2], [1, 1, 0, 2]])
    pred = torch.tensor([[3, 3, 3, 4], [3, 3, -1, -1]])
    # object 1: IoU(3) = 4/5; object 2: IoU(4) = 1/2
    assert math.isclose(matched_miou(pred, gt), (0.8 + 0.5) / 2)
    # one-to-one: a single segment covering both objects matches only one of them
    assert math.isclose(matched_miou(torch.full_like(gt, 0), gt), (4 / 8 + 0.0) / 2)


def test_image_and_depth_metrics_analytic():
    a = torch.zeros(1, 3, 8, 8)
    b = torch.full((1, 3, 8, 8), 0.1)
    assert math.isclose(psnr(a, b), 20.0, rel_tol=1e-5)
    assert math.isclose(ssim(b, b), 1.0, rel_tol=1e-5)
    gt = torch.tensor([2.0, 4.0, 0.0])
    assert math.isclose(depth_abs_rel(torch.tensor([3.0, 4.0, 9.0]), gt), 0.25)


def test_eval_cli_writes_json_figures_and_pruning_table(tmp_path_factory, tmp_path):
    data = tiny_dataset(tmp_path_factory)
    torch.manual_seed(0)
    ckpt = tmp_path / "m.pt"
    save_checkpoint(ckpt, ParticleSplat(ModelConfig(**TINY_MODEL)), step=0)
    out = tmp_path / "eval.json"
    assert (
        main(
            [
                "eval",
                "--checkpoint",
                str(ckpt),
                "--data",
                str(data / "val"),
                "--json",
                str(out),
                "--figures",
                str(tmp_path / "fig"),
                "--prune",
            ]
        )
        == 0
    )
    res = json.loads(out.read_text())
    assert set(res["mean"]) >= {
        "psnr",
        "ssim",
        "depth_abs_rel",
        "fg_ari",
        "miou",
        "fg_ari_particles",
        "miou_particles",
        "objects",
    }
    assert res["mean"]["objects"] <= res["mean"]["active_particles"]
    assert len(res["scenes"]) == 1 and res["scenes"][0]["scene"] == "scene_00000"
    assert 0 < res["mean"]["psnr"] < 60 and -1 <= res["mean"]["fg_ari"] <= 1
    regions = res["error_regions"]
    # the scenes have depth: the far floor by height and what the context sees too
    assert list(regions) == list(REGIONS + FAR_HEIGHTS + OVERLAYS)
    for keys in (REGIONS, OVERLAYS[2:]):  # each a partition of the pixels
        assert math.isclose(sum(regions[k]["pixel_share"] for k in keys), 1.0)
        assert math.isclose(sum(regions[k]["error_share"] for k in keys), 1.0)
    drawn = sum(regions[k]["pixel_share"] for k in OVERLAYS[:2])
    assert 0 <= drawn <= 1 and regions["particles_on_objects"]["pixel_share"] <= 1 - regions["floor_far"]["pixel_share"]
    heights = sum(regions[k]["pixel_share"] for k in FAR_HEIGHTS)
    assert 0 < heights <= regions["floor_far"]["pixel_share"] + 1e-9
    rows = res["pruning"]
    base = rows[0]
    assert base["z_t_threshold"] == 0 and base["opacity_threshold"] == 0
    assert base["gaussians"] == res["mean"]["gaussians"]
    assert all(r["gaussians"] <= base["gaussians"] for r in rows)
    G = ModelConfig(**TINY_MODEL).gaussians_per_particle
    (half,) = [r for r in rows if r["max_per_particle"] == G // 2]
    # one scene: each of its drawn particles loses half its Gaussians, the background none
    assert half["gaussians"] == res["mean"]["gaussians"] - res["mean"]["active_particles"] * (G - G // 2)
    assert -1 <= half["fg_ari"] <= 1 and 0 < half["psnr"] < 60
    img = Image.open(tmp_path / "fig" / "scene_00000.png")
    assert img.size == (FIGURE_LABEL_WIDTH + 4 * 32, 5 * 32)  # a label column, 4 targets wide, 5 rows
    labels = np.asarray(img.convert("L"))[:, :FIGURE_LABEL_WIDTH]
    assert all((labels[r * 32 : (r + 1) * 32] > 128).any() for r in range(5))  # each row has its label
    assert main(["eval", "--checkpoint", str(ckpt), "--data", str(data / "val"), "--context", "1"]) == 0


def test_mask_regions_of_a_square_and_a_neighbour():
    """A 4x4 object in a 12x12 view: 4 interior and 12 edge pixels, 48 floor pixels within 2 px, 80 farther.
    A second object touching it makes the shared column edge on both sides."""
    m = torch.zeros(1, 12, 12, dtype=torch.long)
    m[0, 4:8, 4:8] = 3
    counts = {k: int(v.sum()) for k, v in mask_regions(m).items()}
    assert counts == {"object_interior": 4, "object_edge": 12, "floor_near_object": 48, "floor_far": 80}
    m[0, 4:8, 8:10] = 5
    r = mask_regions(m)
    assert not bool(r["object_interior"][0, 4:8, 7].any()) and bool(r["object_edge"][0, 4:8, 8].all())
    assert sum(int(v.sum()) for v in r.values()) == 144 and not bool(sum(v.int() for v in r.values()).gt(1).any())


def test_region_errors_sum_and_summary_analytic():
    """Error 0.1 on the square's edge, 0.01 on the far floor, 0 elsewhere: sums 12 * 0.01 and 80 * 1e-4,
    edge PSNR 20 dB, far floor 40 dB; the unsupervised half of the view drops out."""
    m = torch.zeros(1, 12, 12, dtype=torch.long)
    m[0, 4:8, 4:8] = 1
    gt = torch.full((1, 3, 12, 12), 0.5)
    r = mask_regions(m)
    pred = gt + 0.1 * r["object_edge"][:, None] + 0.01 * r["floor_far"][:, None]
    parts = region_errors(pred, gt, m)
    assert parts["object_edge"][1] == 12 and math.isclose(parts["object_edge"][0], 12 * 0.01, rel_tol=1e-5)
    assert math.isclose(parts["floor_far"][0], 80 * 1e-4, rel_tol=1e-4) and parts["object_interior"][0] == 0.0
    summary = summarise_region_errors([parts, parts])
    assert math.isclose(summary["object_edge"]["psnr"], 20.0, abs_tol=1e-3)
    assert math.isclose(summary["floor_far"]["psnr"], 40.0, abs_tol=1e-3)
    assert math.isclose(summary["object_edge"]["pixel_share"], 12 / 144)
    assert math.isclose(summary["object_edge"]["error_share"], 0.12 / (0.12 + 0.008), rel_tol=1e-4)
    valid = torch.ones(1, 1, 12, 12)
    valid[..., :, 6:] = 0
    assert region_errors(pred, gt, m, valid)["object_edge"][1] == 6


def test_far_background_split_by_height_over_the_support_surface():
    """An oblique camera over the plane z = 0: the depth where each pixel's ray meets the plane reprojects to
    height 0 (on the support); 0.8 and 1.25 of it to points above and below it; depth 0 to no band."""
    from particlesplat.analysis.evaluate import surface_heights
    from particlesplat.core.camera import Camera

    cam = Camera.look_at((0.3, -0.8, 0.9), (0.0, 0.0, 0.0), width=12, height=12, dtype=torch.float64)
    origins, dirs = cam.rays()
    t_plane = -origins[..., 2] / dirs[..., 2]  # planar depth of the plane z = 0 (a direction's camera z is 1)
    assert bool((t_plane > 0).all())
    scale = torch.ones(12, 12, dtype=torch.float64)
    scale[:, 4:8], scale[:, 8:] = 0.8, 1.25
    depth = (t_plane * scale)[None, None].float()
    depth[..., :2, :] = 0.0  # two rows without depth
    z = surface_heights([cam], depth)
    expected = (origins[..., 2] + t_plane * scale * dirs[..., 2]).float()
    assert torch.allclose(z[0, 2:], expected[2:], atol=1e-5) and bool(z[0, :2].isnan().all())
    assert float(z[0, 2:, :4].abs().max()) < 1e-5
    m = torch.zeros(1, 12, 12, dtype=torch.long)  # no object: every pixel is far background
    gt = torch.full((1, 3, 12, 12), 0.5)
    pred = gt + 0.1 * (scale > 1.0)[None, None]  # an error of 0.1 below the support only
    parts = region_errors(pred, gt, m, None, z)
    assert [parts[k][1] for k in FAR_HEIGHTS] == [40, 40, 40] and parts["floor_far"][1] == 144
    summary = summarise_region_errors([parts])
    below, on = summary["floor_far_below_support"], summary["floor_far_on_support"]
    assert math.isclose(below["pixel_share"], 40 / 144) and math.isclose(below["error_share"], 40 / 48, rel_tol=1e-5)
    assert math.isclose(below["psnr"], 20.0, abs_tol=1e-3) and on["psnr"] == 100.0
    assert set(summarise_region_errors([parts, region_errors(pred, gt, m)])) == set(REGIONS)  # pooled when all have it


def test_overlays_split_where_the_particles_draw_and_what_the_context_sees():
    """A 4x4 object in a 12x12 view; the particles draw (weight 0.8) over columns 2-7, rows 4-7: the object's 16
    pixels and 8 beside it, with an error of 0.1 there and none elsewhere; the context sees the left half.
    Off the objects: 8 pixels holding a third of the error; seen: 6 columns x 12 rows, of the drawn pixels the 16
    in columns 2-5, two thirds of the error. Weight 0.5 exactly is not drawn."""
    m = torch.zeros(1, 12, 12, dtype=torch.long)
    m[0, 4:8, 4:8] = 2
    weight = torch.zeros(1, 12, 12)
    weight[0, 4:8, 2:8] = 0.8
    weight[0, 0, :] = 0.5
    seen = torch.zeros(1, 12, 12, dtype=torch.bool)
    seen[..., :6] = True
    gt = torch.full((1, 3, 12, 12), 0.5)
    pred = gt + 0.1 * (weight > 0.6)[:, None]
    parts = region_errors(pred, gt, m, None, None, weight, seen)
    assert parts["particles_on_objects"][1] == 16 and parts["particles_off_objects"][1] == 8
    assert parts["seen_by_context"][1] == 72 and parts["unseen_by_context"][1] == 72
    summary = summarise_region_errors([parts])
    assert math.isclose(summary["particles_off_objects"]["error_share"], 1 / 3, rel_tol=1e-5)
    assert math.isclose(summary["seen_by_context"]["error_share"], 2 / 3, rel_tol=1e-5)
    assert math.isclose(summary["particles_on_objects"]["psnr"], 20.0, abs_tol=1e-3)
    assert math.isclose(summary["unseen_by_context"]["pixel_share"], 0.5)
    assert set(summarise_region_errors([parts, region_errors(pred, gt, m)])) == set(REGIONS)  # pooled when all have it
    assert set(summary) == set(REGIONS) | set(OVERLAYS)


def test_eval_psnr_is_the_mean_of_per_view_psnr():
    """Two views with MSE 1e-2 and 1e-4 score 20 and 40 dB: the mean is 30 dB, not the pooled 23.0 dB."""
    from particlesplat.analysis.evaluate import view_psnr

    gt = torch.full((2, 3, 4, 4), 0.5)
    pred = gt.clone()
    pred[0] += 0.1
    pred[1] += 0.01
    assert abs(view_psnr(pred, gt, None) - 30.0) < 1e-4
    sup = torch.ones(2, 1, 4, 4)
    sup[1, :, :2] = 0  # unsupervised pixels do not count, whatever their error
    pred[1, :, :2] = 1.0
    assert abs(view_psnr(pred, gt, sup) - 30.0) < 1e-4
