"""PlayCanvas's SOG v2 writer and reader, checked against a reader written from the published specification
(``formats_spec.read_sog_spec``) on the demo scene and on random Gaussians; an unbundled ``meta.json`` reads as
its zip; bad files are refused in one line."""

from __future__ import annotations

import json
import zipfile

import numpy as np
import pytest
from formats_spec import (
    assert_same_as_ours,
    demo_gaussians,
    original,
    random_gaussians,
    read_sog_spec,
    render_psnr,
    rotation_dot,
)

from particlesplat.core.gaussians import Gaussians
from particlesplat.formats.sog import read_sog, write_sog
from particlesplat.formats.splat_arrays import SplatFileError
from particlesplat.formats.splat_files import read_gaussians


def _nearest_error(got: np.ndarray, want: np.ndarray, codebook: list[float]) -> float:
    """How much farther each decoded value is from its original than the nearest codebook entry is (0: the
    writer chose the nearest entry everywhere)."""
    book = np.asarray(codebook)
    assert np.abs(got[..., None] - book).min(-1).max() < 1e-6  # every value decodes to an entry (float32 here)
    best = np.abs(want[..., None] - book).min(-1)
    return float((np.abs(got - want) - best).max())


@pytest.mark.parametrize("source", ["demo", "random"])
def test_the_spec_reader_reads_what_we_write_within_its_steps(tmp_path, source):
    g = demo_gaussians() if source == "demo" else random_gaussians(1000, 0, seed=5)
    path = tmp_path / "g.sog"
    write_sog(g, path)
    with zipfile.ZipFile(path) as z:
        meta = json.loads(z.read("meta.json"))
        assert {"meta.json", "means_l.webp", "means_u.webp", "quats.webp", "scales.webp", "sh0.webp"} == set(
            z.namelist()
        )
    spec, want = read_sog_spec(path), original(g)
    assert meta["count"] == g.num
    lt = lambda v: np.sign(v) * np.log1p(np.abs(v))  # noqa: E731
    span = np.array(meta["means"]["maxs"]) - np.array(meta["means"]["mins"])
    assert (np.abs(lt(spec["means"]) - lt(want["means"])) <= span / 65535 / 2 + 1e-9).all()
    assert rotation_dot(spec["quats"], want["quats"]).min() > 1 - 1e-4  # 8 bits over ±1/sqrt(2)
    assert _nearest_error(spec["log_scales"], want["log_scales"], meta["scales"]["codebook"]) < 1e-6
    assert _nearest_error(spec["dc"], want["dc"], meta["sh0"]["codebook"]) < 1e-6  # alpha 0 keeps its colour too
    assert np.abs(spec["opacities"] - want["opacities"]).max() <= 0.5 / 255 + 1e-9
    assert_same_as_ours(Gaussians(*read_sog(path)), spec)


def test_the_demo_scene_renders_as_its_ply_and_reads_unbundled(tmp_path):
    g = demo_gaussians()
    write_sog(g, tmp_path / "g.sog")
    assert render_psnr(Gaussians(*read_sog(tmp_path / "g.sog")), g) >= 50.0  # 65.3 dB measured
    with zipfile.ZipFile(tmp_path / "g.sog") as z:
        z.extractall(tmp_path / "unbundled")
    a, b = read_gaussians(tmp_path / "g.sog"), read_gaussians(tmp_path / "unbundled" / "meta.json")
    for x, y in zip(a, b, strict=True):
        assert bool((x == y).all())


def _rewrite(src, dst, meta_edit=None, drop=None):
    with zipfile.ZipFile(src) as z, zipfile.ZipFile(dst, "w") as out:
        for name in z.namelist():
            if name == drop:
                continue
            data = z.read(name)
            if name == "meta.json" and meta_edit is not None:
                meta = json.loads(data)
                meta_edit(meta)
                data = json.dumps(meta).encode()
            out.writestr(name, data)


def test_bad_files_are_refused_in_one_line(tmp_path):
    src = tmp_path / "g.sog"
    write_sog(random_gaussians(20, 0, seed=1), src)

    def nan_codebook(m):
        m["scales"]["codebook"][3] = float("nan")

    cases = {
        "v1.sog": (dict(meta_edit=lambda m: m.pop("version")), "version None is not supported"),
        "count.sog": (dict(meta_edit=lambda m: m.update(count=10_000)), "fewer than count 10000"),
        "nan.sog": (dict(meta_edit=nan_codebook), "'scales.codebook': expected 256 finite numbers"),
        "short.sog": (
            dict(meta_edit=lambda m: m["sh0"].update(codebook=[0.0] * 10)),
            "'sh0.codebook': expected 256 finite numbers",
        ),
        "missing.sog": (dict(drop="quats.webp"), "member 'quats.webp' is not in the zip"),
        "nomeans.sog": (dict(meta_edit=lambda m: m.pop("means")), "meta.json: missing 'means'"),
    }
    for name, (edit, message) in cases.items():
        _rewrite(src, tmp_path / name, **edit)
        with pytest.raises(SplatFileError) as info:
            read_gaussians(tmp_path / name)
        msg = str(info.value)
        assert msg.startswith(str(tmp_path / name)) and message in msg and "\n" not in msg, msg
    (tmp_path / "junk.sog").write_bytes(b"PK\x03\x04 not really a zip")
    with pytest.raises(SplatFileError, match=r"junk\.sog: not a SOG zip"):
        read_gaussians(tmp_path / "junk.sog")


@pytest.mark.parametrize("degree", [1, 3])
def test_higher_sh_bands_are_kept_as_one_palette_entry_a_gaussian(tmp_path, degree):
    g = random_gaussians(300, degree, seed=degree)
    write_sog(g, tmp_path / "sh.sog")
    with zipfile.ZipFile(tmp_path / "sh.sog") as z:
        meta = json.loads(z.read("meta.json"))
    assert meta["shN"]["bands"] == degree and meta["shN"]["count"] == 300
    back = Gaussians(*read_sog(tmp_path / "sh.sog"))
    rest, want = back.sh[:, 1:].double().numpy(), g.sh[:, 1:].double().numpy()
    assert _nearest_error(rest, want, meta["shN"]["codebook"]) < 1e-6
    assert render_psnr(back, g) >= 45.0
