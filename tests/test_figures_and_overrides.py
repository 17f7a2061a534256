"""Figures a paper can use and quick training smoke tests: several modes and views of one encode (each image as a
call of its own renders it), depth with a colour bar in metres, and ``particlesplat train`` taking ``KEY=VALUE``
changes of the recipe, checked as the file's keys are."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from particlesplat.analysis.figures import BAR_GAP, BAR_WIDTH, depth_grey, depth_span, with_depth_bar
from particlesplat.cli.main import main
from particlesplat.cli.render import output_paths
from particlesplat.core.bundled import bundled_assets, recipe_path
from particlesplat.model.config import ConfigError, load_config, with_overrides


def test_output_paths_name_each_image():
    one = output_paths("a/x.png", ("rgb",), (4,))
    assert list(one.values())[0].as_posix() == "a/x.png"
    several = output_paths("a/x.png", ("rgb", "depth"), (4, 10))
    assert {k: v.as_posix() for k, v in several.items()} == {
        ("rgb", 4): "a/x_view4_rgb.png",
        ("depth", 4): "a/x_view4_depth.png",
        ("rgb", 10): "a/x_view10_rgb.png",
        ("depth", 10): "a/x_view10_depth.png",
    }
    assert output_paths("x.png", ("rgb", "objects"), None)[("objects", None)].as_posix() == "x_objects.png"


def test_several_modes_and_views_match_single_renders(tmp_path):
    scene = str(bundled_assets() / "scenes" / "scene_00000")
    size = ["--width", "40", "--height", "32"]
    assert (
        main(
            [
                "render",
                "--scene",
                scene,
                "--view",
                "4,10",
                "--mode",
                "rgb,depth",
                *size,
                "--out",
                str(tmp_path / "m.png"),
            ]
        )
        == 0
    )
    assert (
        main(["render", "--scene", scene, "--view", "10", "--mode", "depth", *size, "--out", str(tmp_path / "d.png")])
        == 0
    )
    assert main(["render", "--scene", scene, "--view", "4", *size, "--out", str(tmp_path / "r.png")]) == 0
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names == ["d.png", "m_view10_depth.png", "m_view10_rgb.png", "m_view4_depth.png", "m_view4_rgb.png", "r.png"]
    read = lambda n: np.asarray(Image.open(tmp_path / n), dtype=np.int16)  # noqa: E731
    assert np.abs(read("m_view4_rgb.png") - read("r.png")).max() <= 1
    assert np.abs(read("m_view10_depth.png") - read("d.png")).max() <= 1
    assert read("d.png").shape[1] > 40  # the depth image carries its colour bar
    assert not np.array_equal(read("m_view4_rgb.png"), read("m_view10_rgb.png"))


def test_depth_bar_maps_rows_to_metres():
    """Row r of the bar shows the grey of depth lo + (hi - lo) r / (H - 1): the depth image's grey of that depth."""
    H, W = 64, 30
    depth = np.linspace(2.0, 4.0, H)[:, None].repeat(W, 1)
    alpha = np.ones((H, W))
    span = depth_span(depth, alpha)
    assert span == pytest.approx((np.percentile(depth, 2), np.percentile(depth, 98)))
    image = np.repeat(depth_grey(depth, span)[..., None], 3, -1)
    out = with_depth_bar(image, span)
    assert out.shape[0] == H and out.shape[1] > W + BAR_GAP + BAR_WIDTH
    np.testing.assert_allclose(out[:, :W], np.round(image * 255) / 255, atol=1e-9)
    bar = out[:, W + BAR_GAP + BAR_WIDTH // 2, 0]
    rows = span[0] + (span[1] - span[0]) * np.arange(H) / (H - 1)
    expected = 0.15 + 0.85 * (span[1] - rows) / (span[1] - span[0])
    np.testing.assert_allclose(bar, expected, atol=1 / 255 + 1e-9)
    assert bar[0] == pytest.approx(1.0, abs=1 / 255) and bar[-1] == pytest.approx(0.15, abs=1 / 255)
    labels = out[:, W + BAR_GAP + BAR_WIDTH + 3 :]
    assert (labels > 0.9).sum() > 50  # the white tick labels are drawn
    assert (with_depth_bar(image, None)[:, W + BAR_GAP : W + BAR_GAP + BAR_WIDTH] == 0).all()


def test_overrides_change_the_recipe_and_are_checked():
    cfg, tc = load_config(recipe_path())
    cfg2, tc2 = with_overrides(cfg, tc, {"train.steps": 200, "train.val_every": 50, "model.refine_steps": 0})
    assert (tc2.steps, tc2.val_every, cfg2.refine_steps) == (200, 50, 0)
    assert tc2.lr == tc.lr and cfg2.resolution == cfg.resolution  # the rest as the file says
    assert with_overrides(cfg, tc, {}) == (cfg, tc)
    with pytest.raises(ConfigError, match=r"override train\.steps: expected int"):
        with_overrides(cfg, tc, {"train.steps": "many"})
    with pytest.raises(ConfigError, match="unknown key"):
        with_overrides(cfg, tc, {"train.stepz": 5})
    with pytest.raises(ConfigError, match="expected model.KEY=VALUE"):
        with_overrides(cfg, tc, {"steps": 5})
    with pytest.raises(ConfigError, match=r"override train\.lr"):
        with_overrides(cfg, tc, {"train.lr": float("nan")})


def test_eval_figure_writes_each_views_psnr_and_palette_objects(tmp_path):
    """The grid's render row carries each view's PSNR against its target (a float64 brute force of the same
    images), and its objects row the shared palette's colours (background grey)."""
    import torch

    from particlesplat.analysis.evaluate import FIGURE_LABEL_WIDTH, save_figure
    from particlesplat.core import palette

    H = W = 64
    target = torch.rand(3, 3, H, W, generator=torch.Generator().manual_seed(0))
    rgb = (target + torch.tensor([0.05, 0.1, 0.2]).view(3, 1, 1, 1)).clamp(0, 1)
    seg = torch.full((3, H, W), -1, dtype=torch.int64)
    seg[:, :20, :20], seg[:, 30:, 30:] = 0, 1
    item = {"context_rgb": target[:2], "target_rgb": target}
    res = {"renders": {"rgb": rgb, "depth": torch.rand(3, 1, H, W) * 3.0, "seg_objects": seg}}
    scores = save_figure(tmp_path / "f.png", item, res)
    truth = [-10.0 * np.log10(((rgb[i].double() - target[i].double()) ** 2).mean().item()) for i in range(3)]
    np.testing.assert_allclose(scores, truth, atol=1e-4)
    assert scores[0] > scores[1] > scores[2]
    img = np.asarray(Image.open(tmp_path / "f.png").convert("RGB"))
    objects = img[4 * H : 5 * H, FIGURE_LABEL_WIDTH : FIGURE_LABEL_WIDTH + W]
    for (y, x), key in (((5, 5), 0), ((50, 50), 1), ((5, 50), -1)):
        np.testing.assert_array_equal(objects[y, x], np.round(np.array(palette.colour(key)) * 255))
    assert not np.array_equal(objects[5, 5], objects[50, 50])  # distinct object colours
