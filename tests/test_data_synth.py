"""Generator tests: determinism and resuming, and an independent geometric check of its scenes
against the dataset spec (analytic surfaces, cameras, Lambert colours)."""

from __future__ import annotations

import filecmp
import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from particlesplat.cli.main import main as cli_main
from particlesplat.core.bundled import bundled_assets
from particlesplat.core.errors import run_command
from particlesplat.data import load_scene
from particlesplat.data.synth import generate

ASSET_SCENES = [bundled_assets() / "scenes" / f"scene_0000{i}" for i in range(3)]
SPEC_COLOURS = {
    "red": (0.85, 0.2, 0.2),
    "green": (0.2, 0.7, 0.3),
    "blue": (0.2, 0.35, 0.85),
    "yellow": (0.9, 0.8, 0.2),
    "cyan": (0.2, 0.75, 0.8),
    "magenta": (0.8, 0.25, 0.7),
    "orange": (0.95, 0.5, 0.15),
    "white": (0.9, 0.9, 0.9),
}
LIGHT = np.array([0.4, 0.3, 1.0]) / np.linalg.norm([0.4, 0.3, 1.0])


def _same_tree(a: Path, b: Path) -> bool:
    cmp = filecmp.dircmp(a, b)
    if cmp.left_only or cmp.right_only or cmp.diff_files or cmp.funny_files:
        return False
    match, mismatch, errors = filecmp.cmpfiles(a, b, cmp.common_files, shallow=False)
    return not mismatch and not errors and all(_same_tree(a / d, b / d) for d in cmp.common_dirs)


@pytest.fixture(scope="module")
def generated(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("synth") / "data"
    times = generate(out, {"train": 1, "val": 2, "test": 0}, seed=7, res=40, workers=1, progress=False)
    assert len(times) == 3
    return out


def test_deterministic_across_workers_and_resume(generated, tmp_path):
    other = tmp_path / "other"
    generate(other, {"train": 0, "val": 1, "test": 0}, seed=7, res=40, workers=1, progress=False)
    # resume with more scenes, in two worker processes, in another order of work
    times = generate(other, {"train": 1, "val": 2, "test": 0}, seed=7, res=40, workers=2, progress=False)
    assert len(times) == 2
    for split, name in [("train", "scene_00000"), ("val", "scene_00000"), ("val", "scene_00001")]:
        assert _same_tree(generated / split / name, other / split / name), (split, name)
    different = tmp_path / "seed8"
    generate(different, {"train": 1, "val": 0, "test": 0}, seed=8, res=40, workers=1, progress=False)
    assert not _same_tree(generated / "train" / "scene_00000", different / "train" / "scene_00000")


def test_resume_skips_whole_scenes_and_clears_partial_ones(generated, tmp_path):
    out = tmp_path / "data"
    generate(out, {"train": 1, "val": 0, "test": 0}, seed=7, res=40, workers=1, progress=False)
    first = out / "train" / "scene_00000" / "transforms.json"
    stamp = first.stat().st_mtime_ns
    partial = out / "train" / ".scene_00001.abc.tmp"  # what a killed run leaves behind
    (partial / "rgb").mkdir(parents=True)
    times = generate(out, {"train": 2, "val": 0, "test": 0}, seed=7, res=40, workers=1, progress=False)
    assert len(times) == 1 and first.stat().st_mtime_ns == stamp and not partial.exists()
    assert sorted(p.name for p in (out / "train").iterdir()) == ["scene_00000", "scene_00001"]
    with pytest.raises(ValueError, match=r"synth\.json: key 'seed'"):
        generate(out, {"train": 2, "val": 0, "test": 0}, seed=8, res=40, workers=1, progress=False)


def test_cli(tmp_path, capsys):
    assert (
        cli_main(
            ["synth", str(tmp_path / "d"), "--train", "1", "--val", "0", "--test", "0", "--res", "16", "--workers", "1"]
        )
        == 0
    )
    assert load_scene(tmp_path / "d" / "train" / "scene_00000").rgb.shape == (21, 3, 16, 16)
    (tmp_path / "plain").mkdir()  # a finished scene folder has the permissions of any new folder (umask)
    assert (tmp_path / "d" / "train" / "scene_00000").stat().st_mode == (tmp_path / "plain").stat().st_mode
    (tmp_path / "file").write_text("")
    capsys.readouterr()

    def console(*argv: str) -> int:  # the console script: the one error policy (one line, exit 2)
        return run_command("particlesplat synth", lambda: cli_main(["synth", *argv]))

    assert console(str(tmp_path / "file"), "--train", "1", "--val", "0", "--test", "0") == 2
    assert capsys.readouterr().err.startswith(f"particlesplat synth: error: {tmp_path / 'file'}: exists and is not")
    assert console(str(tmp_path / "e"), "--seed", "-1", "--train", "1") == 2
    assert "--seed" in capsys.readouterr().err
    assert console(str(tmp_path / "e"), "--res", "4100", "--train", "1") == 2  # beyond the largest scene image
    assert "--res must be in [8, 4096]" in capsys.readouterr().err
    assert not (tmp_path / "e").exists()


# ---------------------------------------------------------------------------- independent geometric check
def _sdf(obj: dict, p: np.ndarray) -> np.ndarray:
    """Signed distance of points p (N, 3) to an object, written from the spec's description."""
    c, s = np.asarray(obj["center"]), np.asarray(obj["size"])
    q = p - c
    if obj["shape"] == "sphere":
        return np.linalg.norm(q, axis=1) - s[0]
    if obj["shape"] == "box":
        cy, sy = math.cos(obj["yaw"]), math.sin(obj["yaw"])
        local = np.stack([cy * q[:, 0] + sy * q[:, 1], -sy * q[:, 0] + cy * q[:, 1], q[:, 2]], axis=1)
        d = np.abs(local) - s
        return np.linalg.norm(np.maximum(d, 0), axis=1) + np.minimum(d.max(axis=1), 0)
    d = np.stack([np.hypot(q[:, 0], q[:, 1]) - s[0], np.abs(q[:, 2]) - s[2]], axis=1)
    return np.linalg.norm(np.maximum(d, 0), axis=1) + np.minimum(d.max(axis=1), 0)


def _normal(obj: dict, p: np.ndarray) -> np.ndarray:
    """(N, 3) outward unit normals by central differences of the SDF."""
    eps = 1e-5
    g = np.stack([_sdf(obj, p + eps * e) - _sdf(obj, p - eps * e) for e in np.eye(3)], axis=1)
    return g / np.linalg.norm(g, axis=1, keepdims=True)


def _flat_interior(mask: np.ndarray, rgb: np.ndarray) -> np.ndarray:
    """(H, W) bool: pixels whose 3x3 neighbourhood has one instance id and one colour (no edges)."""
    h, w = mask.shape
    ok = np.zeros((h, w), bool)
    ok[1:-1, 1:-1] = True
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            sl = (slice(1 + dy, h - 1 + dy), slice(1 + dx, w - 1 + dx))
            ok[1:-1, 1:-1] &= (mask[sl] == mask[1:-1, 1:-1]) & (np.abs(rgb[sl] - rgb[1:-1, 1:-1]).max(-1) < 1e-6)
    return ok


def _check_scene(folder: Path) -> None:
    meta = json.loads((folder / "scene.json").read_text())
    objects = meta["objects"]
    # the family's draws
    assert 2 <= len(objects) <= 5
    assert 25 <= meta["elevation_deg"] <= 40 and 3.0 <= meta["distance"] <= 3.6
    grid = np.stack(np.meshgrid(*[np.linspace(-0.35, 0.35, 15)] * 3, indexing="ij"), -1).reshape(-1, 3)
    for k, obj in enumerate(objects):
        assert obj["colour"] in SPEC_COLOURS and obj["shape"] in ("sphere", "box", "cylinder")
        assert all(0.12 <= v <= 0.30 for v in obj["size"])
        assert math.hypot(obj["center"][0], obj["center"][1]) <= 1.0
        assert obj["center"][2] == pytest.approx(obj["size"][2])  # resting on the floor
        inside = grid + np.asarray(obj["center"])
        inside = inside[_sdf(obj, inside) < 0]
        for other in objects[k + 1 :]:
            assert (_sdf(other, inside) > 0).all(), "objects intersect"
    scene = load_scene(folder)
    res = scene.width
    f = 0.5 * res / math.tan(math.radians(20))
    for i, cam in enumerate(scene.cameras):
        # cameras from the spec: azimuth -120..120 in 21 steps, on the arc about (0, 0, 0.15), no roll
        az, el = math.radians(-120 + 12 * i), math.radians(meta["elevation_deg"])
        eye = np.array([0, 0, 0.15]) + meta["distance"] * np.array(
            [math.sin(az) * math.cos(el), -math.cos(az) * math.cos(el), math.sin(el)]
        )
        assert cam.center.double().numpy() == pytest.approx(eye, abs=1e-5)
        assert cam.K.double().numpy() == pytest.approx(
            np.array([[f, 0, res / 2], [0, f, res / 2], [0, 0, 1]]), abs=1e-3
        )
        uv, _ = cam.project(torch.tensor([0.0, 0.0, 0.15]))
        assert uv.tolist() == pytest.approx([res / 2, res / 2], abs=1e-3)
        assert float(cam.R[2, 0]) == pytest.approx(0.0, abs=1e-6)  # no roll: image x is horizontal
        assert float(cam.R[2, 1]) < 0  # image y (down) points down in the world
        # every pixel with depth lies on the surface its mask names
        cam64 = cam.to(dtype=torch.float64)
        d = scene.depth[i, 0].double()
        origins, dirs = cam64.rays()
        p = (origins + dirs * d[..., None]).numpy()
        mask = scene.masks[i].numpy()
        rgb = scene.rgb[i].permute(1, 2, 0).double().numpy()
        has = d.numpy() > 0
        floor = has & (mask == 0)
        assert np.abs(p[floor][:, 2]).max() < 2e-3 and np.abs(p[floor][:, :2]).max() < 2.0 + 1e-2
        assert (mask[~has] == 0).all()
        flat = _flat_interior(mask, rgb)
        greys = np.array([0.55, 0.65]) * (0.35 + 0.65 * LIGHT[2])
        floor_rgb = rgb[floor & flat]
        assert np.abs(floor_rgb[:, :, None] - greys).min(-1).max() < 1.5 / 255  # one of the two greys
        assert np.abs(rgb[~has & flat] - [0.12, 0.14, 0.18]).max() < 1.5 / 255
        for k, obj in enumerate(objects, start=1):
            sel = mask == k
            if not sel.any():
                continue
            assert np.abs(_sdf(obj, p[sel])).max() < 2e-3, (folder, i, k)
            sel &= flat
            if sel.any():
                n = _normal(obj, p[sel])
                want = np.asarray(SPEC_COLOURS[obj["colour"]]) * (0.35 + 0.65 * np.maximum(n @ LIGHT, 0))[:, None]
                assert np.abs(rgb[sel] - np.clip(want, 0, 1)).max() < 1.5 / 255, (folder, i, k)


@pytest.mark.parametrize("index", range(3))
def test_asset_scenes_follow_the_spec(index):
    _check_scene(ASSET_SCENES[index])


def test_generated_scenes_follow_the_spec(generated):
    for folder in sorted((generated / "val").iterdir()):
        _check_scene(folder)
