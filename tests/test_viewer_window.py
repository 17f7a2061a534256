"""Window smoke tests: the real app under xvfb-run, its screenshots against the torch renderer
and against ``particlesplat render`` (same default view, --look/--fov and edits)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from PIL import Image
from viewer_helpers import psnr, small_model

from particlesplat import render
from particlesplat.cli.main import main as cli_main
from particlesplat.core.gaussians import Gaussians
from particlesplat.core.viewpoints import DEFAULT_BACKGROUND, View, default_view, parse_look, scene_background
from particlesplat.model import save_checkpoint
from viewer.bench.random_gaussians import random_gaussians

pytestmark = pytest.mark.window

VIEWER = str(Path(sys.executable).with_name("particlesplat-viewer"))
# the driver as NVIDIA's and AMD's desktop drivers are: without framebuffer fetch
HIDE_FETCH = {"MESA_EXTENSION_OVERRIDE": "-GL_EXT_shader_framebuffer_fetch"}


def write_version_1_edits(path: Path, edits: dict[int, dict[str, tuple[float, ...]]]) -> None:
    """A version 1 edit file (particle index -> values): still read, no longer written by the package."""
    particles = {i: {k: list(v) for k, v in attrs.items()} for i, attrs in edits.items()}
    path.write_text(yaml.safe_dump({"version": 1, "particles": particles}))


def run_viewer(*args: str, env: dict[str, str] | None = None) -> str:
    proc = subprocess.run(
        ["xvfb-run", "-a", VIEWER, *args],
        capture_output=True,
        text=True,
        timeout=240,
        env={**os.environ, **(env or {})},
    )
    assert proc.returncode == 0, proc.stderr
    assert "median frame time" in proc.stdout
    return proc.stdout


def load_png(path: Path) -> np.ndarray:
    return np.asarray(Image.open(path).convert("RGB"), np.float64) / 255.0


def test_ply_screenshot_matches_torch(tmp_path):
    g = random_gaussians(1500, seed=4, sh_degree=2, pixel_scale=0.04)
    g.save_ply(tmp_path / "g.ply")
    g = Gaussians.load_ply(tmp_path / "g.ply")
    shot = tmp_path / "shot.png"
    out = run_viewer(
        "--ply",
        str(tmp_path / "g.ply"),
        "--frames",
        "4",
        "--orbit",
        "--size",
        "160x120",
        "--look",
        "20,25,3.0",
        "--fov",
        "50",
        "--screenshot",
        str(shot),
    )
    # like a drag: moving frames at the moving scale, then the still frame
    assert "over 3 moving frames at render scale 0.5" in out and "still frame at full scale:" in out
    img = Image.open(shot)
    assert img.size == (160, 120)
    assert {"camera", "edits", "model", "look"} <= set(img.text)
    base = default_view(None, g)
    look = parse_look("24,25,3.0")  # --orbit turns 1 degree per frame
    cam = View(base.target, look, 50.0).camera(160, 120)
    ref = render(g, cam, background=DEFAULT_BACKGROUND).rgb.numpy()
    assert psnr(load_png(shot), ref) >= 40.0


@pytest.mark.parametrize("driver", ["as is", "without framebuffer fetch"])
def test_model_scene_with_edits_matches_render_cli(tmp_path, driver):
    ckpt = tmp_path / "small.pt"
    save_checkpoint(ckpt, small_model(), 0)
    edits = tmp_path / "edits.yaml"
    write_version_1_edits(edits, {1: {"z_p": (0.2, -0.3)}, 4: {"z_t": (0.0,)}})
    shot, out = tmp_path / "viewer.png", tmp_path / "render.png"
    hidden = driver != "as is"
    stdout = run_viewer(
        "--checkpoint",
        str(ckpt),
        "--edits",
        str(edits),
        "--frames",
        "2",
        "--size",
        "128x96",
        "--screenshot",
        str(shot),
        env=HIDE_FETCH if hidden else None,
    )
    if hidden:  # auto took the core-GL path
        assert "blend compositing" in stdout
    assert (
        cli_main(
            [
                "render",
                "--checkpoint",
                str(ckpt),
                "--edits",
                str(edits),
                "--width",
                "128",
                "--height",
                "96",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    a, b = load_png(shot), load_png(out)
    assert psnr(a, b) >= 40.0
    # and the edits changed the picture: the same scene without edits differs
    plain = tmp_path / "plain.png"
    assert cli_main(["render", "--checkpoint", str(ckpt), "--width", "128", "--height", "96", "--out", str(plain)]) == 0
    assert np.abs(load_png(plain) - b).max() > 0.01  # (an untrained model: faint particles)


def test_viewer_rejects_bad_arguments(tmp_path):
    proc = subprocess.run(
        [VIEWER, "--ply", str(tmp_path / "missing.ply"), "--frames", "1"], capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == 2 and "missing.ply" in proc.stderr
    proc = subprocess.run([VIEWER, "--ply", "g.ply", "--context", "4,16"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and "--context needs a model scene" in proc.stderr
    proc = subprocess.run([VIEWER, "--size", "12xfoo"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and "--size" in proc.stderr
    proc = subprocess.run([VIEWER, "--compositing", "fast"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and "--compositing" in proc.stderr


def test_forced_fetch_without_the_extension_is_a_clear_error(tmp_path):
    g = random_gaussians(50, seed=0)
    g.save_ply(tmp_path / "g.ply")
    proc = subprocess.run(
        ["xvfb-run", "-a", VIEWER, "--ply", str(tmp_path / "g.ply"), "--frames", "1", "--compositing", "fetch"],
        capture_output=True,
        text=True,
        timeout=240,
        env={**os.environ, **HIDE_FETCH},
    )
    assert proc.returncode == 2  # a bad argument for this driver
    assert proc.stderr.strip().splitlines() == [proc.stderr.strip()]  # one line
    assert "GL_EXT_shader_framebuffer_fetch" in proc.stderr and "--compositing auto or blend" in proc.stderr


def test_render_cli_view_and_errors(tmp_path):
    g = random_gaussians(300, seed=2)
    g.save_ply(tmp_path / "g.ply")
    out = tmp_path / "o.png"
    assert (
        cli_main(
            [
                "render",
                "--ply",
                str(tmp_path / "g.ply"),
                "--look",
                "10,20,3",
                "--fov",
                "45",
                "--width",
                "40",
                "--height",
                "30",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    base = default_view(None, Gaussians.load_ply(tmp_path / "g.ply"))
    ref = render(
        Gaussians.load_ply(tmp_path / "g.ply"),
        View(base.target, parse_look("10,20,3"), 45.0).camera(40, 30),
        background=DEFAULT_BACKGROUND,
    ).rgb.numpy()
    assert psnr(load_png(out), ref) >= 40.0
    assert cli_main(["render", "--ply", str(tmp_path / "g.ply"), "--look", "1,2", "--out", str(out)]) == 2
    assert cli_main(["render", "--ply", str(tmp_path / "g.ply"), "--view", "0", "--out", str(out)]) == 2
    assert cli_main(["render", "--ply", str(tmp_path / "g.ply"), "--context", "1,2", "--out", str(out)]) == 2
    # an --out that cannot be written (a folder) is a clear error, and no temporary file is left
    before = set(tmp_path.iterdir())
    assert (
        cli_main(["render", "--ply", str(tmp_path / "g.ply"), "--width", "8", "--height", "8", "--out", str(tmp_path)])
        == 2
    )
    assert set(tmp_path.iterdir()) == before


def test_context_out_of_range_names_the_folder():
    from particlesplat.editing.open_scene import demo_scenes, encode_scene

    scene = demo_scenes()[0]
    for bad in ([4, 40], [-1, 4], []):
        with pytest.raises(ValueError, match=f"--context: {scene}"):
            encode_scene(small_model(), scene, bad)


def test_render_cli_input_view_with_edits(tmp_path):
    """`--view I` renders input camera I of the scene; edits apply to the decoded particles."""
    from particlesplat.editing.open_scene import demo_scenes, encode_scene
    from particlesplat.editing.particle_edits import apply_edits

    model = small_model()
    ckpt = tmp_path / "small.pt"
    save_checkpoint(ckpt, model, 0)
    edits = {2: {"z_d": (1.5,)}, 3: {"z_s": (0.5, -0.5)}}
    write_version_1_edits(tmp_path / "e.yaml", edits)
    out = tmp_path / "v.png"
    assert (
        cli_main(
            [
                "render",
                "--checkpoint",
                str(ckpt),
                "--edits",
                str(tmp_path / "e.yaml"),
                "--view",
                "3",
                "--width",
                "48",
                "--height",
                "40",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    enc = encode_scene(model, demo_scenes()[0])
    g = model.decode(apply_edits(enc.particles, edits))
    assert scene_background(model) != DEFAULT_BACKGROUND  # the model's learned colour is behind it
    ref = render(g, enc.all_cameras[3].resized(48, 40), background=scene_background(model)).rgb.numpy()
    assert psnr(load_png(out), ref) >= 40.0
    assert "z_d" in Image.open(out).text["edits"]
    # with only --width, an input view keeps its camera's aspect (the demo scenes are square)
    assert cli_main(["render", "--checkpoint", str(ckpt), "--view", "3", "--width", "40", "--out", str(out)]) == 0
    assert Image.open(out).size == (40, 40)
