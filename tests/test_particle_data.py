"""Particles as data: the arrays against float64 brute force and geometry, the .npz round trip, the batched
encode and the ``particlesplat encode`` command (resume, nesting, atomic files)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from model_data import TINY_MODEL, tiny_dataset

from particlesplat.analysis.encode_folder import encode_batch, encode_folder, find_scenes
from particlesplat.analysis.particle_arrays import ParticleArrays, encode_scene_arrays, particle_arrays
from particlesplat.cli.main import main
from particlesplat.core.camera import Camera
from particlesplat.core.gaussians import Gaussians
from particlesplat.data import read_scene
from particlesplat.editing.grouping import dense_objects, drawing_particles, object_centres, weighted_stats
from particlesplat.model import ModelConfig, ParticleSplat, save_checkpoint


@pytest.fixture(scope="module")
def model():
    torch.manual_seed(0)
    return ParticleSplat(ModelConfig(**TINY_MODEL)).eval()


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    return tiny_dataset(tmp_path_factory)


@pytest.fixture(scope="module")
def encoded(model, data):
    scene = data / "train" / "scene_00000"
    return encode_scene_arrays(model, scene, [4, 16]), scene


def _gaussians(means, opacities, owner, sh_dc=None) -> Gaussians:
    n = means.shape[0]
    sh = torch.zeros(n, 1, 3, dtype=means.dtype) if sh_dc is None else sh_dc[:, None, :]
    return Gaussians(
        means,
        torch.tensor([[1.0, 0, 0, 0]], dtype=means.dtype).repeat(n, 1),
        torch.full((n, 3), 0.01, dtype=means.dtype),
        opacities,
        sh,
        owner,
    )


def test_weighted_stats_match_brute_force():
    gen = torch.Generator().manual_seed(3)
    x = torch.randn(200, 3, generator=gen)
    w = torch.rand(200, generator=gen)
    g = torch.randint(-1, 5, (200,), generator=gen)  # -1 = ignored; group 4 has members, group 5 none
    mean, std, total = weighted_stats(x, w, g, 6)
    for k in range(6):
        rows = [i for i in range(200) if int(g[i]) == k]
        if not rows:
            assert float(total[k]) == 0.0 and mean[k].abs().max() == 0 and std[k].abs().max() == 0
            continue
        ws = sum(float(w[i]) for i in rows)
        m = [sum(float(w[i]) * float(x[i, a]) for i in rows) / ws for a in range(3)]
        s = [(sum(float(w[i]) * (float(x[i, a]) - m[a]) ** 2 for i in rows) / ws) ** 0.5 for a in range(3)]
        assert mean[k].tolist() == pytest.approx(m, abs=1e-12)
        assert std[k].tolist() == pytest.approx(s, abs=1e-12)


def test_arrays_have_the_issue_layout(encoded, model):
    a, _ = encoded
    P, D = a.num_particles, model.config.d_obj if hasattr(model.config, "d_obj") else a.z_f.shape[1]
    shapes = {
        "z_p": (P, 2),
        "z_s": (P, 2),
        "z_d": (P, 1),
        "z_e": (P, 1),
        "z_t": (P, 1),
        "z_f": (P, a.z_f.shape[1]),
        "view": (P,),
        "anchor": (P, 3),
        "centroid": (P, 3),
        "extent": (P, 3),
        "colour": (P, 3),
        "active": (P,),
        "object": (P,),
        "object_centroid": (a.num_objects, 3),
        "object_extent": (a.num_objects, 3),
        "K": (2, 3, 3),
        "c2w": (2, 4, 4),
    }
    assert D > 0
    for name, shape in shapes.items():
        assert getattr(a, name).shape == shape, name
    assert a.active.dtype == bool and a.object.dtype == np.int64 and a.view.dtype == np.int64
    assert ((a.colour >= 0) & (a.colour <= 1)).all()
    assert a.meta["context"] == [4, 16]
    # object labels: dense 0..K-1 over the active particles, -1 elsewhere
    assert (a.object[~a.active] == -1).all()
    assert sorted(set(a.object[a.active].tolist())) == list(range(a.num_objects))


def test_anchor_reprojects_to_z_p_at_depth_d(encoded, model):
    a, _ = encoded
    cfg = model.config
    for i in range(a.num_particles):
        cam = Camera(
            torch.tensor(a.K[a.view[i]], dtype=torch.float64),
            torch.tensor(a.c2w[a.view[i]], dtype=torch.float64),
            cfg.resolution,
            cfg.resolution,
        )
        uv, z = cam.project(torch.tensor(a.anchor[i], dtype=torch.float64))
        expect_uv = (a.z_p[i].astype(np.float64) + 1.0) * 0.5 * cfg.resolution
        d = cfg.d_min + (cfg.d_max - cfg.d_min) / (1.0 + np.exp(-float(a.z_d[i, 0])))
        assert uv.tolist() == pytest.approx(expect_uv.tolist(), abs=2e-3)
        assert float(z) == pytest.approx(d, abs=1e-4)


def test_centroid_extent_colour_are_brute_force_weighted_means(encoded, model):
    a, scene = encoded
    from particlesplat.editing.open_scene import encode_scene

    enc = encode_scene(model, scene, [4, 16])
    g = model.decode(enc.particles)
    x, w, own = g.means.double().numpy(), g.opacities.double().numpy(), g.owner.numpy()
    dc = np.clip(0.28209479177387814 * g.sh[:, 0, :].double().numpy() + 0.5, 0, 1)
    for i in range(a.num_particles):
        sel = own == i
        if not sel.any():
            continue
        ws = w[sel]
        m = (ws[:, None] * x[sel]).sum(0) / ws.sum()
        s = np.sqrt((ws[:, None] * (x[sel] - m) ** 2).sum(0) / ws.sum())
        c = (ws[:, None] * dc[sel]).sum(0) / ws.sum()
        np.testing.assert_allclose(a.centroid[i], m, atol=1e-5)
        np.testing.assert_allclose(a.extent[i], s, atol=1e-5)
        np.testing.assert_allclose(a.colour[i], c, atol=1e-5)
    # object centre "weighted": the brute-force mean over all Gaussians of the object's particles
    weighted = particle_arrays(model, enc.particles, g, object_centre="weighted")
    for k in range(weighted.num_objects):
        sel = np.isin(own, np.flatnonzero(weighted.object == k))
        m = (w[sel, None] * x[sel]).sum(0) / w[sel].sum()
        np.testing.assert_allclose(weighted.object_centroid[k], m, atol=1e-5)


def test_active_means_the_particle_draws(model, data):
    from particlesplat.editing.open_scene import encode_scene

    enc = encode_scene(model, data / "train" / "scene_00001", [4, 16])
    p = enc.particles.with_attribute(0, "z_t", [0.0])  # hidden: z_t below the threshold
    p = p.with_attribute(1, "z_t", [1.0])
    g = model.decode(p, z_t_threshold=0.0)
    active = drawing_particles(p, g, model.config.bg_mask_threshold)
    assert not bool(active[0]) and bool(active[1])
    # a particle whose Gaussians are all below the renderer's 1/255 cut-off does not draw either
    faint = Gaussians(
        g.means, g.quats, g.scales, torch.where(g.owner == 1, torch.zeros_like(g.opacities), g.opacities), g.sh, g.owner
    )
    assert not bool(drawing_particles(p, faint, model.config.bg_mask_threshold)[1])
    # the arrays agree: an inactive particle has no object
    a = particle_arrays(model, p)
    assert not a.active[0] and a.object[0] == -1 and a.active[1] and a.object[1] >= 0


def test_dense_objects_numbering():
    groups = torch.tensor([0, 0, 2, 3, 2, 5])
    active = torch.tensor([True, True, False, True, True, False])
    assert dense_objects(groups, active).tolist() == [0, 0, -1, 2, 1, -1]


def test_resting_centre_analytic():
    """A column of Gaussians from z = 0.1 to 0.1 + 2h standing on a support at z = 0.1: the top is the 0.95
    quantile 0.95 * 2h (+ 0.1 below it), the centre half-way to the support; x, y the opacity-weighted mean. The
    support is the world frame's (z = 0) unless given: background Gaussians far below it (a robot workspace's
    floor under its table) do not move it."""
    h = 0.2
    z = torch.linspace(0.1, 0.1 + 2 * h, 101, dtype=torch.float64)
    obj = torch.stack([torch.full_like(z, 0.3), torch.full_like(z, -0.2), z], -1)
    obj[:50, 0] += 0.1  # half the column shifted in x with opacity 1, half at 0.5: mean x = 0.3 + 0.1 * 50/75.5
    op = torch.cat([torch.ones(50), torch.full((51,), 0.5)]).double()
    floor = torch.stack([torch.rand(30).double(), torch.rand(30).double(), torch.full((30,), 0.1).double()], -1)
    g = _gaussians(
        torch.cat([obj, floor]),
        torch.cat([op, torch.ones(30).double()]),
        torch.cat([torch.zeros(101, dtype=torch.int64), torch.full((30,), -1)]),
    )
    centre, _ = object_centres(g, torch.tensor([0]), 1, "resting", support=0.1)
    assert centre[0].tolist() == pytest.approx([0.3 + 0.1 * 50 / 75.5, -0.2, 0.1 + 0.5 * 0.95 * 2 * h], abs=1e-9)
    below = _gaussians(g.means - torch.tensor([0.0, 0.0, 0.1]).double(), g.opacities, g.owner)  # stands on z = 0
    below = _gaussians(
        torch.cat([below.means, floor - torch.tensor([0.0, 0.0, 0.9]).double()]),  # and a floor at z = -0.8
        torch.cat([below.opacities, torch.ones(30).double()]),
        torch.cat([below.owner, torch.full((30,), -1)]),
    )
    centre, _ = object_centres(below, torch.tensor([0]), 1, "resting")
    assert float(centre[0, 2]) == pytest.approx(0.5 * 0.95 * 2 * h, abs=1e-9)
    with pytest.raises(ValueError, match="object centre method"):
        object_centres(g, torch.tensor([0]), 1, "middle")


def test_npz_round_trip(encoded, tmp_path):
    a, _ = encoded
    path = a.save(tmp_path / "s.npz")
    b = ParticleArrays.load(path)
    for name, value in a.arrays().items():
        if name == "meta":
            assert json.loads(str(value)) == b.meta
        else:
            np.testing.assert_array_equal(value, getattr(b, name))
    with np.load(path, allow_pickle=False) as f:  # a learner needs numpy only
        assert json.loads(str(f["meta"]))["context"] == [4, 16]
    bad = tmp_path / "bad.npz"
    np.savez(bad, z_p=np.zeros((1, 2)))
    with pytest.raises(ValueError, match="bad.npz: missing array"):
        ParticleArrays.load(bad)


def test_encode_batch_equals_single_encode(model, data):
    paths = [data / "train" / "scene_00000", data / "train" / "scene_00001", data / "val" / "scene_00000"]
    scenes = [read_scene(p).select([4, 16], model.config.resolution) for p in paths]
    batched = encode_batch(model, scenes)
    for sc, pb in zip(scenes, batched, strict=False):
        ps = model.encode(sc.rgb, sc.depth, sc.cameras)
        for name in ("z_p", "z_s", "z_d", "z_e", "z_t", "z_f", "background"):
            torch.testing.assert_close(getattr(pb, name), getattr(ps, name), atol=1e-5, rtol=1e-4)


def test_encode_command_resumes_and_mirrors_folders(model, data, tmp_path):
    ckpt = tmp_path / "m.pt"
    save_checkpoint(ckpt, model, 0)
    out = tmp_path / "out"
    assert (
        main(
            [
                "encode",
                "--data",
                str(data),
                "--out",
                str(out),
                "--checkpoint",
                str(ckpt),
                "--batch",
                "2",
                "--context",
                "4,16",
                "--device",
                "cpu",
                "--no-progress",
            ]
        )
        == 0
    )
    files = sorted(p.relative_to(out).as_posix() for p in out.rglob("*.npz"))
    assert files == ["train/scene_00000.npz", "train/scene_00001.npz", "val/scene_00000.npz"]
    assert not [p for p in out.rglob("*") if p.name.startswith(".")]  # no temporaries left
    a = ParticleArrays.load(out / "val" / "scene_00000.npz")
    assert a.meta["context"] == [4, 16] and a.meta["scene"].endswith("val/scene_00000")
    assert len(a.meta["checkpoint_sha256"]) == 64
    # the same scene through the one-scene API gives the same arrays
    single = encode_scene_arrays(model, data / "val" / "scene_00000", [4, 16])
    np.testing.assert_allclose(a.centroid, single.centroid, atol=1e-4)
    np.testing.assert_array_equal(a.active, single.active)
    # resumable: existing outputs are skipped (their bytes untouched), a missing one is written again
    stamp = (out / "train" / "scene_00000.npz").stat().st_mtime_ns
    (out / "train" / "scene_00001.npz").unlink()
    stats = encode_folder(model, data, out, context=[4, 16], progress=False)
    assert (stats["written"], stats["skipped"]) == (1, 2)
    assert (out / "train" / "scene_00000.npz").stat().st_mtime_ns == stamp
    # one scene folder works too
    one = tmp_path / "one"
    encode_folder(model, data / "val" / "scene_00000", one, context=[4, 16], progress=False)
    assert [p.name for p in one.iterdir()] == ["scene_00000.npz"]


def test_find_scenes_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="no such folder"):
        find_scenes(tmp_path / "missing")
    with pytest.raises(FileNotFoundError, match="no scene folders"):
        find_scenes(tmp_path)


def test_scene_object_centres_and_distances(data, tmp_path):
    from particlesplat.analysis.particle_arrays import localisation_summary, nearest_distances, scene_object_centres

    scene = data / "train" / "scene_00000"
    doc = json.loads((scene / "scene.json").read_text())
    centres = scene_object_centres(scene)
    assert centres.tolist() == [o["center"] for o in doc["objects"]]
    assert scene_object_centres(tmp_path) is None  # no scene.json: no localisation
    (tmp_path / "scene.json").write_text('{"objects": [{"center": [1, 2]}]}')
    with pytest.raises(ValueError, match="scene.json: objects"):
        scene_object_centres(tmp_path)
    truth = np.array([[0.0, 0, 0], [1, 0, 0], [5, 5, 5]])
    pred = np.array([[0.0, 0.04, 0], [1, 0, 0.12]])
    d = nearest_distances(truth, pred)
    assert d[:2].tolist() == pytest.approx([0.04, 0.12])
    assert d[2] == pytest.approx(np.linalg.norm([4, 5, 5.0 - 0.12]))
    assert np.isinf(nearest_distances(truth, np.zeros((0, 3)))).all()
    s = localisation_summary(d)
    assert (s["objects"], s["within_0.05"], s["within_0.1"], s["within_0.15"]) == (3, 1 / 3, 1 / 3, 2 / 3)


def test_eval_reports_localisation(model, data, tmp_path):
    from particlesplat.analysis.evaluate import evaluate_dataset

    out = evaluate_dataset(model, data / "val", progress_bar=False)
    n_true = len(json.loads((data / "val" / "scene_00000" / "scene.json").read_text())["objects"])
    loc = out["localisation"]
    assert set(loc) == {"resting", "weighted"} and loc["resting"]["objects"] == n_true
    assert len(out["scenes"][0]["localisation_m"]["weighted"]) == n_true


def test_find_scenes_follows_symlinks_and_skips_hidden(data, tmp_path):
    root = tmp_path / "links"
    (root / "split").mkdir(parents=True)
    (root / "split" / "a").symlink_to(data / "train" / "scene_00000", target_is_directory=True)
    (root / "split" / "loop").symlink_to(root, target_is_directory=True)  # a cycle must not hang
    (root / ".tmp").mkdir()
    (root / ".tmp" / "b").symlink_to(data / "train" / "scene_00001", target_is_directory=True)
    assert find_scenes(root) == [root / "split" / "a"]
