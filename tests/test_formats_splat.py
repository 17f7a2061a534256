"""The antimatter15 ``.splat`` writer and reader, checked against a reader written from the format's description
(``formats_spec.read_splat_spec``), on the demo scene and on random Gaussians; bad files are refused in one line."""

from __future__ import annotations

import numpy as np
import pytest
from formats_spec import (
    C0,
    assert_same_as_ours,
    demo_gaussians,
    original,
    random_gaussians,
    read_splat_spec,
    render_psnr,
    rotation_dot,
)

from particlesplat.core.gaussians import Gaussians
from particlesplat.formats.splat import read_splat, write_splat
from particlesplat.formats.splat_arrays import SplatFileError


@pytest.mark.parametrize("source", ["demo", "random"])
def test_the_spec_reader_reads_what_we_write_within_a_byte(tmp_path, source):
    g = demo_gaussians() if source == "demo" else random_gaussians(500, 1, seed=3)
    path = tmp_path / "g.splat"
    write_splat(g, path)
    assert path.stat().st_size == 32 * g.num
    spec, want = read_splat_spec(path), original(g)
    np.testing.assert_array_equal(spec["means"], want["means"])  # float32 in, float32 out
    np.testing.assert_allclose(spec["log_scales"], want["log_scales"], atol=1e-6)
    assert np.abs(spec["opacities"] - want["opacities"]).max() <= 0.5 / 255 + 1e-9
    colour = lambda dc: np.clip(C0 * dc + 0.5, 0, 1)  # noqa: E731
    assert np.abs(colour(spec["dc"]) - colour(want["dc"])).max() <= 0.5 / 255 + 1e-9
    assert rotation_dot(spec["quats"], want["quats"]).min() > 0.9997  # a byte a component: < 2.8 degrees
    assert_same_as_ours(Gaussians(*read_splat(path)), spec | {"rest": np.zeros((g.num, 0, 3))})


def test_the_demo_scene_renders_as_its_ply(tmp_path):
    g = demo_gaussians()
    write_splat(g, tmp_path / "g.splat")
    assert render_psnr(Gaussians(*read_splat(tmp_path / "g.splat")), g) >= 50.0  # 59.4 dB measured


def test_bad_files_are_refused_in_one_line(tmp_path):
    write_splat(random_gaussians(3, 0, seed=1), tmp_path / "g.splat")
    data = (tmp_path / "g.splat").read_bytes()
    (tmp_path / "short.splat").write_bytes(data[:-5])
    with pytest.raises(SplatFileError, match=r"short\.splat: size 91 bytes is not a multiple of the \.splat record"):
        read_splat(tmp_path / "short.splat")
    bad = bytearray(data)
    bad[32 + 12 : 32 + 16] = np.float32(np.nan).tobytes()  # Gaussian 1's first scale
    (tmp_path / "nan.splat").write_bytes(bytes(bad))
    with pytest.raises(SplatFileError, match=r"nan\.splat: scale at Gaussian 1 is \[nan") as info:
        read_splat(tmp_path / "nan.splat")
    assert "\n" not in str(info.value)
    bad = bytearray(data)
    bad[64:68] = np.float32(np.inf).tobytes()  # Gaussian 2's x
    (tmp_path / "inf.splat").write_bytes(bytes(bad))
    with pytest.raises(SplatFileError, match=r"inf\.splat: means: non-finite value at Gaussian 2"):
        read_splat(tmp_path / "inf.splat")
