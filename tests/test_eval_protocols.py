"""``eval --protocol``: the paper's fixed frames, the context views redrawn, and PSNR on the pixels the context views
see and on those they do not, checked against the scenes' own frames and analytic cases."""

from __future__ import annotations

import json
import math
import re
import shutil

import pytest
import torch
from model_data import tiny_dataset, untrained_tiny_checkpoint

from particlesplat.analysis.eval_summary import summary_line
from particlesplat.analysis.evaluate import SCALARS
from particlesplat.analysis.metrics import OBJECT_HELD, object_pixels_held, region_psnr
from particlesplat.cli.main import main
from particlesplat.core.choices import PAPER_CONTEXT_FRAMES, PAPER_TARGET_FRAMES
from particlesplat.core.errors import EXIT_USER, run_command
from particlesplat.data import SceneDataset
from particlesplat.data.views import protocol_views


def test_protocol_views_choose_the_papers_frames_or_the_context_itself():
    ctx, tgt = torch.tensor([3, 11]), torch.tensor([4, 5, 8, 10])
    assert protocol_views("sampled", 21, ctx, tgt) == (ctx, tgt)
    c, t = protocol_views("inputs", 21, ctx, tgt)
    assert c.tolist() == [3, 11] and t.tolist() == [3, 11]
    c, t = protocol_views("paper", 21, ctx, tgt)
    assert c.tolist() == [6, 14] and t.tolist() == [6, 8, 10, 12, 14]
    assert protocol_views("paper", 15, ctx, tgt)[0].tolist() == [6, 14]  # frames 0-14 are enough
    with pytest.raises(ValueError, match="needs at least 15"):
        protocol_views("paper", 14, ctx, tgt)


def test_the_papers_protocol_reads_frames_6_to_14_of_each_scene(tmp_path_factory):
    """The dataset's items under the paper's protocol hold the scene's own frames 6, 8, ..., 14: target frame 6 is
    the first context image, pixel for pixel, and frame 14 the second."""
    data = tiny_dataset(tmp_path_factory)
    item = SceneDataset(data / "val", deterministic=True, progress=1.0, protocol="paper")[0]
    assert item["context_index"].tolist() == list(PAPER_CONTEXT_FRAMES)
    assert item["target_index"].tolist() == list(PAPER_TARGET_FRAMES)
    assert torch.equal(item["target_rgb"][0], item["context_rgb"][0])
    assert torch.equal(item["target_rgb"][-1], item["context_rgb"][1])
    assert torch.equal(item["target_c2w"][2], SceneDataset(data / "val", deterministic=True).raw(0).cameras[10].c2w)
    inputs = SceneDataset(data / "val", deterministic=True, progress=1.0, protocol="inputs")[0]
    default = SceneDataset(data / "val", deterministic=True, progress=1.0)[0]
    assert torch.equal(inputs["context_index"], default["context_index"])  # the same context as the default
    assert torch.equal(inputs["target_rgb"], inputs["context_rgb"])


def test_region_psnr_leaves_out_views_without_pixels_and_object_pixels_held_counts_analytically():
    gt = torch.full((2, 3, 4, 4), 0.5)
    pred = gt + 0.1  # MSE 1e-2 everywhere: 20 dB
    region = torch.zeros(2, 4, 4, dtype=torch.bool)
    assert math.isnan(region_psnr(pred, gt, region))
    region[0, :2] = True  # view 1 has no pixel in the region: it must not count as a perfect 100 dB
    assert abs(region_psnr(pred, gt, region) - 20.0) < 1e-4
    weight = torch.zeros(2, 4, 4)
    masks = torch.zeros(2, 4, 4, dtype=torch.long)
    assert math.isnan(object_pixels_held(weight, masks))
    masks[0, :, :2] = 1  # 8 object pixels
    weight[0, 0, :2] = OBJECT_HELD  # 2 at the threshold: held
    weight[0, 1, :2] = OBJECT_HELD - 1e-3  # 2 just under: not held
    weight[1] = 1.0  # no object there: not counted
    assert object_pixels_held(weight, masks) == pytest.approx(2 / 8)
    valid = torch.ones(2, 1, 4, 4)
    valid[0, 0, 2:] = 0  # 4 object pixels left out of the score
    assert object_pixels_held(weight, masks, valid) == pytest.approx(2 / 4)


@pytest.fixture(scope="module")
def tiny_checkpoint(tmp_path_factory):
    return untrained_tiny_checkpoint(tmp_path_factory.mktemp("protocols"))


def test_eval_inputs_protocol_scores_pixels_the_context_sees(tmp_path_factory, tmp_path, tiny_checkpoint, capsys):
    """Redrawn at their own cameras, the context views see every pixel of themselves: the unseen region is empty
    (reported as "no pixels", never as a number), and the seen PSNR is the whole image's."""
    data = tiny_dataset(tmp_path_factory)
    out = tmp_path / "eval.json"
    args = ["eval", "--checkpoint", str(tiny_checkpoint), "--data", str(data / "val"), "--json", str(out)]
    assert main([*args, "--protocol", "inputs", "--num-figures", "0"]) == 0
    res = json.loads(out.read_text())
    assert res["protocol"] == "inputs"
    mean = res["mean"]
    assert mean["psnr_unseen"] is None  # NaN in JSON: no pixel is unseen
    assert mean["psnr_seen"] == pytest.approx(mean["psnr"], abs=1e-6)
    assert res["error_regions"]["seen_by_context"]["pixel_share"] == pytest.approx(1.0)
    assert 0.0 <= mean["object_held"] <= 1.0
    printed = capsys.readouterr().out
    assert (
        "protocol inputs" in printed
        and "no pixels on those none does" in printed
        and not re.search(r"\bnan\b", printed)
    )
    # the default protocol scores novel views: some of their pixels are unseen by both context views
    assert main([*args, "--protocol", "sampled"]) == 0
    res = json.loads(out.read_text())
    assert res["protocol"] == "sampled" and 0.0 < res["error_regions"]["unseen_by_context"]["pixel_share"] < 1.0
    assert res["mean"]["psnr_seen"] is not None and res["mean"]["psnr_unseen"] is not None


def short_split(tmp_path_factory, tmp_path):
    """A copy of the tiny val split whose scene keeps only its first 12 frames."""
    data = tiny_dataset(tmp_path_factory)
    short = tmp_path / "short"
    shutil.copytree(data / "val", short)
    transforms = short / "scene_00000" / "transforms.json"
    meta = json.loads(transforms.read_text())
    meta["frames"] = meta["frames"][:12]
    transforms.write_text(json.dumps(meta))
    return short


def test_eval_paper_protocol_refuses_short_scenes_and_one_context_view(tmp_path, tiny_checkpoint, tmp_path_factory):
    data = tiny_dataset(tmp_path_factory)
    short = short_split(tmp_path_factory, tmp_path)
    base = ["eval", "--checkpoint", str(tiny_checkpoint), "--protocol", "paper", "--num-figures", "0"]
    assert run_command("particlesplat eval", lambda: main([*base, "--data", str(short)])) == EXIT_USER
    one_view = [*base, "--data", str(data / "val"), "--context", "1"]
    assert run_command("particlesplat eval", lambda: main(one_view)) == EXIT_USER
    assert main([*base, "--data", str(data / "val"), "--json", str(tmp_path / "p.json")]) == 0
    assert json.loads((tmp_path / "p.json").read_text())["protocol"] == "paper"


def test_eval_short_scene_error_names_the_scene_and_the_protocol(tmp_path, tiny_checkpoint, tmp_path_factory, capsys):
    short = short_split(tmp_path_factory, tmp_path)
    argv = ["eval", "--checkpoint", str(tiny_checkpoint), "--protocol", "paper", "--data", str(short)]
    assert run_command("particlesplat eval", lambda: main(argv)) == EXIT_USER
    err = [line for line in capsys.readouterr().err.splitlines() if line.startswith("particlesplat eval:")]
    assert len(err) == 1 and "scene_00000" in err[0] and "paper's protocol" in err[0] and "12 frame(s)" in err[0]


def test_summary_line_says_no_pixels_for_an_empty_region():
    mean = dict.fromkeys(SCALARS, 1.0)
    mean |= {"psnr_seen": 25.0, "psnr_unseen": float("nan"), "object_held": float("nan")}
    line = summary_line({"scenes": [{}], "mean": mean, "protocol": "inputs"}, 2, False)
    assert "25.00 dB on the pixels a context view sees, no pixels on those none does" in line
    assert not re.search(r"\bnan\b", line)
