"""Render modes and turntables: keypoints land on z_p's pixel in the particle's own view, boxes stay inside their
projected corners, depth is brighter near, the turntable's frames and animation agree with still renders."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from model_data import TINY_MODEL, tiny_dataset
from PIL import Image

from particlesplat.analysis.figures import (
    DIM,
    depth_image,
    render_mode,
    turntable_cameras,
    turntable_paths,
)
from particlesplat.analysis.particle_arrays import particle_arrays
from particlesplat.cli.main import main
from particlesplat.core.camera import Camera
from particlesplat.core.choices import MODES
from particlesplat.core.palette import colour
from particlesplat.core.viewpoints import Look, View
from particlesplat.editing.open_scene import encode_scene
from particlesplat.model import ModelConfig, ParticleSplat, save_checkpoint
from particlesplat.rendering.api import render

UP = 4  # render the context view at 4x its size


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    torch.manual_seed(0)
    model = ParticleSplat(ModelConfig(**TINY_MODEL)).eval()
    data = tiny_dataset(tmp_path_factory)
    enc = encode_scene(model, data / "train" / "scene_00000", [4, 16])
    g = model.decode(enc.particles)
    return model, enc, g, particle_arrays(model, enc.particles, g), data


def test_modes_shapes_and_plain_layers(scene):
    model, enc, g, arrays, _ = scene
    cam = enc.particles.cameras[0].resized(48, 40)
    for mode in MODES:
        img = render_mode(g, cam, mode, background=(0.1, 0.2, 0.3), arrays=arrays)
        assert img.shape == (40, 48, 3) and np.isfinite(img).all() and img.min() >= 0 and img.max() <= 1
    ref = render(g, cam, background=(0.1, 0.2, 0.3)).rgb.numpy()
    np.testing.assert_allclose(render_mode(g, cam, "rgb", background=(0.1, 0.2, 0.3)), ref, atol=1e-6)
    fg = render(g.subset(g.owner >= 0), cam, background=(0.1, 0.2, 0.3)).rgb.numpy()
    np.testing.assert_allclose(
        render_mode(g, cam, "foreground", background=(0.1, 0.2, 0.3), arrays=arrays), fg, atol=1e-6
    )
    with pytest.raises(ValueError, match="needs a model scene"):
        render_mode(g, cam, "keypoints")
    with pytest.raises(ValueError, match="--mode must be one of"):
        render_mode(g, cam, "normals", arrays=arrays)


def test_keypoints_sit_on_z_p_in_their_own_view(scene):
    """In a particle's own context view the anchor projects to z_p's pixel, so the dot is drawn there."""
    model, enc, g, arrays, _ = scene
    res = model.config.resolution
    cam = enc.particles.cameras[0].resized(res * UP, res * UP)
    img = render_mode(g, cam, "keypoints", arrays=arrays)
    mine = [i for i in np.flatnonzero(arrays.active) if arrays.view[i] == 0]
    assert mine
    hits = 0
    for i in mine:
        u, v = ((arrays.z_p[i] + 1.0) * 0.5 * res * UP).astype(int)
        if 0 <= u < res * UP and 0 <= v < res * UP:
            hits += int(np.abs(img[v, u] - np.array(colour(int(arrays.object[i])))).max() < 2 / 255)
    assert hits >= max(1, len(mine) - 1)  # a later dot may cover one


def test_boxes_are_drawn_inside_their_projected_corners(scene):
    model, enc, g, arrays, _ = scene
    one = np.zeros_like(arrays.active)
    one[int(np.flatnonzero(arrays.active)[0])] = True
    a = particle_arrays(model, enc.particles, g)
    a.active = one
    cam = Camera.orbit((0.0, 0.0, 0.15), 20.0, 35.0, 3.3, width=160, height=120)
    img = render_mode(g, cam, "boxes", arrays=a)
    base = np.clip(render(g, cam).rgb.numpy() * DIM, 0, 1)
    drawn = np.abs(img - np.round(base * 255) / 255).max(-1) > 3 / 255
    assert drawn.sum() > 20
    i = int(np.flatnonzero(one)[0])
    c, e = a.centroid[i].astype(np.float64), 2.0 * a.extent[i].astype(np.float64)
    corners = torch.tensor(
        [[c[0] + sx * e[0], c[1] + sy * e[1], c[2] + sz * e[2]] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]
    )
    uv, _ = cam.to(dtype=torch.float64).project(corners)
    lo, hi = uv.min(0).values.numpy() - 2, uv.max(0).values.numpy() + 2
    v, u = np.nonzero(drawn)
    assert ((u >= lo[0]) & (u <= hi[0]) & (v >= lo[1]) & (v <= hi[1])).all()


def test_depth_image_near_is_bright():
    depth = np.array([[1.0, 2.0, 3.0, 0.0]])
    alpha = np.array([[1.0, 1.0, 1.0, 0.0]])
    grey = depth_image(depth, alpha)[0, :, 0]
    assert grey[0] > grey[1] > grey[2] > grey[3] == 0.0


def test_depth_image_shows_depth_not_opacity():
    """A floor at one depth drawn with opacity 0.59..1.0 (a checker of semi-transparent splats) is one grey."""
    depth = np.full((4, 4), 2.0)
    depth[0] = 1.0  # something nearer, so the range is not empty
    alpha = np.where(np.indices((4, 4)).sum(0) % 2 == 0, 1.0, 0.59)
    grey = depth_image(depth, alpha)[..., 0]
    assert np.ptp(grey[1:]) == 0.0 and grey[0, 0] > grey[1, 0]


def test_turntable_cameras_orbit_once():
    view = View((0.1, 0.0, 0.2), Look(30.0, 25.0, 3.0), 40.0)
    cams = turntable_cameras(view, 4, 32, 24)
    first = view.camera(32, 24)
    torch.testing.assert_close(cams[0].c2w, first.c2w)
    target = torch.tensor(view.target, dtype=cams[0].c2w.dtype)
    radii = [float((c.center - target).norm()) for c in cams]
    assert radii == pytest.approx([3.0] * 4, abs=1e-5)
    # a quarter turn each: opposite frames' centres are mirror images through the vertical axis at the target
    assert float((cams[0].center + cams[2].center - 2 * target)[:2].norm()) < 1e-5
    frames, anim = turntable_paths("/x/t.png", 12)
    assert (frames[0].name, frames[-1].name, anim.name) == ("t_000.png", "t_011.png", "t.gif")
    assert turntable_paths("/x/t.webp", 2)[1].name == "t.webp"


def test_render_command_turntable(scene, tmp_path, capsys):
    model, _, _, _, data = scene
    ckpt = tmp_path / "m.pt"
    save_checkpoint(ckpt, model, 0)
    out = tmp_path / "tt" / "spin.gif"
    scene_dir = str(data / "train" / "scene_00000")
    assert (
        main(
            [
                "render",
                "--checkpoint",
                str(ckpt),
                "--scene",
                scene_dir,
                "--context",
                "4,16",
                "--mode",
                "objects",
                "--turntable",
                "3",
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
    frames = sorted(p.name for p in out.parent.glob("spin_*.png"))
    assert frames == ["spin_000.png", "spin_001.png", "spin_002.png"]
    with Image.open(out) as im:
        assert (im.n_frames, im.size) == (3, (40, 30))
    # frame 0 is the still render of the same mode from the default view
    still = tmp_path / "still.png"
    assert (
        main(
            [
                "render",
                "--checkpoint",
                str(ckpt),
                "--scene",
                scene_dir,
                "--context",
                "4,16",
                "--mode",
                "objects",
                "--width",
                "40",
                "--height",
                "30",
                "--out",
                str(still),
            ]
        )
        == 0
    )
    np.testing.assert_array_equal(np.asarray(Image.open(still)), np.asarray(Image.open(out.parent / frames[0])))
    # a PNG's camera is one fixed camera, not an orbit: refused with one line, before the work
    fixed = ["render", "--checkpoint", str(ckpt), "--scene", scene_dir, "--camera-from", str(still)]
    capsys.readouterr()
    assert main([*fixed, "--turntable", "2", "--out", str(tmp_path / "fixed.gif")]) == 2
    assert "--turntable orbits the default target" in capsys.readouterr().err
    assert not list(tmp_path.glob("fixed*"))
    ply = tmp_path / "s.ply"
    model.decode(encode_scene(model, scene_dir, [4, 16]).particles).detach().save_ply(ply)
    assert main(["render", "--ply", str(ply), "--mode", "boxes", "--out", str(tmp_path / "b.png")]) != 0
