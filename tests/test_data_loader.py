"""Loader tests: reprojection between frames of generated scenes, an independently written
nerfstudio-style folder, resizing, flips, and every format error."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from particlesplat.core.bundled import bundled_assets
from particlesplat.data import SceneFormatError, flip_horizontal, load_scene
from particlesplat.data.scene import Scene

SCENES = bundled_assets() / "scenes"
SCENE = Path(str(SCENES / "scene_00000"))


def reprojection(scene: Scene, i: int, j: int) -> dict[str, float]:
    """Unproject frame i's depth, project into frame j; compare where the point is visible in j.

    Colour is compared only where both pixels sit in flat 3x3 neighbourhoods (no edge blending).
    """
    ci, cj = scene.cameras[i].to(dtype=torch.float64), scene.cameras[j].to(dtype=torch.float64)
    d = scene.depth[i, 0].double()
    _, dirs = ci.rays()
    points = ci.center + dirs * d[..., None]
    uv, z = cj.project(points)
    u, v = uv[..., 0].floor().long(), uv[..., 1].floor().long()
    inside = (d > 0) & (z > 0) & (u >= 0) & (u < cj.width) & (v >= 0) & (v < cj.height)
    u, v = u.clamp(0, cj.width - 1), v.clamp(0, cj.height - 1)
    dj = scene.depth[j, 0].double()[v, u]
    visible = inside & ((dj - z).abs() < 0.01 * z)

    def flat(rgb: torch.Tensor) -> torch.Tensor:  # (3, H, W) -> (H, W) bool
        pad = torch.nn.functional.pad(rgb[None], (1, 1, 1, 1), mode="replicate")[0]
        win = pad.unfold(1, 3, 1).unfold(2, 3, 1)  # (3, H, W, 3, 3)
        return (win.amax((-1, -2)) - win.amin((-1, -2))).amax(0) < 1.5 / 255

    both_flat = visible & flat(scene.rgb[i]) & flat(scene.rgb[j])[v, u]
    colour_err = (scene.rgb[i] - scene.rgb[j][:, v, u]).abs().amax(0)
    return {
        "visible": float(visible.sum()),
        "inside": float(inside.sum()),
        "colour_ok": float((colour_err[both_flat] < 2.5 / 255).double().mean()),
        "flat": float(both_flat.sum()),
        "mask_ok": float((scene.masks[i][visible] == scene.masks[j][v, u][visible]).double().mean()),
    }


@pytest.mark.parametrize("resolution", [None, 64, (96, 72)])
def test_reprojection_between_frames(resolution):
    scene = load_scene(SCENE, resolution)
    w, h = (
        (128, 128) if resolution is None else ((resolution, resolution) if isinstance(resolution, int) else resolution)
    )
    assert scene.rgb.shape == (21, 3, h, w) and scene.depth.shape == (21, 1, h, w)
    assert scene.masks.shape == (21, h, w) and scene.masks.dtype == torch.int64
    for i, j in [(10, 11), (10, 13), (3, 0), (20, 16)]:
        r = reprojection(scene, i, j)
        assert r["visible"] > 0.6 * r["inside"] > 0.3 * w * h
        assert r["flat"] > 0.2 * r["visible"]
        assert r["colour_ok"] > 0.99, (i, j, r)
        assert r["mask_ok"] > 0.99, (i, j, r)


def test_reprojection_fails_with_wrong_camera_convention():
    """The check above has teeth: treating OpenGL matrices as OpenCV breaks it."""
    scene = load_scene(SCENE)
    flip = torch.diag(torch.tensor([1.0, -1.0, -1.0, 1.0]))
    for cam in scene.cameras:
        cam.c2w = cam.c2w @ flip
    r = reprojection(scene, 10, 11)
    assert r["visible"] < 0.05 * r["inside"] or r["colour_ok"] < 0.9


def test_flip_keeps_frames_consistent():
    scene = load_scene(SCENE)
    rgb, cams, (depth, masks) = flip_horizontal(scene.rgb, scene.cameras, scene.depth, scene.masks)
    flipped = Scene(rgb, depth, masks, cams, scene.path, scene.frame_indices)
    for cam in cams:
        assert torch.det(cam.c2w[:3, :3].double()) == pytest.approx(1.0, abs=1e-5)
    for i, j in [(10, 12), (5, 2)]:
        r = reprojection(flipped, i, j)
        assert r["visible"] > 0.5 * r["inside"] and r["colour_ok"] > 0.99 and r["mask_ok"] > 0.99
    # a flipped world point lands on the mirrored pixel: u' = W - u
    point = torch.tensor([0.3, -0.2, 0.1])
    uv, z = scene.cameras[4].project(point)
    uv_f, z_f = cams[4].project(point * torch.tensor([-1.0, 1.0, 1.0]))
    assert float(z_f) == pytest.approx(float(z), abs=1e-5)
    assert float(uv_f[0]) == pytest.approx(128 - float(uv[0]), abs=1e-3)
    assert float(uv_f[1]) == pytest.approx(float(uv[1]), abs=1e-3)


# ---------------------------------------------------------------------------- independent writer
def _gl_look_at(eye, target) -> np.ndarray:
    """OpenGL camera-to-world (x right, y up, looking down -z), z-up world, written from scratch."""
    eye, target = np.asarray(eye, float), np.asarray(target, float)
    back = (eye - target) / np.linalg.norm(eye - target)
    right = np.cross([0.0, 0.0, 1.0], back)
    right /= np.linalg.norm(right)
    up = np.cross(back, right)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = right, up, back, eye
    return m


def _gl_project(c2w: np.ndarray, fx, fy, cx, cy, point) -> tuple[float, float]:
    p = np.linalg.inv(c2w) @ np.append(point, 1.0)
    return cx + fx * p[0] / -p[2], cy - fy * p[1] / -p[2]


def _write_png(path: Path, arr: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(arr).save(path)


@pytest.fixture
def nerfstudio_folder(tmp_path):
    """Two frames, non-square 40x30 images, the second with its own intrinsics; no depth, no masks."""
    rng = np.random.default_rng(3)
    frames = []
    for k, (eye, own) in enumerate([((0.5, -3.0, 1.2), {}), ((2.0, -2.0, 0.8), {"fl_x": 50.0, "cx": 21.0})]):
        _write_png(tmp_path / "images" / f"f{k}.png", rng.integers(0, 256, (30, 40, 3), dtype=np.uint8))
        frames.append(
            {"file_path": f"images/f{k}.png", "transform_matrix": _gl_look_at(eye, (0, 0, 0)).tolist(), **own}
        )
    meta = {"w": 40, "h": 30, "fl_x": 35.0, "fl_y": 33.0, "cx": 19.5, "cy": 15.5, "frames": frames}
    (tmp_path / "transforms.json").write_text(json.dumps(meta))
    return tmp_path


def test_independent_nerfstudio_folder_cameras(nerfstudio_folder):
    meta = json.loads((nerfstudio_folder / "transforms.json").read_text())
    scene = load_scene(nerfstudio_folder)
    assert scene.depth is None and scene.masks is None
    assert scene.rgb.shape == (2, 3, 30, 40)
    img = np.array(Image.open(nerfstudio_folder / "images" / "f1.png"))
    assert torch.equal(scene.rgb[1], torch.from_numpy(img).permute(2, 0, 1).float() / 255)
    points = [(0.0, 0.0, 0.0), (0.3, 0.2, 0.4), (-0.4, 0.1, -0.2)]
    for k, frame in enumerate(meta["frames"]):
        intr = {key: frame.get(key, meta[key]) for key in ("fl_x", "fl_y", "cx", "cy")}
        c2w = np.asarray(frame["transform_matrix"])
        for p in points:
            want = _gl_project(c2w, intr["fl_x"], intr["fl_y"], intr["cx"], intr["cy"], p)
            uv, z = scene.cameras[k].project(torch.tensor(p))
            assert float(z) > 0
            assert uv.tolist() == pytest.approx(want, abs=1e-3)
            # resized to 20x45: continuous coordinates scale per axis
            uv_r, _ = load_scene(nerfstudio_folder, (20, 45)).cameras[k].project(torch.tensor(p))
            assert uv_r.tolist() == pytest.approx((want[0] * 0.5, want[1] * 1.5), abs=1e-3)


def test_blender_style_folder(tmp_path):
    """NeRF 'blender' folders: camera_angle_x, no w/h/cx/cy, paths without an extension."""
    _write_png(tmp_path / "train" / "r_0.png", np.full((16, 16, 3), 200, np.uint8))
    m = _gl_look_at((0, -4, 0), (0, 0, 0))
    (tmp_path / "transforms.json").write_text(
        json.dumps({"camera_angle_x": 0.6911, "frames": [{"file_path": "./train/r_0", "transform_matrix": m.tolist()}]})
    )
    cam = load_scene(tmp_path).cameras[0]
    assert float(cam.fx) == pytest.approx(8 / np.tan(0.6911 / 2), rel=1e-5)
    assert (float(cam.cx), float(cam.cy)) == (8.0, 8.0)


# ---------------------------------------------------------------------------- errors
def _folder(tmp_path: Path, edit=None, depth: bool = True, size=(8, 6)) -> Path:
    """A valid 1-frame folder with depth; ``edit(meta)`` breaks it."""
    w, h = size
    _write_png(tmp_path / "rgb" / "0.png", np.zeros((6, 8, 3), np.uint8))
    _write_png(tmp_path / "depth" / "0.png", np.full((6, 8), 1000, np.uint16))
    frame = {"file_path": "rgb/0.png", "transform_matrix": np.eye(4).tolist()}
    if depth:
        frame["depth_file_path"] = "depth/0.png"
    meta = {
        "w": w,
        "h": h,
        "fl_x": 10.0,
        "fl_y": 10.0,
        "cx": 4.0,
        "cy": 3.0,
        "depth_unit_scale_factor": 0.001,
        "frames": [frame],
    }
    if edit is not None:
        edit(meta)
    (tmp_path / "transforms.json").write_text(json.dumps(meta))
    return tmp_path


def test_valid_error_fixture_loads(tmp_path):
    scene = load_scene(_folder(tmp_path))
    assert torch.allclose(scene.depth, torch.ones(1, 1, 6, 8))


def test_error_no_transforms(tmp_path):
    with pytest.raises(FileNotFoundError, match=re.escape(str(tmp_path / "transforms.json"))):
        load_scene(tmp_path)
    with pytest.raises(FileNotFoundError, match="no such scene folder"):
        load_scene(tmp_path / "nope")


def _set(path: list, value):
    def edit(meta):
        node = meta
        for key in path[:-1]:
            node = node[key]
        node[path[-1]] = value

    return edit


def _delete(path: list):
    def edit(meta):
        node = meta
        for key in path[:-1]:
            node = node[key]
        del node[path[-1]]

    return edit


@pytest.mark.parametrize(
    "edit, key, message",
    [
        (_delete(["frames"]), "frames", "missing key"),
        (_set(["frames"], []), "frames", "non-empty"),
        (_delete(["frames", 0, "file_path"]), "file_path", "missing key"),
        (_delete(["frames", 0, "transform_matrix"]), "transform_matrix", "missing key"),
        (_delete(["fl_x"]), "fl_x", "missing key"),
        (_delete(["fl_y"]), "fl_y", "missing key"),
        (_set(["fl_x"], -3.0), "fl_x", "positive"),
        (
            _set(
                ["frames", 0, "transform_matrix"], [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, float("nan")], [0, 0, 0, 1]]
            ),
            "transform_matrix",
            "non-finite",
        ),
        (
            _set(["frames", 0, "transform_matrix"], (np.eye(4) * [2, 2, 2, 1]).tolist()),
            "transform_matrix",
            "not a rigid",
        ),
        (
            _set(["frames", 0, "transform_matrix"], np.diag([1.0, 1.0, -1.0, 1.0]).tolist()),
            "transform_matrix",
            "not a rigid",
        ),
        (_set(["frames", 0, "transform_matrix"], [[1, 0, 0], [0, 1, 0]]), "transform_matrix", "4x4"),
        (_delete(["depth_unit_scale_factor"]), "depth_unit_scale_factor", "no key"),
    ],
)
def test_format_errors_name_file_and_key(tmp_path, edit, key, message):
    folder = _folder(tmp_path, edit)
    with pytest.raises(SceneFormatError) as info:
        load_scene(folder)
    text = str(info.value)
    assert str(folder / "transforms.json") in text and f"'{key}'" in text and message in text, text


def test_error_missing_image(tmp_path):
    folder = _folder(tmp_path, _set(["frames", 0, "file_path"], "rgb/missing.png"))
    with pytest.raises(FileNotFoundError) as info:
        load_scene(folder)
    assert "'file_path'" in str(info.value) and str(folder / "rgb" / "missing.png") in str(info.value)


def test_error_image_path_is_a_folder(tmp_path):
    folder = _folder(tmp_path, _set(["frames", 0, "file_path"], "rgb"))
    with pytest.raises(FileNotFoundError, match="'file_path'.*a folder, not an image file"):
        load_scene(folder)


def test_error_missing_depth_image(tmp_path):
    folder = _folder(tmp_path, _set(["frames", 0, "depth_file_path"], "depth/none.png"))
    with pytest.raises(FileNotFoundError, match="'depth_file_path'.*none.png"):
        load_scene(folder)


def test_error_image_size_disagrees_with_intrinsics(tmp_path):
    folder = _folder(tmp_path, size=(9, 6))
    with pytest.raises(SceneFormatError) as info:
        load_scene(folder)
    text = str(info.value)
    assert "transforms.json" in text and "rgb/0.png" in text and "'w', 'h'" in text and "8x6" in text


def test_error_depth_size_disagrees(tmp_path):
    folder = _folder(tmp_path)
    _write_png(folder / "depth" / "0.png", np.zeros((5, 8), np.uint16))
    with pytest.raises(SceneFormatError, match="'depth_file_path'.*8x5"):
        load_scene(folder)


def test_error_mixed_sizes_need_a_resolution(tmp_path):
    def second_frame(meta):
        meta["frames"].append({**meta["frames"][0], "file_path": "rgb/1.png", "w": 4, "h": 3, "cx": 2.0, "cy": 1.5})
        del meta["frames"][1]["depth_file_path"]

    folder = _folder(tmp_path, second_frame)
    _write_png(folder / "rgb" / "1.png", np.zeros((3, 4, 3), np.uint8))
    with pytest.raises(SceneFormatError, match="different sizes"):
        load_scene(folder)
    scene = load_scene(folder, (8, 6))
    assert scene.rgb.shape == (2, 3, 6, 8)
    assert float(scene.depth[1].abs().max()) == 0.0  # no depth for frame 1: zeros
    assert float(scene.cameras[1].cx) == pytest.approx(4.0)
