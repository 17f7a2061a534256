"""``particlesplat export``: an edited scene to each format (what ``render`` draws for the same edit file), a
Gaussian file converted, ``--prune``, object bundles whose parts are exactly the scene, and the errors."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from formats_spec import random_gaussians, render_psnr

from particlesplat.analysis.particle_arrays import particle_arrays
from particlesplat.cli.main import main
from particlesplat.core.gaussians import Gaussians
from particlesplat.editing.editor import SceneEditor
from particlesplat.editing.open_scene import demo_scenes, load_model_scene
from particlesplat.formats.splat_files import SUFFIXES, read_gaussians

CONTEXT = "4,16"


@pytest.fixture(scope="module")
def edited(tmp_path_factory):
    """The demo scene with its largest object removed: (edit file, model, edited particles, their Gaussians)."""
    torch.set_num_threads(1)
    model, enc, _ = load_model_scene(None, demo_scenes()[0], CONTEXT)
    ed = SceneEditor(model, enc.particles, enc.all_cameras, enc.context)
    objects = ed.objects()
    label = int(torch.mode(objects[objects >= 0]).values)
    ed.remove_object(label)
    path = ed.save(tmp_path_factory.mktemp("edits") / "rm.yaml", scene=str(demo_scenes()[0]))
    with torch.no_grad():
        g = model.decode(ed.particles).detach().to("cpu")
    return path, model, ed.particles, g


def _scene_args(edits) -> list[str]:
    return ["--scene", str(demo_scenes()[0]), "--context", CONTEXT, "--edits", str(edits)]


def _sorted_rows(g: Gaussians) -> np.ndarray:
    """The Gaussians as rows (owner, means, scales, opacity, sh), sorted: a multiset to compare."""
    rows = torch.cat(
        [
            g.owner[:, None].double(),
            g.means.double(),
            g.scales.double(),
            g.opacities[:, None].double(),
            g.sh.reshape(g.num, -1).double(),
        ],
        dim=1,
    ).numpy()
    return rows[np.lexsort(rows.T[::-1])]


def test_an_edited_scene_exports_as_render_draws_it(edited, tmp_path, capsys):
    edits, _, _, g = edited
    assert main(["export", *_scene_args(edits), "--out", str(tmp_path / "s.ply")]) == 0
    assert "saved" in capsys.readouterr().out
    got = Gaussians(*read_gaussians(tmp_path / "s.ply"))
    assert got.num == g.num
    np.testing.assert_allclose(_sorted_rows(got), _sorted_rows(g), atol=2e-5)
    assert (
        main(
            [
                "render",
                "--ply",
                str(tmp_path / "s.ply"),
                "--width",
                "32",
                "--height",
                "24",
                "--out",
                str(tmp_path / "s.png"),
            ]
        )
        == 0
    )


def test_a_gaussian_file_converts_to_every_format_and_back(tmp_path, capsys):
    g = random_gaussians(600, 0, seed=4)
    g.opacities[100:] = g.opacities[100:].clamp_min(0.01)
    g.opacities[:100] = 0.001  # below half an 8-bit step
    g.save_ply(tmp_path / "in.ply")
    for suffix in SUFFIXES:
        out = tmp_path / f"out{suffix}"
        assert main(["export", "--ply", str(tmp_path / "in.ply"), "--out", str(out), "--prune"]) == 0
        said = capsys.readouterr().out
        assert "600 Gaussians" not in said and "500 Gaussians, 100 below opacity 0.003922 dropped" in said, said
        back = Gaussians(*read_gaussians(out))
        assert back.num == 500
        assert render_psnr(back, g.subset(g.opacities >= 1 / 255)) >= 40.0, suffix
        # the converted file converts again (compressed .ply and SOG files read back as themselves) and renders
        assert main(["export", "--ply", str(out), "--out", str(tmp_path / f"again{suffix}")]) == 0
        png = tmp_path / f"render{suffix}.png"
        assert main(["render", "--ply", str(out), "--width", "32", "--height", "24", "--out", str(png)]) == 0


def test_bundles_hold_every_gaussian_once_and_merge_back_to_the_scene(edited, tmp_path, capsys):
    edits, model, particles, g = edited
    arrays = particle_arrays(model, particles, g)
    for by in ("object", "particle"):
        out = tmp_path / by
        assert main(["export", *_scene_args(edits), "--by", by, "--out", str(out)]) == 0
        manifest = json.loads((out / "manifest.json").read_text())
        parts = manifest["parts"]
        assert parts[-1]["file"] == "rest.ply" and manifest["gaussians"] == g.num
        assert manifest["context"] == [4, 16] and len(manifest["cameras"]) == 2
        assert np.asarray(manifest["cameras"][0]["K"]).shape == (3, 3)
        files = sorted(p.name for p in out.iterdir())
        assert files == sorted([p["file"] for p in parts] + ["manifest.json"])
        pieces = [Gaussians.load_ply(out / p["file"]) for p in parts]
        assert [p.num for p in pieces] == [p["gaussians"] for p in parts]
        np.testing.assert_allclose(_sorted_rows(Gaussians.cat(pieces)), _sorted_rows(g), atol=2e-5)
        if by == "object":
            assert len(parts) - 1 == arrays.num_objects
            for k, p in enumerate(parts[:-1]):
                assert p["file"] == f"object_{k}.ply" and p["members"] == np.flatnonzero(arrays.object == k).tolist()
                assert set(pieces[k].owner.tolist()) <= set(p["members"])
        else:
            for p, piece in zip(parts[:-1], pieces, strict=False):
                assert p["file"] == f"particle_{p['index']}.ply" and set(piece.owner.tolist()) == {p["index"]}
                assert p["object"] == int(arrays.object[p["index"]]) and p["active"] == bool(arrays.active[p["index"]])
                centre = (piece.opacities[:, None] * piece.means).sum(0) / piece.opacities.sum()
                np.testing.assert_allclose(p["centre"], centre.numpy(), atol=1e-5)
        assert set(pieces[-1].owner.tolist()) - {-1} == (
            set() if by == "particle" else set(np.flatnonzero(arrays.object < 0).tolist()) & set(g.owner.tolist())
        )
        merged = Gaussians(*read_gaussians(out / "manifest.json"))
        assert render_psnr(merged, g) >= 50.0  # the same Gaussians in another order
    # a second export replaces the bundle
    assert main(["export", *_scene_args(edits), "--by", "object", "--out", str(tmp_path / "particle")]) == 0
    assert not list((tmp_path / "particle").glob("particle_*.ply"))


def test_bad_requests_are_one_line_errors(tmp_path, capsys):
    random_gaussians(20, 0, seed=1).save_ply(tmp_path / "g.ply")
    (tmp_path / "keep").mkdir()
    (tmp_path / "keep" / "precious.txt").write_text("mine")
    cases = [
        (
            ["--ply", str(tmp_path / "g.ply"), "--out", str(tmp_path / "x.obj")],
            "x.obj: unknown Gaussian file extension",
        ),
        (
            ["--ply", str(tmp_path / "g.ply"), "--by", "object", "--out", str(tmp_path / "b")],
            "--by object needs a model",
        ),
        (
            ["--ply", str(tmp_path / "g.ply"), "--by", "particle", "--out", str(tmp_path / "keep")],
            "neither empty nor a",
        ),
        (
            ["--ply", str(tmp_path / "nope.spz"), "--out", str(tmp_path / "x.ply")],
            "--ply " + str(tmp_path / "nope.spz") + ": no such file",
        ),
        (
            ["--ply", str(tmp_path / "g.ply"), "--by", "particle", "--out", str(tmp_path / "b.spz")],
            f"--by writes a folder of .ply parts and a manifest, not a .spz file: give a folder, e.g. --out "
            f"{tmp_path / 'b_particles'}/",
        ),
        (
            ["--ply", str(tmp_path / "g.ply"), "--by", "particle", "--out", str(tmp_path / "c.compressed.ply")],
            f"not a .compressed.ply file: give a folder, e.g. --out {tmp_path / 'c_particles'}/",
        ),
        (["--ply", str(tmp_path / "g.ply"), "--prune", "2", "--out", str(tmp_path / "x.ply")], "--prune must be"),
        (["--ply", str(tmp_path / "g.ply"), "--context", "1,2", "--out", str(tmp_path / "x.ply")], "--context needs"),
    ]
    for args, message in cases:
        assert main(["export", *args]) == 2
        err = capsys.readouterr().err.strip()
        assert message in err and "\n" not in err, err
    assert (tmp_path / "keep" / "precious.txt").read_text() == "mine"
    # the folder the refusal suggests is one --by writes
    assert (
        main(["export", "--ply", str(tmp_path / "g.ply"), "--by", "particle", "--out", str(tmp_path / "b_particles")])
        == 0
    )
    assert (tmp_path / "b_particles" / "manifest.json").is_file()


def test_the_formats_benchmark_reports_every_format_and_the_bundle(tmp_path, capsys):
    from particlesplat.bench.formats import main as bench_formats

    random_gaussians(800, 0, seed=6).save_ply(tmp_path / "g.ply")  # (.splat holds no SH)
    assert (
        bench_formats(
            ["--ply", str(tmp_path / "g.ply"), "--width", "64", "--height", "48", "--json", str(tmp_path / "b.json")]
        )
        == 0
    )
    report = json.loads((tmp_path / "b.json").read_text())
    rows = {r["format"]: r for r in report["rows"]}
    assert set(rows) == set(SUFFIXES) and rows[".ply"]["ours_db"] >= 99 and report["bundle_db"] >= 99
    assert all(r["ours_db"] >= 30 for r in rows.values()), rows
    assert rows[".splat"]["bytes_per_gaussian"] == 32.0
    assert (
        rows[".sog"]["bytes_per_gaussian"] < rows[".spz"]["bytes_per_gaussian"] * 2 < rows[".ply"]["bytes_per_gaussian"]
    )
    assert "bundle by particle, merged" in capsys.readouterr().out


def test_gaussians_load_and_save_take_every_format(tmp_path):
    g = random_gaussians(300, 0, seed=9)
    for suffix in SUFFIXES:
        g.save(tmp_path / f"g{suffix}")
        back = Gaussians.load(tmp_path / f"g{suffix}")
        assert back.num == 300 and render_psnr(back, g) >= 40.0, suffix
