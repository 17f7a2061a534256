"""What a user meets around cameras and colours: a negative --look azimuth, a screenshot's camera reproduced by
``particlesplat render --camera-from``, list swatches in the colours the segmentation modes draw, a warning for a
scene without depth, and the default framing clear of the panel."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from particlesplat.core.camera import Camera
from particlesplat.core.gaussians import Gaussians
from particlesplat.core.options import attach_option_values
from particlesplat.core.viewpoints import parse_look
from particlesplat.editing.open_scene import demo_scenes
from particlesplat.formats.png import camera_from_png, png_text, save_png


def test_a_negative_look_value_is_attached_to_its_option():
    assert attach_option_values(["--look", "-30,20,3", "--view", "2"]) == ["--look=-30,20,3", "--view", "2"]
    assert attach_option_values(["--look", "30,20,3"]) == ["--look", "30,20,3"]
    assert attach_option_values(["--look", "--out", "x"]) == ["--look", "--out", "x"]  # an option stays one
    import argparse

    p = argparse.ArgumentParser()
    p.add_argument("--look")
    assert parse_look(p.parse_args(attach_option_values(["--look", "-30.5,20,3"])).look).azimuth == -30.5


def test_negative_numbers_after_any_long_option_are_its_value():
    """``--at -0.1,0.2`` (an object spot left of the table's centre) reaches ``--at``; a ``--`` ends the rewriting
    and a word that only starts with a dash is left alone."""
    assert attach_option_values(["--at", "-0.1,0.2", "--out", "x"]) == ["--at=-0.1,0.2", "--out", "x"]
    assert attach_option_values(["--scale", "-.5"]) == ["--scale=-.5"]
    assert attach_option_values(["--at", "-1e-3,2"]) == ["--at=-1e-3,2"]
    assert attach_option_values(["--at", "-x"]) == ["--at", "-x"]
    assert attach_option_values(["--", "--at", "-1,2"]) == ["--", "--at", "-1,2"]
    assert attach_option_values(["--at=-1,2"]) == ["--at=-1,2"]
    import argparse

    p = argparse.ArgumentParser()
    p.add_argument("--at")
    assert p.parse_args(attach_option_values(["--at", "-0.25,-0.1"])).at == "-0.25,-0.1"


def test_render_reproduces_a_png_camera(tmp_path):
    from particlesplat.cli.main import main

    scene = str(demo_scenes()[0])
    a, b = tmp_path / "a.png", tmp_path / "b.png"
    assert (
        main(["render", "--scene", scene, "--look", "-35,25,3.1", "--width", "48", "--height", "36", "--out", str(a)])
        == 0
    )
    cam = camera_from_png(a)
    expected = Camera.orbit((0.0, 0.0, 0.0), -35.0, 25.0, 3.1, width=48, height=36)
    assert (cam.width, cam.height) == (48, 36)
    # the look is about the scene's default target: the viewing direction is the one asked for
    torch.testing.assert_close(cam.c2w[:3, :3], expected.c2w[:3, :3].float(), rtol=0, atol=1e-5)
    assert main(["render", "--scene", scene, "--camera-from", str(a), "--out", str(b)]) == 0
    assert np.array_equal(np.asarray(Image.open(a)), np.asarray(Image.open(b)))
    assert main(["render", "--scene", scene, "--camera-from", str(a), "--width", "96", "--out", str(b)]) == 0
    assert Image.open(b).size == (96, 72)


def test_camera_from_png_errors_name_the_file(tmp_path):
    plain = tmp_path / "plain.png"
    Image.new("RGB", (4, 4)).save(plain)
    with pytest.raises(ValueError, match=r"plain.png: no 'camera' text chunk"):
        camera_from_png(plain)
    with pytest.raises(FileNotFoundError, match="missing.png"):
        camera_from_png(tmp_path / "missing.png")
    cam = Camera.orbit((0.0, 0.0, 0.0), 10.0, 20.0, 3.0, width=8, height=6)
    text = png_text(cam, {}, "m")
    text["camera"] = text["camera"].replace('"width": 8', '"width": "x"')
    save_png(tmp_path / "bad.png", np.zeros((6, 8, 3)), text)
    with pytest.raises(ValueError, match=r"bad.png: camera chunk"):
        camera_from_png(tmp_path / "bad.png")


@pytest.mark.gl
def test_list_swatches_are_the_colours_the_segmentation_mode_draws():
    from viewer_helpers import egl_context

    from viewer.gl.renderer import SplatRenderer
    from viewer.ui.objects import segmentation_colour

    ctx = egl_context()
    try:
        owners = [3, 7, 12]
        means = torch.tensor([[-0.4, 0.0, 0.0], [0.0, 0.0, 0.0], [0.4, 0.0, 0.0]])
        g = Gaussians(
            means,
            torch.tensor([[1.0, 0.0, 0.0, 0.0]]).repeat(3, 1),
            torch.full((3, 3), 0.06),
            torch.full((3,), 0.999),
            torch.zeros(3, 1, 3),
            torch.tensor(owners),
        )
        cam = Camera.look_at((0.0, -3.0, 0.0), (0.0, 0.0, 0.0), fov_y_deg=30.0, width=96, height=64)
        r = SplatRenderer(ctx)
        r.set_gaussians(g)
        r.render(cam, color_mode=1)
        rgba = r.read_rgba()  # premultiplied: the colour is rgb / alpha
        uv, _ = cam.project(means)
        for (u, v), owner in zip(uv.tolist(), owners, strict=False):
            px = rgba[int(v), int(u)]
            assert px[3] > 0.9
            np.testing.assert_allclose(px[:3] / px[3], segmentation_colour(owner), atol=0.01)
        r.release()
    finally:
        ctx.release()


def test_a_scene_without_depth_warns(tmp_path):
    import json
    import shutil

    from particlesplat.editing.open_scene import encode_scene
    from particlesplat.model import load_model

    src = demo_scenes()[0]
    dst = tmp_path / "rgb_only"
    shutil.copytree(src, dst)
    tf = json.loads((dst / "transforms.json").read_text())
    for frame in tf["frames"]:
        frame.pop("depth_file_path", None)
    (dst / "transforms.json").write_text(json.dumps(tf))
    shutil.rmtree(dst / "depth")
    model = load_model(None)
    enc = encode_scene(model, dst, [4, 16])
    assert len(enc.warnings) == 1 and "no depth" in enc.warnings[0] and "rgb_only" in enc.warnings[0]
    # it quotes the README's results table: PSNR of 2 RGB views and of 2 RGB-D views
    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    for row in ("2 RGB views (no depth)", "2 RGB-D views"):
        psnr = re.search(rf"^\| {re.escape(row)} \| [^|]+ \| ([0-9.]+) \|", readme, re.MULTILINE).group(1)
        assert f"{psnr} dB" in enc.warnings[0], (row, psnr)
    assert encode_scene(model, src, [4, 16]).warnings == []


def test_the_default_framing_keeps_the_scene_clear_of_the_panel():
    from viewer.ui.panel import PANEL_MARGIN, PANEL_WIDTH, clear_of_panel

    cam = Camera.orbit((0.2, -0.1, 0.15), 30.0, 30.0, 3.3, width=2560, height=1600)
    framed = clear_of_panel(cam, 2.0)  # a HiDPI window: 2 pixels a point
    (u, v), _ = framed.project(torch.tensor([[0.2, -0.1, 0.15]]))[0][0], None
    free = 2560 - 2.0 * (PANEL_WIDTH + PANEL_MARGIN)  # pixels left of the panel
    assert abs(float(u) - free / 2) < 1e-3 and abs(float(v) - 800) < 1e-3
    small = Camera.orbit((0.0, 0.0, 0.0), 0.0, 30.0, 3.0, width=300, height=200)
    assert clear_of_panel(small, 1.0) is small  # too narrow to share with the panel: centred
